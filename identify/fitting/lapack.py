"""The dense algebra of SciPy's least-squares solvers, called without holding the GIL.

Fits run side by side in threads (:func:`identify.fitting.threads.side_by_side`), and a fit's
model kernels release the GIL, but two calls inside :func:`scipy.optimize.least_squares` hold
it for their whole LAPACK routine: ``numpy.linalg.lstsq`` (the Gauss-Newton step of each
``dogbox`` iteration, LAPACK ``dgelsd``) and ``scipy.linalg.svd`` (each ``trf`` iteration,
``dgesdd``). Measured on a 3500 x 21 Jacobian, two threads calling ``lstsq`` get nothing
done faster than one (0.97-0.98 x), calling ``svd`` 1.0-1.7 x: such a call stops the other fit.

:func:`lstsq` and :func:`svd` call the same LAPACK routines (SciPy's, through the stable
``scipy.linalg.cython_lapack`` interface) with the same arguments and workspace query, through
:mod:`ctypes`, which releases the GIL during a foreign call: two threads then run them 1.8-3.0
times as fast as one (``benchmarks/lapack_gil.py``). Their results are those of ``numpy.linalg.lstsq`` and
``scipy.linalg.svd`` bit for bit on the wheels this project installs (a table test), and a
diagnosis's answers are unchanged. Any other input (another dtype or shape, a non-finite
value, another ``rcond``, a LAPACK error) goes to the original function.

:func:`release_the_gil_in_least_squares` puts them in the two solver modules, once per process;
SciPy looks the names up at each iteration. It leaves the modules alone unless they still
hold the functions it replaces.
"""

from __future__ import annotations

import ctypes
import functools
import importlib

import numpy as np
import scipy.linalg
from numba.extending import get_cython_function_address

__all__ = ["lstsq", "svd", "release_the_gil_in_least_squares"]

#: LAPACK's ``dgesdd`` and ``dgelsd`` (14 pointer arguments each, passed as addresses), as SciPy
#: exports them.
_DGESDD = ctypes.CFUNCTYPE(None, *[ctypes.c_void_p] * 14)(
    get_cython_function_address("scipy.linalg.cython_lapack", "dgesdd")
)
_DGELSD = ctypes.CFUNCTYPE(None, *[ctypes.c_void_p] * 14)(
    get_cython_function_address("scipy.linalg.cython_lapack", "dgelsd")
)
#: dgesdd's JOBZ, "S": the first min(m, n) singular vectors (a byte that lives as long as the module).
_THIN = np.frombuffer(b"S", dtype=np.uint8)


def _address(array: np.ndarray) -> int:
    return array.__array_interface__["data"][0]


def _integers(values) -> tuple[np.ndarray, list]:
    """LAPACK's integer arguments: an int32 array and the address of each of its entries."""
    ints = np.array(values, dtype=np.int32)
    base = _address(ints)
    return ints, [base + 4 * k for k in range(ints.size)]


def svd(a, full_matrices=True, **kwargs):
    """``scipy.linalg.svd(a, full_matrices=False)`` of a finite float64 matrix ``(m, n)``:
    ``(u (m, k), s (k,), vh (k, n))``, ``k = min(m, n)``, without holding the GIL; anything
    else is ``scipy.linalg.svd(a, full_matrices, **kwargs)``."""
    a = np.asarray(a)
    if full_matrices or kwargs or a.dtype != np.float64 or a.ndim != 2 or a.size == 0 or not np.isfinite(a).all():
        return scipy.linalg.svd(a, full_matrices=full_matrices, **kwargs)
    m, n = a.shape
    k = min(m, n)
    work_a = np.array(a, order="F")
    s = np.empty(k)
    u = np.empty((m, k), order="F")
    vh = np.empty((k, n), order="F")
    iwork = np.empty(8 * k, dtype=np.int32)
    ints, at = _integers([m, n, m, m, k, -1, 0])  # m, n, lda, ldu, ldvt, lwork, info
    work = np.empty(1)

    def call():
        _DGESDD(
            _address(_THIN),
            at[0],
            at[1],
            _address(work_a),
            at[2],
            _address(s),
            _address(u),
            at[3],
            _address(vh),
            at[4],
            _address(work),
            at[5],
            _address(iwork),
            at[6],
        )

    call()  # the workspace query
    work = np.empty(max(1, int(work[0])))
    ints[5] = work.size
    call()
    if ints[6] != 0:  # no convergence or a bad argument: the original says which
        return scipy.linalg.svd(a, full_matrices=False)
    return u, s, vh


def lstsq(a, b, rcond=None):
    """``numpy.linalg.lstsq(a, b, rcond=-1)`` of a float64 matrix ``(m, n)`` and vector ``(m,)``
    (the solution ``(n,)``, an empty residuals array, the rank and the singular values), without
    holding the GIL; anything else is ``numpy.linalg.lstsq(a, b, rcond)``. Only the solution and
    the rank are what NumPy returns bit for bit (``dogbox`` reads the solution)."""
    a, b = np.asarray(a), np.asarray(b)
    if (
        rcond is None
        or rcond != -1
        or a.dtype != np.float64
        or b.dtype != np.float64
        or a.ndim != 2
        or b.shape != a.shape[:1]
        or a.size == 0
    ):
        return np.linalg.lstsq(a, b, rcond=rcond)
    m, n = a.shape
    work_a = np.array(a, order="F")
    solution = np.zeros(max(m, n))
    solution[:m] = b
    s = np.empty(min(m, n))
    cutoff = np.array([-1.0])
    ints, at = _integers([m, n, 1, m, max(m, n), 0, -1, 0])  # m, n, nrhs, lda, ldb, rank, lwork, info
    work = np.empty(1)
    iwork = np.empty(1, dtype=np.int32)

    def call():
        _DGELSD(
            at[0],
            at[1],
            at[2],
            _address(work_a),
            at[3],
            _address(solution),
            at[4],
            _address(s),
            _address(cutoff),
            at[5],
            _address(work),
            at[6],
            _address(iwork),
            at[7],
        )

    call()  # the workspace query
    work = np.empty(max(1, int(work[0])))
    iwork = np.empty(max(1, int(iwork[0])), dtype=np.int32)
    ints[6] = work.size
    call()
    if ints[7] != 0:
        return np.linalg.lstsq(a, b, rcond=rcond)
    return solution[:n].copy(), np.empty(0), int(ints[5]), s


@functools.cache
def release_the_gil_in_least_squares() -> bool:
    """:func:`lstsq` into SciPy's ``dogbox`` and :func:`svd` into its ``trf`` (once per process),
    where they still hold ``numpy.linalg.lstsq`` and ``scipy.linalg.svd``; True when both are in."""
    done = []
    for module_name, name, original, replacement in (
        ("scipy.optimize._lsq.dogbox", "lstsq", np.linalg.lstsq, lstsq),
        ("scipy.optimize._lsq.trf", "svd", scipy.linalg.svd, svd),
    ):
        try:
            module = importlib.import_module(module_name)
        except ImportError:
            continue
        if getattr(module, name, None) is original:
            setattr(module, name, replacement)
            done.append(name)
    return len(done) == 2

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

:func:`trf_svd` is the ``svd`` ``trf`` gets: on a tall Jacobian it keeps ``U`` implicit (``trf``
only ever multiplies ``U^T`` by the residual), the same singular values and vectors ``V`` bit
for bit and ``U^T f`` to the last bits, at a third to a seventh of the cost.

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

__all__ = ["lstsq", "svd", "trf_svd", "ImplicitU", "release_the_gil_in_least_squares"]

#: LAPACK's ``dgesdd`` and ``dgelsd`` (14 pointer arguments each, passed as addresses), as SciPy
#: exports them.
_DGESDD = ctypes.CFUNCTYPE(None, *[ctypes.c_void_p] * 14)(
    get_cython_function_address("scipy.linalg.cython_lapack", "dgesdd")
)
_DGELSD = ctypes.CFUNCTYPE(None, *[ctypes.c_void_p] * 14)(
    get_cython_function_address("scipy.linalg.cython_lapack", "dgelsd")
)
#: LAPACK's Householder QR ``dgeqrf`` (8 pointer arguments) and the product with its ``Q``, ``dormqr`` (13).
_DGEQRF = ctypes.CFUNCTYPE(None, *[ctypes.c_void_p] * 8)(
    get_cython_function_address("scipy.linalg.cython_lapack", "dgeqrf")
)
_DORMQR = ctypes.CFUNCTYPE(None, *[ctypes.c_void_p] * 13)(
    get_cython_function_address("scipy.linalg.cython_lapack", "dormqr")
)
#: dormqr's SIDE "L" and its TRANS "T" (Q^T) or "N" (Q).
_LEFT = np.frombuffer(b"L", dtype=np.uint8)
_TRANS = {True: np.frombuffer(b"T", dtype=np.uint8), False: np.frombuffer(b"N", dtype=np.uint8)}
#: dgesdd's JOBZ, "S": the first min(m, n) singular vectors (a byte that lives as long as the module).
_THIN = np.frombuffer(b"S", dtype=np.uint8)


def _address(array: np.ndarray) -> int:
    return array.__array_interface__["data"][0]


def _integers(values) -> tuple[np.ndarray, list]:
    """LAPACK's integer arguments: an int32 array and the address of each of its entries."""
    ints = np.array(values, dtype=np.int32)
    base = _address(ints)
    return ints, [base + 4 * k for k in range(ints.size)]


def _with_workspace(call, ints: np.ndarray, lwork: int) -> None:
    """A LAPACK routine that asks for its workspace first: ``call(work)`` with ``LWORK = -1`` (at
    ``ints[lwork]``, the workspace query: the size goes to ``work[0]``), then again with the
    workspace it asked for."""
    work = np.empty(1)
    call(work)
    work = np.empty(max(1, int(work[0])))
    ints[lwork] = work.size
    call(work)


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

    def call(work):
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

    _with_workspace(call, ints, 5)
    if ints[6] != 0:  # no convergence or a bad argument: the original says which
        return scipy.linalg.svd(a, full_matrices=False)
    return u, s, vh


def _householder_qr(a: np.ndarray):
    """LAPACK ``dgeqrf`` of a float64 matrix ``(m, n)``, ``m >= n``, without the GIL: ``(qr, tau)``,
    ``R`` on and above the diagonal of ``qr`` (Fortran order) and the reflectors below it; None on
    a LAPACK error."""
    m, n = a.shape
    qr = np.array(a, order="F")
    tau = np.empty(n)
    ints, at = _integers([m, n, m, -1, 0])  # m, n, lda, lwork, info

    def call(work):
        _DGEQRF(at[0], at[1], _address(qr), at[2], _address(tau), _address(work), at[3], at[4])

    _with_workspace(call, ints, 3)
    return (qr, tau) if ints[4] == 0 else None


def _times_q(qr: np.ndarray, tau: np.ndarray, c: np.ndarray, transposed: bool) -> np.ndarray | None:
    """``Q^T c`` (``transposed``) or ``Q c`` of the ``Q`` of :func:`_householder_qr`, ``c`` ``(m, k)``,
    by LAPACK ``dormqr`` without the GIL (a new array; None on a LAPACK error)."""
    m, n = qr.shape
    out = np.array(c, dtype=np.float64, order="F")
    ints, at = _integers([m, out.shape[1], n, m, m, -1, 0])  # m, columns of c, k, lda, ldc, lwork, info

    def call(work):
        _DORMQR(
            _address(_LEFT),
            _address(_TRANS[transposed]),
            at[0],
            at[1],
            at[2],
            _address(qr),
            at[3],
            _address(tau),
            _address(out),
            at[4],
            _address(work),
            at[5],
            at[6],
        )

    _with_workspace(call, ints, 5)
    return out if ints[6] == 0 else None


#: Rows per column from which :func:`trf_svd` keeps ``U`` implicit: above LAPACK ``dgesdd``'s own
#: threshold ``11 n / 6`` (from which it factors ``A = Q R`` first, so that ``s`` and ``vh`` are its
#: own), and where forming ``U`` costs more than the extra calls (a Jacobian has thousands of rows
#: for tens of columns).
_TALL_RATIO = 8


class ImplicitU:
    """The left singular vectors ``U = Q U_R`` ``(m, n)`` of a tall matrix ``A = Q R``, ``R = U_R S V^T``,
    kept as ``Q``'s Householder reflectors and ``U_R`` ``(n, n)`` (:func:`trf_svd`).

    ``U.T.dot(f)`` (what SciPy's ``trf`` asks of ``U``) applies ``Q^T`` to ``f`` and then ``U_R^T``:
    about ``4 m n`` operations where forming ``U`` takes about ``4 m n^2``. ``numpy.asarray(U)``
    forms it, for any other use."""

    def __init__(self, qr: np.ndarray, tau: np.ndarray, u_r: np.ndarray):
        self._qr, self._tau, self._u_r = qr, tau, u_r
        self.shape = (qr.shape[0], u_r.shape[1])
        self.ndim = 2
        self.dtype = np.dtype(np.float64)

    def transposed_times(self, f) -> np.ndarray:
        """``U^T f`` of a vector ``f`` ``(m,)`` or matrix ``(m, k)``."""
        f = np.asarray(f, dtype=np.float64)
        q_t_f = _times_q(self._qr, self._tau, f.reshape(f.shape[0], -1), transposed=True)
        if q_t_f is None:  # forming U would take the same dormqr
            raise np.linalg.LinAlgError("dormqr failed applying Q^T")
        out = self._u_r.T @ q_t_f[: self._u_r.shape[0]]
        return out.reshape((self.shape[1],) + f.shape[1:])

    @property
    def T(self) -> _ImplicitUTransposed:
        return _ImplicitUTransposed(self)

    def __array__(self, dtype=None, copy=None):
        n = self._u_r.shape[0]
        padded = np.zeros((self._qr.shape[0], self._u_r.shape[1]))
        padded[:n] = self._u_r
        u = _times_q(self._qr, self._tau, padded, transposed=False)
        if u is None:
            raise np.linalg.LinAlgError("dormqr failed forming U")
        return u if dtype is None else u.astype(dtype)


class _ImplicitUTransposed:
    """``U.T`` of an :class:`ImplicitU`: ``.dot(f)`` and ``@ f``."""

    def __init__(self, u: ImplicitU):
        self._u = u
        self.shape = u.shape[::-1]
        self.ndim = 2
        self.dtype = u.dtype

    def dot(self, f) -> np.ndarray:
        return self._u.transposed_times(f)

    __matmul__ = dot

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self._u, dtype=dtype).T


def trf_svd(a, full_matrices=True, **kwargs):
    """:func:`svd` as SciPy's ``trf`` uses it: for a tall matrix (``m`` at least :data:`_TALL_RATIO`
    times ``n``), ``(ImplicitU, s, vh)``.

    ``dgesdd`` on such a matrix factors ``A = Q R``, takes the SVD of ``R`` and then forms
    ``U = Q U_R``, an ``(m, n)`` product costing twice the rest; ``trf`` only ever needs ``U^T f``.
    Here ``R`` comes from the same ``dgeqrf`` and its SVD from the same ``dgesdd``, so ``s`` and
    ``vh`` are ``scipy.linalg.svd``'s bit for bit; ``U`` stays implicit (:class:`ImplicitU`), and
    ``U^T f`` differs from the product with the formed ``U`` in the last bits (the sums' order).
    On a 14002 x 22 Jacobian about 2.5 times, on 70001 x 20 about 7 times as fast. Anything else
    is :func:`svd`'s."""
    a = np.asarray(a)
    tall = a.ndim == 2 and a.shape[1] > 0 and a.shape[0] >= _TALL_RATIO * a.shape[1]
    if full_matrices or kwargs or not tall or a.dtype != np.float64 or not np.isfinite(a).all():
        return svd(a, full_matrices=full_matrices, **kwargs)
    factored = _householder_qr(a)
    if factored is None:
        return svd(a, full_matrices=False)
    qr, tau = factored
    n = a.shape[1]
    u_r, s, vh = svd(np.triu(qr[:n]), full_matrices=False)
    return ImplicitU(qr, tau, u_r), s, vh


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
    """:func:`lstsq` into SciPy's ``dogbox`` and :func:`trf_svd` into its ``trf`` (once per process),
    where they still hold ``numpy.linalg.lstsq`` and ``scipy.linalg.svd``; True when both are in."""
    done = []
    for module_name, name, original, replacement in (
        ("scipy.optimize._lsq.dogbox", "lstsq", np.linalg.lstsq, lstsq),
        ("scipy.optimize._lsq.trf", "svd", scipy.linalg.svd, trf_svd),
    ):
        try:
            module = importlib.import_module(module_name)
        except ImportError:
            continue
        if getattr(module, name, None) is original:
            setattr(module, name, replacement)
            done.append(name)
    return len(done) == 2

"""The export's C called from Python (ctypes): the tests' and the benchmark's view of it.

:class:`NativeModel` compiles ``OUT/c/`` into a shared library with the local compiler and
runs whole arrays through its step functions (``msma_forward_run``, ``msma_inverse_run``:
one step per sample, exactly what a controller calls), with the exported parameter set.
"""

from __future__ import annotations

import ctypes
import tempfile
from pathlib import Path

import numpy as np

from .compiler import shared_library

__all__ = ["NativeModel", "STATUS"]

#: ``msma_inverse_step``'s status values (model.inverse's names).
STATUS = {0: "exact", 1: "saturated", 2: "branch"}

_DOUBLES = np.ctypeslib.ndpointer(dtype=np.float64, flags="C_CONTIGUOUS")
_INTS = np.ctypeslib.ndpointer(dtype=np.intc, flags="C_CONTIGUOUS")


class NativeModel:
    """The C forward model and inverse of an export folder's ``c/`` (or the folder itself).

    Parameters
    ----------
    c_dir : path
        ``OUT/c`` (or ``OUT``) of an export.
    compiler : str, optional
        The C compiler (default ``$CC``, ``cc``, ``gcc``, ``clang``).
    """

    def __init__(self, c_dir, *, compiler=None):
        c_dir = Path(c_dir)
        if (c_dir / "c").is_dir():
            c_dir = c_dir / "c"
        self.c_dir = c_dir
        with tempfile.TemporaryDirectory(prefix="msma-native-") as work:
            library = shared_library(
                [c_dir / "msma_gpi.c", c_dir / "msma_params.c"],
                Path(work) / "libmsma.so",
                compiler=compiler,
                extra_flags=(f"-I{c_dir}",),
            )
            self.library = ctypes.CDLL(str(library))  # mapped: the file may go
        lib = self.library
        lib.msma_params_size.restype = ctypes.c_size_t
        lib.msma_default_params.argtypes = [ctypes.c_void_p]
        lib.msma_forward_run.argtypes = [ctypes.c_void_p, ctypes.c_size_t, _DOUBLES, _DOUBLES, _DOUBLES]
        lib.msma_inverse_run.argtypes = [
            ctypes.c_void_p,
            ctypes.c_double,
            ctypes.c_double,
            ctypes.c_double,
            ctypes.c_size_t,
            _DOUBLES,
            _DOUBLES,
            _DOUBLES,
            _DOUBLES,
            _INTS,
        ]
        self._params = ctypes.create_string_buffer(lib.msma_params_size())
        lib.msma_default_params(self._params)

    @staticmethod
    def _arrays(time, values):
        time = np.ascontiguousarray(time, dtype=np.float64)
        values = np.ascontiguousarray(values, dtype=np.float64)
        if time.ndim != 1 or values.shape != time.shape:
            raise ValueError(f"time and values must both have shape (T,), got {time.shape} and {values.shape}")
        return time, values

    def forward(self, time, current) -> np.ndarray:
        """The displacement, one ``msma_forward_step`` per sample, shape (T,)."""
        time, current = self._arrays(time, current)
        out = np.empty_like(time)
        code = self.library.msma_forward_run(self._params, time.size, time, current, out)
        if code:
            raise ValueError(f"msma_forward_init refused the parameters (code {code})")
        return out

    def inverse(self, time, target, current_range, scale):
        """``(current, output, status)``: one ``msma_inverse_step`` per sample, each shape (T,)."""
        time, target = self._arrays(time, target)
        current, output = np.empty_like(time), np.empty_like(time)
        status = np.empty(time.size, dtype=np.intc)
        lo, hi = (float(x) for x in current_range)
        code = self.library.msma_inverse_run(
            self._params, lo, hi, float(scale), time.size, time, target, current, output, status
        )
        if code:
            raise ValueError(f"msma_inverse_init refused the parameters or the range (code {code})")
        return current, output, status

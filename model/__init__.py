"""Forward models: the GPI hysteresis model of the seed paper, its input, and physical effects.

Pure and vectorised: no I/O, no plotting.
"""

import os as _os

# numba's OpenMP threads wait passively between parallel regions unless the user chose
# otherwise: busy-waiting (libgomp's default) gives the same wall time here but keeps a
# core spinning after every kernel call, so two diagnoses side by side on two cores run at
# half speed (docs/benchmarks.md#diagnosis-speed). Read when the threads start: at the first
# parallel call, after this import.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from .gpi import GPI_PARAMETERS, READINGS, TABLE1, THETA_NAMES, bound_overlap, classical_pi, envelope, gpi
from .parameters import Parameter, ParameterSet
from .composite import EFFECTS, Effect, Model, get_effect, register_effect
from . import effects as _effects  # noqa: F401  (fills EFFECTS)
from .signals import INPUT_READINGS, QUIET_SECONDS, paper_current

__all__ = [
    "gpi",
    "bound_overlap",
    "classical_pi",
    "envelope",
    "paper_current",
    "THETA_NAMES",
    "TABLE1",
    "GPI_PARAMETERS",
    "READINGS",
    "INPUT_READINGS",
    "QUIET_SECONDS",
    "Model",
    "Effect",
    "EFFECTS",
    "get_effect",
    "register_effect",
    "Parameter",
    "ParameterSet",
]

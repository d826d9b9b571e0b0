"""Forward models: the GPI hysteresis model of the seed paper, its input, and physical effects.

Pure and vectorised: no I/O, no plotting.
"""

from . import effects  # registers the library's effects in EFFECTS
from .composite import EFFECTS, Effect, Model, get_effect, register_effect
from .gpi import GPI_PARAMETERS, READINGS, TABLE1, THETA_NAMES, bound_overlap, classical_pi, envelope, gpi
from .parameters import Parameter, ParameterSet
from .signals import INPUT_READINGS, QUIET_SECONDS, paper_current

__all__ = [
    "effects",
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

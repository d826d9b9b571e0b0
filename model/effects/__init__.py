r"""Library of physical effects that can be added to the GPI model (see :mod:`model.composite`).

A package: :mod:`~model.effects.base` holds the protocol (:class:`Effect`, the parameter
declaration, the registry :data:`EFFECTS`), one module per effect holds its class beside
its kernel, and :mod:`~model.effects._filters` the shared numerical core (the exact
first-order filter and its tables). Importing the package registers the library's effects
in :data:`EFFECTS`, in the canonical order below (:data:`LIBRARY`). Every effect names its
parameters ``<effect>_<what>`` with physical units and bounds, declares each at its
``off`` value (the model is then the plain GPI bit for bit) and has a typical "on" setting
(:meth:`get_test_parameters`).

``lag`` (input, :mod:`~model.effects.lag`)
    :math:`\tau_L \dot v = i - v`, the GPI sees :math:`u(t) = v(t - d)` (first order plus dead time)
``training`` (input, :mod:`~model.effects.training`)
    excursion :math:`i - i_0` less :math:`F f`, times :math:`1 - g f`; thresholds times :math:`1 + w f`; strain
    excursion times :math:`1 + s f`; :math:`f = e^{-(V/V_0)^p}`, :math:`V` the drive's travel
``rate_width`` (input, :mod:`~model.effects.rate_width`)
    thresholds :math:`r_j (1 + b g)` (:math:`b \ge 0`) or :math:`r_j / (1 + |b| g)` (:math:`b < 0`),
    :math:`g = \ln(1 + c|\dot u|)/c`: rate-dependent hysteresis
``initial_state`` (state, :mod:`~model.effects.initial_state`)
    operators' initial memory from a level :math:`z^0`, a prior excursion and a memory held beyond the bounds
``incomplete_reset`` (output, :mod:`~model.effects.incomplete_reset`)
    :math:`y = y_g + A (n + q)`: extra strain on the virgin loading, fraction :math:`R` kept after unloading, fading
    with travel
``creep`` (output, :mod:`~model.effects.creep`)
    saturating spectrum :math:`y_g - A(y_g - \tfrac1M\sum_m s_m)` plus logarithmic creep :math:`\gamma` per decade
    after each change (or from the end of its leg)
``thermal`` (output, :mod:`~model.effects.thermal`)
    two nodes :math:`\tau_T \dot\vartheta_1 = (i/i_\mathrm{ref})^2 - \vartheta_1`,
    :math:`\tau_2 \dot\vartheta_2 = \vartheta_1 - \vartheta_2`,
    :math:`y = y_g (1 - S\vartheta_1 - S_2\vartheta_2) + E\vartheta_1 + E_2\vartheta_2`
``sensor_drift`` (output, :mod:`~model.effects.sensor_drift`)
    :math:`y = y_g + D_1 s + D_2 s^2 + D_w (1 - e^{-t/\tau_w})` plus a periodic ambient,
    :math:`s = (t - t_0)/(t_{T-1} - t_0)`

Output-stage effects act in the order incomplete reset, creep, thermal, sensor drift (the
registration order): the first-cycle strain and creep belong to the strain, temperature
scales the strain and adds expansion, and the sensor drifts on top of everything.

Each effect is written in a general physical form whose earlier, simpler form is a special
case (its extra amplitudes 0): the test parameters (:meth:`get_test_parameters`) are that
simpler form. Each docstring says which parameters trade off with each other or with the
GPI; ``docs/effects.md`` gives the measured Jacobian ranks on the paper's input.

All first-order filters use the actual sample times (no assumed sampling rate) and the
exact solution of :math:`\tau \dot u = x - u` for an input that is linear between
samples (:func:`first_order_lowpass`).
"""

from __future__ import annotations

# the protocol and the constants the kernels use are importable from here too (``X as X``:
# re-exported beside __all__, as from the module this package replaced)
from ._filters import MAX_DISTINCT_STEPS as MAX_DISTINCT_STEPS
from ._filters import first_order_lowpass
from .base import EFFECTS as EFFECTS
from .base import STAGES as STAGES
from .base import Effect as Effect
from .base import get_effect as get_effect
from .base import register_effect
from .creep import (
    CREEP_MODES,
    LOG_CREEP_MAX_MODES,
    LOG_CREEP_MODES_PER_DECADE,
    Creep,
    creep_time_constants,
    log_creep_time_constants,
)
from .creep import CREEP_STEP_HOLD as CREEP_STEP_HOLD
from .creep import LOG_CREEP_MODE_WEIGHT as LOG_CREEP_MODE_WEIGHT
from .creep import LOG_CREEP_REACH as LOG_CREEP_REACH
from .incomplete_reset import IncompleteReset, incomplete_reset_strain
from .initial_state import InitialState
from .lag import Lag, delayed_lowpass
from .rate_width import RateWidth, drive_rate, rate_threshold_scale
from .sensor_drift import SensorDrift
from .thermal import REFERENCE_CURRENT, Thermal, thermal_rise
from .training import Training, accumulated_travel, training_fade

__all__ = [
    "LOG_CREEP_MAX_MODES",
    "Lag",
    "Training",
    "RateWidth",
    "InitialState",
    "Creep",
    "Thermal",
    "SensorDrift",
    "IncompleteReset",
    "first_order_lowpass",
    "delayed_lowpass",
    "log_creep_time_constants",
    "incomplete_reset_strain",
    "creep_time_constants",
    "thermal_rise",
    "accumulated_travel",
    "drive_rate",
    "rate_threshold_scale",
    "training_fade",
    "REFERENCE_CURRENT",
    "CREEP_MODES",
    "LOG_CREEP_MODES_PER_DECADE",
]

#: The library's effects in the canonical order (input stage, state, output stage; within
#: a stage, the order of application), registered in :data:`EFFECTS` in this order.
LIBRARY = tuple(
    register_effect(effect)
    for effect in (Lag, Training, RateWidth, InitialState, IncompleteReset, Creep, Thermal, SensorDrift)
)

"""What an export holds: the model, one parameter vector, its provenance, and the refusals.

:func:`export_spec` checks that every effect of the model can be stepped sample by sample
by the C code (:data:`C_EFFECTS`) and inverted as :mod:`model.inverse` inverts it, and
refuses the others by name with the reason (:data:`REFUSED`), never dropping one silently.
Pure: no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from model import EFFECTS, THETA_NAMES, Model
from model.effects import CREEP_MODES, LOG_CREEP_MAX_MODES, creep_time_constants, log_creep_time_constants
from model.inverse import SUPPORTED_EFFECTS

__all__ = [
    "ExportError",
    "ExportSpec",
    "C_EFFECTS",
    "REFUSED",
    "HORIZON_EFFECTS",
    "export_spec",
]

#: effect -> the parameters the C step knows, by name (the fields of ``msma_params``).
C_EFFECTS = {
    "lag": ("lag_tau", "lag_delay"),
    "training": (
        "training_deficit",
        "training_threshold",
        "training_travel",
        "training_shape",
        "training_gain",
        "training_width",
    ),
    "initial_state": (
        "initial_state_memory",
        "initial_state_excursion",
        "initial_state_held",
        "initial_state_held_slope",
    ),
    "creep": (
        "creep_amplitude",
        "creep_tau",
        "creep_decades",
        "creep_log_rate",
        "creep_log_onset",
        "creep_log_hold",
    ),
    "thermal": (
        "thermal_tau",
        "thermal_sensitivity",
        "thermal_expansion",
        "thermal_tau_core",
        "thermal_sensitivity_core",
        "thermal_expansion_core",
        "thermal_initial",
        "thermal_initial_core",
    ),
    "sensor_drift": (
        "sensor_drift_linear",
        "sensor_drift_quadratic",
        "sensor_drift_settling",
        "sensor_drift_settling_tau",
        "sensor_drift_ambient_sine",
        "sensor_drift_ambient_cosine",
        "sensor_drift_ambient_period",
    ),
}

#: effect -> why it is not exported (an effect of the library outside :data:`C_EFFECTS`).
REFUSED = {
    "incomplete_reset": (
        "its extra strain is normalised by the record's largest strain excursion, known only at the "
        "record's end, and it keeps a stack of reset levels that grows with the record: no fixed-memory "
        "stream reproduces it"
    ),
    "rate_width": (
        "model.inverse has no inverse step for it (compensate refuses it too), so no compensator can be "
        "built from this model"
    ),
}

#: The C arrays' sizes for the creep modes (``MSMA_CREEP_MODES``, ``MSMA_LOG_CREEP_MAX_MODES`` in
#: ``c/msma_gpi.h.in``), checked against the library's constants before an export.
C_CREEP_MODES = 9
C_LOG_CREEP_MODES = 24

#: Effects whose streaming form needs the run's length (``horizon``): the logarithmic creep's
#: modes reach ten times the record's duration, the sensor drift's time is normalised by it.
HORIZON_EFFECTS = ("creep", "sensor_drift")


class ExportError(ValueError):
    """A study or model that cannot be exported; the message is one line naming it and why."""


@dataclass(frozen=True)
class ExportSpec:
    """One parameter vector of a model, ready to be written as C and FMUs.

    Attributes
    ----------
    model : Model
    values : dict
        ``{name: value}`` for every parameter of ``model`` (:attr:`Model.names` order).
    units : dict
        ``{"input": ..., "output": ...}``: the drive's and the displacement's units.
    horizon : float
        The run's length [s] for the effects of :data:`HORIZON_EFFECTS`.
    current_range : (float, float)
        The compensator's default current limits.
    output_scale : float
        The compensator's default output scale (the root find's rounding tolerance).
    provenance : dict
        What the parameters are and where they come from (JSON-ready).
    notes : list of str
    """

    model: Model
    values: dict
    units: dict
    horizon: float
    current_range: tuple
    output_scale: float
    provenance: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    @property
    def n_operators(self) -> int:
        return self.model.n_operators

    @property
    def effects(self) -> tuple:
        return self.model.effect_names

    def units_of(self) -> dict:
        """``{name: unit}`` of every parameter."""
        return {p.name: p.unit for p in self.model.parameters}

    def descriptions(self) -> dict:
        """``{name: description}`` of every parameter."""
        return {p.name: p.description for p in self.model.parameters}

    def uses_horizon(self) -> bool:
        return any(e in self.effects for e in HORIZON_EFFECTS)

    def creep_constants(self):
        """``(mode taus (9,), logarithmic taus (24,) padded with 0, their count)``: the creep modes' time
        constants as :mod:`model.effects` computes them, with :attr:`horizon` as the record's duration (the
        C takes these values, so its filters are the Python model's to the bit)."""
        values = self.values if "creep" in self.effects else EFFECTS["creep"].off
        modes = creep_time_constants(values["creep_tau"], values["creep_decades"])[0]
        taus, counts = log_creep_time_constants(np.array([values["creep_log_onset"]]), self.horizon)
        count = int(counts[0])
        logs = np.zeros(C_LOG_CREEP_MODES)
        logs[:count] = taus[0, :count]
        return modes, logs, count

    def c_values(self) -> dict:
        """Every field of ``msma_params`` the C code reads: the model's values, and for an effect
        the model lacks its ``off`` values (its flag is 0, so they are not read)."""
        out = {name: self.values[name] for name in THETA_NAMES}
        for effect, names in C_EFFECTS.items():
            off = EFFECTS[effect].off if effect in EFFECTS else {}
            for name in names:
                out[name] = self.values[name] if effect in self.effects else float(off.get(name, 0.0))
        return out


def _refusals(model: Model, values: dict) -> list[str]:
    """One line per effect the export cannot stream or invert, naming it and the reason."""
    refused = []
    for effect in model.effect_names:
        names = tuple(model.names[model.effect_slice(effect)])
        if effect not in C_EFFECTS:
            reason = REFUSED.get(effect, "the C export has no streaming step for it")
            refused.append(f"{effect}: {reason}")
        elif set(names) != set(C_EFFECTS[effect]):
            unknown = sorted(set(names) ^ set(C_EFFECTS[effect]))
            refused.append(f"{effect}: its parameters {unknown} are not those the C step knows")
        elif effect not in SUPPORTED_EFFECTS:
            refused.append(f"{effect}: model.inverse has no inverse step for it")
        elif effect == "lag" and values["lag_delay"] != 0.0:
            refused.append(
                f"lag: its dead time lag_delay = {values['lag_delay']:.6g} s: the current at a sample acts on the "
                "output only a dead time later, which no per-sample inverse reaches (model.inverse refuses it "
                "too); a study pins it at 0 where the record does not support it"
            )
    return refused


def export_spec(
    model: Model,
    theta,
    *,
    units=None,
    horizon: float,
    current_range=(0.0, 5.0),
    output_scale: float = 1.0,
    provenance=None,
    notes=(),
) -> ExportSpec:
    """The :class:`ExportSpec` of ``model`` at the parameter vector ``theta``.

    Raises
    ------
    ExportError
        An effect that cannot be streamed or inverted (each named with its reason, in one
        line), a non-finite parameter, a horizon or current range that is not a number.
    """
    theta = np.asarray(theta, dtype=float)
    values = model.theta_dict(theta)
    bad = [name for name, value in values.items() if not math.isfinite(value)]
    if bad:
        raise ExportError(f"the parameters {bad} are not finite")
    refused = _refusals(model, values)
    if refused:
        raise ExportError("cannot export " + "; ".join(refused))
    horizon = float(horizon)
    if not (math.isfinite(horizon) and horizon > 0.0):
        raise ExportError(f"the horizon must be a duration > 0 s, got {horizon!r}")
    if CREEP_MODES != C_CREEP_MODES:  # pragma: no cover - the library's constant and the C arrays
        raise ExportError(f"creep: {CREEP_MODES} saturating modes, the C step has {C_CREEP_MODES}")
    if LOG_CREEP_MAX_MODES != C_LOG_CREEP_MODES:  # pragma: no cover - likewise
        raise ExportError(f"creep: up to {LOG_CREEP_MAX_MODES} logarithmic modes, the C step has {C_LOG_CREEP_MODES}")
    lo, hi = (float(x) for x in current_range)
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ExportError(f"the current range must be LO < HI, got {lo:g}:{hi:g}")
    output_scale = float(output_scale)
    if not (math.isfinite(output_scale) and output_scale > 0.0):
        raise ExportError(f"the output scale must be > 0, got {output_scale!r}")
    return ExportSpec(
        model=model,
        values=values,
        units=dict(units or {"input": "A", "output": "um"}),
        horizon=horizon,
        current_range=(lo, hi),
        output_scale=output_scale,
        provenance=dict(provenance or {}),
        notes=list(notes),
    )

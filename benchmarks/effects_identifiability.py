"""Do the effects' general forms create an exact degeneracy with the GPI? Jacobian ranks on the paper's input.

Run from the repository root::

    python benchmarks/effects_identifiability.py [--fs 100]

For each effect at a typical "on" setting of its general form (every extra term on), on
the paper's input (literal reading, Table 1, alpha pinned as the fits pin it), the
Jacobian of the model output with respect to every free parameter (central differences,
each column scaled by the parameter's size, ``max(|theta|, 0.01)``, and by 1/sqrt(T)) is
computed, and printed:

* ``sv_min/sv_max`` of the whole GPI + effect Jacobian, against the plain GPI's own
  (the GPI has near-degenerate directions of its own: 1e-7 or so);
* the effect's columns projected out of the GPI's column span: the smallest singular value
  of that projection relative to the effect columns' own size (``indep``). An exact
  reparametrisation of the GPI (``initial_state``'s level, freed here: the positive control) gives round-off
  (1e-8 or less); an effect the GPI cannot imitate in any direction gives a value of order
  1e-3 to 1; the smallest says which combination of the effect is least separable from the
  GPI, and the "worst direction" lists its largest parameter loadings;
* the same projection within the effect (each effect parameter against the GPI *and* the
  effect's other parameters): the parameter that trades off most.

An effect parameter a row does not set is pinned at its off value (a row of an effect's
simpler form leaves its general form's extra terms off). Then, for the pairs of
:data:`PAIRS` (two first-cycle effects, both at their rows' settings, in one model): the
smallest singular value of both effects' columns together after projecting out the GPI's
span (``joint``) and its direction, and each effect's columns after projecting out the GPI
*and* the other effect's (how much of it the other cannot take over), with its own worst
direction.
"""

from __future__ import annotations

import argparse

import numpy as np

from identify.fitting.parametrisation import normalised_model
from model import TABLE1, Model, paper_current

#: typical "on" settings of the general forms (every term of the general form on); a row's
#: effect is the first word of its label
SETTINGS = {
    "lag": {"lag_tau": 0.02, "lag_delay": 0.03},
    "rate_width": {"rate_width_coefficient": 0.1, "rate_width_saturation": 1.0},
    "training": {
        "training_deficit": 0.08,
        "training_threshold": 0.1,
        "training_travel": 2.0,
        "training_shape": 1.5,
        "training_gain": 0.05,
        "training_width": 0.2,
    },
    "initial_state (level freed: the control)": {"initial_state_memory": -0.5},
    "initial_state": {"initial_state_excursion": 2.0, "initial_state_held": 0.3, "initial_state_held_slope": 0.2},
    "incomplete_reset": {
        "incomplete_reset_strain": 5.0,
        "incomplete_reset_retained": 0.5,
        "incomplete_reset_fade": 0.05,
    },
    "incomplete_reset (loading shape: drive share 0.3, p 0.6)": {
        "incomplete_reset_strain": 5.0,
        "incomplete_reset_retained": 0.5,
        "incomplete_reset_fade": 0.05,
        "incomplete_reset_drive": 0.3,
        "incomplete_reset_shape": 0.6,
    },
    "incomplete_reset (stroke: b 1)": {
        "incomplete_reset_strain": 5.0,
        "incomplete_reset_retained": 0.5,
        "incomplete_reset_fade": 0.05,
        "incomplete_reset_stroke": 1.0,
    },
    "incomplete_reset (step in the drive: m 1, c 0.55, k 12)": {
        "incomplete_reset_strain": 5.0,
        "incomplete_reset_retained": 0.5,
        "incomplete_reset_fade": 0.05,
        "incomplete_reset_drive": 1.0,
        "incomplete_reset_shape": 1.0,
        "incomplete_reset_onset": 0.55,
        "incomplete_reset_sharpness": 12.0,
    },
    "creep": {
        "creep_amplitude": 0.02,
        "creep_tau": 2.0,
        "creep_decades": 2.0,
        "creep_log_rate": 0.005,
        "creep_log_onset": 0.1,
        "creep_log_hold": 0.5,
    },
    "thermal": {
        "thermal_tau": 10.0,
        "thermal_sensitivity": 0.03,
        "thermal_expansion": 1.0,
        "thermal_tau_core": 200.0,
        "thermal_sensitivity_core": 0.03,
        "thermal_expansion_core": 1.0,
    },
    "sensor_drift": {
        "sensor_drift_linear": 1.0,
        "sensor_drift_quadratic": 0.5,
        "sensor_drift_settling": 1.0,
        "sensor_drift_settling_tau": 10.0,
        "sensor_drift_ambient_sine": 1.0,
        "sensor_drift_ambient_cosine": 0.5,
        "sensor_drift_ambient_period": 120.0,
    },
}


#: pairs of rows of :data:`SETTINGS` measured together (first-cycle effects that trade off)
PAIRS = (
    ("incomplete_reset (step in the drive: m 1, c 0.55, k 12)", "training"),
    ("incomplete_reset (step in the drive: m 1, c 0.55, k 12)", "initial_state"),
    ("incomplete_reset (loading shape: drive share 0.3, p 0.6)", "training"),
    ("incomplete_reset (loading shape: drive share 0.3, p 0.6)", "initial_state"),
    ("incomplete_reset (stroke: b 1)", "training"),
    ("incomplete_reset (stroke: b 1)", "initial_state"),
    ("incomplete_reset", "training"),
    ("incomplete_reset", "initial_state"),
)


def configured(plain: Model, labels, theta0):
    """``(model, theta, values)``: ``plain`` with the effects of the rows ``labels``, their
    parameters set by the rows (freed where pinned by default) and every effect parameter a
    row does not set pinned at its off value."""
    model = plain
    values = {}
    for label in labels:
        model = model + label.split()[0]
        values |= SETTINGS[label]
    parameters = model.parameters
    for effect in model.effects:
        for parameter in effect.parameters:
            if parameter.name in values:  # freed where pinned by default (initial_state's level: the control)
                parameters = parameters.replace(parameter.name, vary=True)
            else:
                parameters = parameters.replace(parameter.name, value=float(effect.off[parameter.name]), vary=False)
    model = model.with_parameters(parameters)
    theta = model.theta_from_dict(dict(zip(plain.names, theta0)) | values)
    return model, theta, values


def loadings(model, free, cols, vector, count=3) -> str:
    order = np.argsort(-np.abs(vector))[:count]
    return ", ".join(f"{model.names[free[cols[k]]]} {vector[k]:+.2f}" for k in order)


def jacobian(model: Model, theta, time, current, free):
    scales = np.maximum(np.abs(theta[free]), 0.01)
    steps = 1e-5 * scales
    rows = []
    for j, column in enumerate(free):
        for sign in (1.0, -1.0):
            row = theta.copy()
            row[column] += sign * steps[j]
            rows.append(row)
    y = model(np.array(rows), time, current)
    jac = (y[0::2] - y[1::2]).T / (2.0 * steps)
    return jac * scales / np.sqrt(time.size)


def projected_sv(basis_matrix, columns):
    """Singular values of ``columns`` after projecting out span(``basis_matrix``), relative to their own norms."""
    u, s, _ = np.linalg.svd(basis_matrix, full_matrices=False)
    u = u[:, s > 1e-12 * s[0]]
    norms = np.linalg.norm(columns, axis=0)
    c = columns / np.where(norms > 0, norms, 1.0)
    rest = c - u @ (u.T @ c)
    _, sv, vt = np.linalg.svd(rest, full_matrices=False)
    return sv, vt


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fs", type=float, default=100.0)
    parser.add_argument("--only", default="", help="only rows and pairs whose label contains this text")
    args = parser.parse_args(argv)
    time, current = paper_current(args.fs)
    plain = normalised_model(Model())
    theta0 = plain.default_theta(TABLE1)
    free0 = np.flatnonzero(plain.parameters.vary)
    j0 = jacobian(plain, theta0, time, current, free0)
    s0 = np.linalg.svd(j0, compute_uv=False)
    print(
        f"paper input, {time.size} samples; plain GPI: {free0.size} free parameters, sv_min/sv_max {s0[-1] / s0[0]:.2e}"
    )
    print(
        f"| effect | free | sv_min/sv_max (GPI alone {s0[-1] / s0[0]:.1e}) | indep (effect vs GPI) | worst direction "
        "| least separable parameter (vs GPI + rest of effect) |"
    )
    print("|---|---|---|---|---|---|")
    for label in SETTINGS:
        if args.only not in label:
            continue
        model, theta, values = configured(plain, [label], theta0)
        free = np.flatnonzero(model.parameters.vary)
        jac = jacobian(model, theta, time, current, free)
        s = np.linalg.svd(jac, compute_uv=False)
        effect_cols = [i for i, c in enumerate(free) if model.names[c] in values]
        gpi_cols = [i for i, c in enumerate(free) if model.names[c] not in values]
        sv, vt = projected_sv(jac[:, gpi_cols], jac[:, effect_cols])
        worst = loadings(model, free, effect_cols, vt[-1])
        per_param = []
        for k in range(len(effect_cols)):
            others = gpi_cols + [effect_cols[m] for m in range(len(effect_cols)) if m != k]
            sv_k, _ = projected_sv(jac[:, others], jac[:, [effect_cols[k]]])
            per_param.append((sv_k[0], model.names[free[effect_cols[k]]]))
        least = min(per_param)
        print(
            f"| {label} | {len(effect_cols)} | {s[-1] / s[0]:.1e} | {sv[-1]:.1e} (largest {sv[0]:.2f}) | {worst} | "
            f"{least[1]} {least[0]:.1e} |"
        )
    print()
    print(
        "| pair A + B | joint indep (both vs GPI) | joint worst direction | A vs GPI + B | its worst direction "
        "| B vs GPI + A | its worst direction |"
    )
    print("|---|---|---|---|---|---|---|")
    for first, second in PAIRS:
        if args.only not in first + second:
            continue
        model, theta, values = configured(plain, [first, second], theta0)
        free = np.flatnonzero(model.parameters.vary)
        jac = jacobian(model, theta, time, current, free)
        a_cols = [i for i, c in enumerate(free) if model.names[c] in SETTINGS[first]]
        b_cols = [i for i, c in enumerate(free) if model.names[c] in SETTINGS[second]]
        gpi_cols = [i for i, c in enumerate(free) if model.names[c] not in values]
        both = a_cols + b_cols
        sv, vt = projected_sv(jac[:, gpi_cols], jac[:, both])
        sv_a, vt_a = projected_sv(jac[:, gpi_cols + b_cols], jac[:, a_cols])
        sv_b, vt_b = projected_sv(jac[:, gpi_cols + a_cols], jac[:, b_cols])
        print(
            f"| {first} + {second} | {sv[-1]:.1e} | {loadings(model, free, both, vt[-1], 4)} | {sv_a[-1]:.1e} | "
            f"{loadings(model, free, a_cols, vt_a[-1])} | {sv_b[-1]:.1e} | {loadings(model, free, b_cols, vt_b[-1])} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

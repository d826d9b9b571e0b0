"""Slow statistical tests of the diagnosis on the virtual bench (``python -m pytest -m slow``).

* Confusion matrix (true effect x verdict) over seeds: every library effect hidden alone
  at about twice the noise in RMS, clean records, and three effects outside the library.
  A hidden effect is named, or tied with it listed beside a rival the noiseless oracle
  (:mod:`identify.bench.oracle`) does not class as separated from it. Printed.
* No false alarm on clean records over many seeds.
* Other functional forms of the same physics (logarithmic creep, a thermal law with two
  time constants, a second-order lag, an exponentially settling drift) are named as
  their library counterpart.
* Two hidden effects found one after the other, converging to ``adequate``, including
  creep + thermal at 2 sigma each (thermal absorbs half of creep's visible part, leaving
  0.21 sigma, which the omnibus noise tests miss on some seeds; the targeted refit of the
  screened candidates finds it).
* Visible sizes: what the best plain GPI leaves of each hidden effect, noise-free.

Sizes: the hidden effect's noise-free contribution has an RMS of about 2 noise sigmas
(sigma = 0.5 um) relative to the plain GPI at the same parameters (the bench's
``effect_size.rms_over_noise_sigma``); the GPI's refit absorbs part of it, so what the
diagnosis sees is smaller: the *visible* size, the RMS over the energised part of the
best plain-GPI fit's residual to the noise-free record (measured at seed 0: thermal
0.54, creep 0.45, lag 0.51, sensor_drift 0.70 sigma). ``initial_state`` (virgin start,
z0 = -20: 293 sigma against the plain GPI at the same parameters) is an exact
reparametrisation of the plain GPI (visible size ~1e-13 sigma, round-off; the proof is in
:data:`identify.diagnosis.reparametrisation.GPI_EQUIVALENTS`): no diagnosis can name it,
and the right verdict is ``adequate`` (the effect's prior excursion is screened and explains nothing).
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from identify.bench import simulate
from identify.bench.oracle import separability
from identify.data.records import Record
from identify.diagnosis import diagnose, fit_baseline
from identify.fitting.noise import NoiseModel
from identify.fitting.parametrisation import normalised_model
from model import TABLE1, Model, gpi
from model.effects import accumulated_travel, first_order_lowpass

pytestmark = pytest.mark.slow

SIGMA = 0.5
#: Library effects at ~2 sigma RMS (scaled from the effects' test parameters by the bench's
#: measured effect RMS at seed 0: thermal 5.32, creep 6.53, lag 7.87, drift 3.62 sigma).
HIDDEN = {
    "thermal": "thermal_sensitivity=0.030,thermal_expansion=1.13",
    "creep": "creep_amplitude=0.0153",
    "lag": "lag_tau=0.0127",
    "sensor_drift": "sensor_drift_linear=1.10,sensor_drift_quadratic=0.83",
    # a first-cycle deficit of 8 % of the drive fading over V0 = 2 A of travel (exponential):
    # 1.94 sigma RMS against the plain GPI at the same parameters (test parameters otherwise)
    "training": "training_deficit=0.08",
    # every threshold times 1 + b |du/dt|: 1.97 sigma RMS against the plain GPI at the same
    # parameters (paper input, 100 Hz, Table 1; 2.74 sigma at b = 0.05 s/A, linear in b here)
    "rate_width": "rate_width_coefficient=0.018",
}
OUTSIDE = ("interference", "deadzone", "signflip")
SEEDS = (11, 12, 13, 14, 15)


def outside_record(kind: str, seed: int) -> Record:
    """A bench record with an effect no library candidate can represent.

    ``interference``: pickup from the energised coil driver, 1 um at 3.7 Hz (unrelated to
    the 0.1 Hz drive), only while current flows. ``deadzone``: a 2 um backlash between
    the transducer and the sensor (the sensor follows only after the gap is taken up).
    ``signflip``: an offset of 1.5 um while the current exceeds 4 A whose sign flips from
    one cycle to the next.
    """
    sim = simulate(None, seed=seed, noise_sigma=SIGMA)
    t, i = sim.record.time, sim.record.current
    y = sim.record.displacement.copy()
    if kind == "interference":
        y += np.where(i > 0, np.sin(2 * np.pi * 3.7 * t + 0.3), 0.0)
    elif kind == "deadzone":
        out = np.empty_like(sim.clean)
        z = sim.clean[0]
        for k, c in enumerate(sim.clean):
            z = c - 1.0 if c > z + 1.0 else (c + 1.0 if c < z - 1.0 else z)
            out[k] = z
        y += out - sim.clean
    elif kind == "signflip":
        y += np.where(i > 4.0, 1.5 * (-1.0) ** np.floor((t - 10.0) / 10.0), 0.0)
    else:  # pragma: no cover - test bug
        raise ValueError(kind)
    return Record(t, i, y, source=f"outside-library effect {kind!r} (seed {seed})", sha256="")


def _amount_for_size(clean_of, plain, size: float, upper: float) -> float:
    """The amount at which ``clean_of(amount)`` differs from ``plain`` by ``size`` noise sigmas RMS
    (root finding between 1e-4 and ``upper``): an effect nonlinear in its amount is sized by its
    own parameter, not by scaling its output."""
    from scipy.optimize import brentq

    return brentq(
        lambda amount: np.sqrt(np.mean((clean_of(amount) - plain) ** 2)) / SIGMA - size, 1e-4, upper, xtol=1e-6
    )


def alternative_record(kind: str, seed: int, size: float = 3.0) -> Record:
    """A record whose hidden effect follows another functional form of a library effect's physics.

    ``log_creep``: ``y = y_g + g sum_k dy_g(t_k) log10(1 + (t - t_k)/0.05 s)`` (logarithmic
    creep, no saturation; library: saturating mode spectrum). ``thermal2``: heating through
    two time constants, 8 s (60 %) and 120 s (40 %) (library: one). ``lag2``: the field
    through two cascaded first-order lags of 6 ms, a critically damped second-order lag
    (library: first order). ``exp_drift``: ``D (1 - exp(-t / 25 s))`` (library: quadratic).
    ``rate_saturating``: every threshold times ``1 + a tanh(|di/dt| / 1 A/s)``, a viscous
    friction that saturates at high rates, the rate by central differences (library: linear,
    or logarithmic above a rate, in the rate of the step into each sample); its amplitude
    ``a`` is found by root finding (the GPI is not linear in its thresholds). The others are
    scaled to ``size`` noise sigmas RMS.
    """
    sim = simulate(None, seed=seed, noise_sigma=SIGMA)
    t, i, plain = sim.record.time, sim.record.current, sim.plain
    noise = sim.record.displacement - sim.clean
    if kind == "log_creep":
        shape = np.convolve(np.diff(plain, prepend=plain[0]), np.log10(1.0 + (t - t[0]) / 0.05))[: t.size]
    elif kind == "thermal2":
        heat = (i / 5.0) ** 2
        rise = 0.6 * first_order_lowpass(t, heat, 8.0, 0.0)[0] + 0.4 * first_order_lowpass(t, heat, 120.0, 0.0)[0]
        shape = 40.0 * rise - plain * rise
    elif kind == "lag2":
        shape = gpi(TABLE1, first_order_lowpass(t, first_order_lowpass(t, i, 0.006)[0], 0.006)[0]) - plain
    elif kind == "exp_drift":
        shape = 1.0 - np.exp(-(t - t[0]) / 25.0)
    elif kind == "rate_saturating":  # nonlinear in its amplitude: the amplitude is sized, not the output scaled
        rate = np.abs(np.gradient(i, t))

        def clean_of(amount):
            return gpi(TABLE1, i, threshold_scale=1.0 + amount * np.tanh(rate / 1.0))

        clean = clean_of(_amount_for_size(clean_of, plain, size, 1.0))
        return Record(t, i, clean + noise, source=f"alternative form {kind!r} (seed {seed})", sha256="")
    else:  # pragma: no cover - test bug
        raise ValueError(kind)
    scale = size * SIGMA / np.sqrt(np.mean(shape**2))
    return Record(t, i, plain + scale * shape + noise, source=f"alternative form {kind!r} (seed {seed})", sha256="")


def _case_record(case: str, seed: int) -> Record:
    if case in HIDDEN:
        return simulate(HIDDEN[case], seed=seed, noise_sigma=SIGMA).record
    if case == "initial_state":
        return simulate("initial_state_memory=-20", seed=seed, noise_sigma=SIGMA).record
    if case == "none":
        return simulate(None, seed=seed, noise_sigma=SIGMA).record
    return outside_record(case, seed)


#: visible size of HIDDEN["training"] (seed 0, noise-free, best plain GPI), in sigmas: measured
#: with visible_size at a5ea29a (1.94 sigma against the plain GPI at the same parameters)
VISIBLE_TRAINING = 1.42
#: wall time of each diagnosis in the confusion matrix [s]
WALL_SECONDS: dict = {}
CASES = tuple(HIDDEN) + ("initial_state", "none") + OUTSIDE
VERDICTS = tuple(HIDDEN) + ("initial_state", "adequate", "tied", "unexplained")


@pytest.fixture(scope="module")
def confusion():
    """Diagnose every case x seed once: ``{(case, seed): Diagnosis}``."""
    results = {}
    for seed in SEEDS:
        for case in CASES:
            record = _case_record(case, seed)
            started = time.perf_counter()
            results[case, seed] = diagnose(record, rng=np.random.default_rng(seed))
            WALL_SECONDS[case, seed] = time.perf_counter() - started
    return results


def _verdict(d) -> str:
    return d.missing if d.status == "missing_effect" else d.status


def format_confusion(results) -> str:
    """The confusion matrix as a Markdown table (rows: truth, columns: verdict)."""
    header = "| true effect \\ verdict | " + " | ".join(VERDICTS) + " | other |"
    lines = [header, "|" + "---|" * (len(VERDICTS) + 2)]
    for case in CASES:
        counts = {v: 0 for v in VERDICTS}
        other = 0
        for (c, _), d in results.items():
            if c == case:
                v = _verdict(d)
                if v in counts:
                    counts[v] += 1
                else:
                    other += 1
        label = (
            case
            if case in HIDDEN or case == "none"
            else (
                "initial_state (virgin, z0 = -20; exact reparametrisation)"
                if case == "initial_state"
                else f"{case} (outside library)"
            )
        )
        lines.append(f"| {label} | " + " | ".join(str(counts[v]) for v in VERDICTS) + f" | {other} |")
    return "\n".join(lines)


def test_confusion_matrix(confusion, capsys):
    with capsys.disabled():
        print(f"\nDiagnosis confusion matrix over seeds {SEEDS} (sigma = {SIGMA} um, effects ~2 sigma RMS):")
        print(format_confusion(confusion))
        for (case, seed), d in sorted(confusion.items()):
            print(
                f"  {case:<14} seed {seed}: {_verdict(d):<14} RMS {d.rms / d.noise_sigma:.3f} sigma, "
                f"misfit {d.adequacy.size_ratio:.2f} sigma, {WALL_SECONDS[case, seed]:.0f} s"
            )
    for (case, seed), d in confusion.items():
        verdict = _verdict(d)
        if case in HIDDEN and verdict == case:
            # adding it brings the residual RMS to the noise level within 15 %
            assert abs(d.best.rms_after / d.noise_sigma - 1.0) < 0.15
            assert d.best.adequate_after
        elif case in HIDDEN:
            # not named: right only as a tie that lists it, beside a rival the noiseless oracle
            # does not class as separated from it (the data could not name it on most noise draws)
            assert d.status == "tied" and case in d.tied, f"{case} seed {seed}: diagnosed {verdict} ({d.reason})"
            sim = simulate(HIDDEN[case], seed=seed, noise_sigma=SIGMA)
            kinds = {
                other: separability(sim.record, sim.clean, [], case, other, rng=np.random.default_rng(seed)).kind
                for other in d.tied
                if other != case
            }
            with capsys.disabled():
                print(f"  {case} seed {seed}: tied; the oracle against each rival: {kinds}")
            assert any(k != "data separate" for k in kinds.values()), f"{case} seed {seed}: separable, tied {kinds}"
        elif case == "none":
            assert verdict == "adequate", f"clean seed {seed}: {verdict} ({d.reason})"
        elif case == "initial_state":
            # a constant initial memory is exactly a plain GPI with shifted offsets: the data
            # cannot tell, the verdict is "adequate" at the noise level; the effect is screened
            # through its prior excursion (its level is pinned), which explains nothing here
            assert verdict == "adequate", f"initial_state seed {seed}: {verdict} ({d.reason})"
            assert abs(d.rms / d.noise_sigma - 1.0) < 0.15
            entry = next(c for c in d.ranking if c.effect == "initial_state")
            assert entry.delta_bic < d.thresholds.bic_significant, f"initial_state seed {seed}: {entry}"
        else:  # physics outside the library: never a name (a tie of library effects names none)
            assert verdict in ("unexplained", "tied"), f"{case} seed {seed}: blamed {verdict} ({d.reason})"


def test_no_false_alarm_on_clean_records(capsys):
    seeds = range(100, 124)
    verdicts = []
    for seed in seeds:
        reading = "centred" if seed % 2 else "literal"
        rho = 0.3 if seed % 3 == 0 else 0.0
        record = simulate(None, seed=seed, noise_sigma=SIGMA, noise_rho=rho, input_reading=reading).record
        d = diagnose(record, rng=np.random.default_rng(seed))
        verdicts.append((seed, d.status, max(d.adequacy.z.values()), d.adequacy.size_ratio))
    with capsys.disabled():
        print("\nclean records (seed, verdict, largest z, misfit/sigma):", verdicts)
    assert all(status == "adequate" for _, status, _, _ in verdicts)


@pytest.mark.parametrize(
    "kind, expected",
    [
        ("log_creep", "creep"),
        ("thermal2", "thermal"),
        ("lag2", "lag"),
        ("exp_drift", "sensor_drift"),
        ("rate_saturating", "rate_width"),
    ],
)
def test_other_functional_forms_are_named_by_their_physics(kind, expected):
    """Named by its physics, or ``tied`` with it listed where the record does not separate it
    (the slow effects on the paper's drive); never another name."""
    d = diagnose(alternative_record(kind, seed=21), rng=np.random.default_rng(21))
    if d.status == "tied":
        assert any(expected in entry.split("+") for entry in d.tied), d.reason
        return
    assert d.status == "missing_effect" and d.missing == expected, d.reason
    # the library's general form absorbs the differently shaped physics (within 15 % of the noise)
    assert d.best.rms_after / d.noise_sigma < 1.15
    # the name holds: the explanation it rests on (the effect, or a pair with it) is ahead of
    # every compared explanation without it by more than the noise gives the gap
    rows = d.decision.numbers["rivals"]
    assert expected in d.decision.best.split("+") and rows, d.decision
    without = [g for g in rows if expected not in g["other"].split("+")]
    assert without and all(g["better"] == d.decision.best and g["z"] > d.thresholds.gap_z for g in without), rows


def training_alternative_drive(kind: str, current, size: float):
    """The drive of a first-cycle effect in another functional form than the library's.

    ``abrupt``: the virgin material lacks the fraction ``size`` of the drive until the first
    input reversal, then nothing (library: a fade in the accumulated travel).
    ``threshold_linear``: an extra threshold of ``size`` A (nothing moves below it) that fades
    linearly to 0 over the first 20 A of travel, two of the paper's early cycles.
    ``scale_linear``: a deficit of the fraction ``size`` fading linearly over 20 A of travel.
    """
    current = np.asarray(current, dtype=float)
    travel = accumulated_travel(current)[0]
    linear_fade = np.clip(1.0 - travel / 20.0, 0.0, None)
    if kind == "abrupt":
        first_reversal = int(np.argmax(np.diff(current) < 0))
        return np.where(np.arange(current.size) <= first_reversal, (1.0 - size) * current, current)
    if kind == "threshold_linear":
        return np.maximum(current - size * linear_fade, 0.0)
    if kind == "scale_linear":
        return current * (1.0 - size * linear_fade)
    raise ValueError(kind)  # pragma: no cover - test bug


def training_alternative_record(kind: str, seed: int, size: float = 3.0) -> Record:
    """A bench record with a first-cycle effect of another form (:func:`training_alternative_drive`)
    whose noise-free contribution has ``size`` noise sigmas RMS against the plain GPI (the
    effect's own parameter set to that size by root finding, not a scaled output)."""
    sim = simulate(None, seed=seed, noise_sigma=SIGMA)
    t, i, plain = sim.record.time, sim.record.current, sim.plain

    def clean_of(amount):
        return gpi(TABLE1, training_alternative_drive(kind, i, amount))

    clean = clean_of(_amount_for_size(clean_of, plain, size, 0.5 if kind != "threshold_linear" else 2.0))
    noise = sim.record.displacement - sim.clean
    return Record(t, i, clean + noise, source=f"first-cycle form {kind!r} (seed {seed})", sha256="")


@pytest.mark.parametrize("kind", ["abrupt", "threshold_linear", "scale_linear"])
def test_other_first_cycle_forms_point_to_training(kind, capsys):
    """Measured at seed 21, 3 sigma RMS: `training` explains 90-99 % of the misfit; RMS after
    1.125 (abrupt), 1.039 (threshold_linear), 1.039 (scale_linear) sigma; only the threshold
    form leaves an adequate residual and is named (the fade exp(-(V/V0)^p) is no step at the
    first reversal and no exact linear fade: about 0.2-0.4 sigma of structure remains, and a
    candidate that leaves structure is not named: `unexplained`, training the best candidate)."""
    d = diagnose(training_alternative_record(kind, seed=21), rng=np.random.default_rng(21))
    with capsys.disabled():
        print(
            f"\n{kind}: {d.status} {d.missing}, RMS {d.rms / d.noise_sigma:.3f} -> "
            f"{d.best.rms_after / d.noise_sigma:.3f} sigma, explained {d.best.explained:.2f}, "
            f"adequate after {d.best.adequate_after}, {d.best.parameters}"
        )
    assert d.best.effect == "training", d.reason
    assert d.best.rms_after / d.noise_sigma < 1.15
    assert d.best.explained > 0.75
    if d.best.adequate_after:
        assert d.status == "missing_effect" and d.missing == "training", d.reason
    else:
        assert d.status == "unexplained" and "'training' (delta BIC" in d.reason, d.reason


_ABSORBED = (
    "known failure (issue 16, docs/diagnosis.md 'Limits'): the general forms overlap on the paper's "
    "input, so one effect absorbs the other"
)


@pytest.mark.parametrize(
    "hidden",
    [
        ("lag", "sensor_drift"),
        ("thermal", "lag"),
        pytest.param(
            ("creep", "thermal"),
            marks=pytest.mark.xfail(
                strict=True,
                reason=f"{_ABSORBED}: with the first effect added the record is adequate, the second is not found",
            ),
        ),
    ],
)
def test_two_hidden_effects_are_found_one_after_the_other(hidden):
    record = simulate(",".join(HIDDEN[h] for h in hidden), seed=31, noise_sigma=SIGMA).record
    first = diagnose(record, rng=np.random.default_rng(31))
    assert first.status == "missing_effect" and first.missing in hidden, first.reason
    second = diagnose(record, [first.missing], rng=np.random.default_rng(31))
    other = (set(hidden) - {first.missing}).pop()
    # the second may sit at the margin (lag, then a drift that a warming tells apart only by
    # about 2.5 noise sd of the gap): named, or tied with the rival the data do not separate
    assert (second.status == "missing_effect" and second.missing == other) or (
        second.status == "tied" and other in second.tied
    ), second.reason
    final = diagnose(record, sorted(hidden), rng=np.random.default_rng(31))
    assert final.status == "adequate", final.reason
    assert first.rms > second.rms > final.rms
    assert abs(final.rms / final.noise_sigma - 1.0) < 0.15


def visible_size(spec: str, seed: int = 0) -> float:
    """RMS over the energised part of the best plain-GPI fit's residual to the noise-free
    record with the hidden effect ``spec``, in noise sigmas (the diagnosis' baseline fit)."""
    sim = simulate(spec, seed=seed, noise_sigma=0.0)
    fit = fit_baseline(
        sim.record, normalised_model(Model()), NoiseModel(sigma=SIGMA, source="user"), rng=np.random.default_rng(seed)
    )
    energised = sim.record.time >= 10.0
    return float(np.sqrt(np.mean(fit.residual[energised] ** 2)) / SIGMA)


def test_visible_sizes_of_the_hidden_effects(capsys):
    sizes = {case: visible_size(HIDDEN[case]) for case in HIDDEN}
    sizes["initial_state"] = visible_size("initial_state_memory=-20")
    with capsys.disabled():
        print(
            "\nvisible size (best plain GPI on the noise-free record, energised RMS / sigma):",
            {k: f"{v:.3g}" for k, v in sizes.items()},
        )
    # the library effects at ~2 sigma against the plain GPI leave 0.45-0.70 sigma after
    # the refit (seed 0, measured at c9fe905); a band of +-40 % around that. training leaves
    # more of its 1.94 sigma (measured VISIBLE_TRAINING): the GPI cannot bend its first branch
    # away from the later ones; a band of +-40 % around that
    for case in HIDDEN:
        if case == "training":
            assert 0.6 * VISIBLE_TRAINING < sizes[case] < 1.4 * VISIBLE_TRAINING, (case, sizes[case])
        else:
            assert 0.3 < sizes[case] < 1.0, (case, sizes[case])
    # a virgin initial state is reproduced by a plain GPI exactly (round-off only)
    assert sizes["initial_state"] < 1e-6

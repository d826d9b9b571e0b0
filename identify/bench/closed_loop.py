"""Closed loop on the virtual bench: identify, compensate, drive the TRUE transducer, score.

The measurement of issue 17's "how well" for compensation, end to end with the project's
own tools and nothing the user would not have:

1. a bench record of the paper's transducer with a hidden effect (:func:`identify.bench.simulate`,
   truth in its sidecar), or a given bench CSV with its sidecar;
2. :func:`identify.diagnosis.diagnose.diagnose` of the plain GPI on it; the effect it names is added;
3. ``python -m identify study RECORD --effects NAMED`` (the real command, in a subprocess as
   :mod:`identify.workflows.batch` runs it);
4. for targets the study never saw (:func:`bench_targets`: a triangle and a multi-sine within
   the reachable range), :func:`identify.workflows.use.compensate` gives the feedforward current;
5. the bench's **true** transducer (the sidecar's model and parameters, ``sensor_drift`` off:
   it is the sensor's, not the displacement's) is driven with that current, and the tracking
   error against the target is scored: RMS and max as % of the target's range, with
   compensation and with the best linear drive ``i = a y* + b`` (a, b chosen on the true
   transducer itself, the most favourable uncompensated baseline), and how often the
   predicted 95 % bands cover the realised error (credible band: the true displacement;
   predictive band: the realised error plus a fresh draw of the bench's sensor noise).

``benchmarks/closed_loop.py`` runs it over seeds; a slow test runs the bundled record.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time as _time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from model import Model

from ..commands import package_environment
from ..data.records import load_record, write_record
from ..diagnosis import diagnose
from ..workflows.use import Target, compensate, load_study, write_compensation
from .synthetic import sensor_noise, simulate

__all__ = [
    "bench_targets",
    "best_linear_drive",
    "ClosedLoopCase",
    "ClosedLoopResult",
    "closed_loop",
    "DEFAULT_BENCH_EFFECTS",
]

#: The hidden effect of the bundled ``data/bench_default.csv`` (its sidecar's command).
DEFAULT_BENCH_EFFECTS = "thermal_tau=30,thermal_sensitivity=0.08,thermal_expansion=1.5"


def bench_targets(fs: float = 100.0, duration: float = 64.0) -> dict:
    """Two targets unlike the paper's decaying sine, within Table 1's reachable 0-296 um.

    ``triangle``: 30 -> 270 -> 30 um, period 16 s (constant rate, sharp reversals);
    ``multisine``: ``150 + 60 sin(2 pi 0.05 t) + 35 sin(2 pi 0.13 t + 1) + 15 sin(2 pi 0.31 t + 2)`` um
    (nested minor loops). Both at ``fs`` over ``duration`` seconds, starting at ``t = 0``.
    """
    t = np.arange(0.0, duration, 1.0 / fs)
    phase = (t / 16.0) % 1.0
    triangle = 30.0 + 240.0 * np.where(phase < 0.5, 2 * phase, 2 - 2 * phase)
    multisine = (
        150.0
        + 60.0 * np.sin(2 * np.pi * 0.05 * t)
        + 35.0 * np.sin(2 * np.pi * 0.13 * t + 1.0)
        + 15.0 * np.sin(2 * np.pi * 0.31 * t + 2.0)
    )
    return {"triangle": Target(t, triangle, "triangle"), "multisine": Target(t, multisine, "multisine")}


def best_linear_drive(response, time, target, current_range, start):
    """The linear drive ``i = clip(a y* + b)`` minimising the RMS tracking error of ``response``.

    Parameters
    ----------
    response : callable(current) -> displacement, shape (T,)
        The transducer (here the bench's true one).
    time, target : ndarray, shape (T,)
    current_range : (float, float)
    start : (float, float)
        Starting ``(a, b)`` (e.g. the least-squares line of current on displacement of the
        training record).

    Returns
    -------
    (a, b, error) with ``error`` = response - target, shape (T,).
    """
    lo, hi = current_range

    def rms(p):
        return float(np.sqrt(np.mean((response(np.clip(p[0] * target + p[1], lo, hi)) - target) ** 2)))

    best = minimize(
        rms,
        np.asarray(start, dtype=float),
        method="Nelder-Mead",
        options={"xatol": 1e-7, "fatol": 1e-9, "maxiter": 2000},
    )
    a, b = (float(x) for x in best.x)
    return a, b, response(np.clip(a * target + b, lo, hi)) - target


@dataclass
class ClosedLoopCase:
    """One target's scores (all % are of the target's range)."""

    target: str
    rms_pct: float
    max_pct: float
    linear_rms_pct: float
    linear_max_pct: float
    linear_gain: float
    linear_offset: float
    credible_coverage: float
    predictive_coverage: float
    predicted_rms_pct: dict
    predicted_max_pct: dict
    model_samples: dict
    current_min: float
    current_max: float
    seconds: float


@dataclass
class ClosedLoopResult:
    """A whole run: what the diagnosis named, the study, the cases."""

    record: str
    seed: int | None
    diagnosis_status: str
    named: str | None
    effects: list
    study: str
    converged: bool
    cases: list = field(default_factory=list)
    seconds: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)


def _truth(sidecar: dict):
    model = Model.from_dict(sidecar["model"])
    theta = model.theta_from_dict(sidecar["theta"])
    if "sensor_drift" in model.effect_names:
        theta[model.effect_slice("sensor_drift")] = 0.0
    return model, theta


def closed_loop(
    out_dir,
    *,
    record=None,
    effects: str = DEFAULT_BENCH_EFFECTS,
    seed: int = 1,
    targets: dict | None = None,
    n_draws: int = 200,
    study_options=(),
    progress=None,
) -> ClosedLoopResult:
    """Run the closed loop (module docstring) in ``out_dir`` (resumable: a finished study is reused).

    Parameters
    ----------
    out_dir : path
    record : path, optional
        A bench CSV with its JSON sidecar (the truth); default: simulate one with
        ``effects`` and ``seed`` (0.5 um white noise, 100 Hz, the paper's input).
    effects : str
        Hidden effects of the simulated record (:func:`identify.bench.parse_effect_spec`).
    seed : int
        Noise seed of the simulated record, seed of the diagnosis and the study.
    targets : dict of name -> Target, optional
        Default :func:`bench_targets`.
    n_draws : int
    study_options : sequence of str
        Extra ``study`` options (e.g. ``("--max-steps", "20000")``).

    The steps: the record and its truth (:func:`_bench_record`), the diagnosis
    (:func:`_diagnosed`), the study of the named effect (:func:`_run_study`), and one
    compensation per target driven through the truth (:func:`_closed_loop_case`).
    """
    say = progress or (lambda message: None)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    seconds: dict[str, float] = {}
    record, data = _bench_record(out, record, effects, seed)
    truth = _truth(data.sidecar)
    clock = _time.perf_counter()
    status, named = _diagnosed(out, record, data, seed, say)
    seconds["diagnosis"] = _time.perf_counter() - clock
    clock = _time.perf_counter()
    study_dir = _run_study(out, record, [named] if named else [], seed, study_options, say)
    seconds["study"] = _time.perf_counter() - clock
    study = load_study(study_dir)
    noise = data.sidecar.get("noise", {})
    sigma, rho = float(noise.get("sigma", 0.5)), float(noise.get("rho", 0.0))
    start_line = np.polyfit(data.displacement, data.current, 1)
    cases = [
        _closed_loop_case(out, name, target, study, truth, seed, n_draws, (sigma, rho), start_line, say)
        for name, target in (targets or bench_targets()).items()
    ]
    result = ClosedLoopResult(
        record=str(record),
        seed=seed,
        diagnosis_status=status,
        named=named,
        effects=list(study.model.effect_names),
        study=str(study_dir),
        converged=study.converged,
        cases=cases,
        seconds=seconds,
    )
    (out / "closed_loop.json").write_text(json.dumps(result.to_dict(), indent=2) + "\n")
    return result


def _bench_record(out: Path, record, effects: str, seed: int):
    """``(path, Record)`` of the bench record (simulated into ``out/record.csv`` when none is
    given), refused without the truth in its JSON sidecar."""
    if record is None:
        record = out / "record.csv"
        if not record.exists():
            write_record(record, simulate(effects, seed=seed).record)
    record = Path(record)
    data = load_record(record)
    if not data.sidecar or "theta" not in data.sidecar:
        raise ValueError(f"{record}: a closed loop needs the bench's truth in the JSON sidecar")
    return record, data


def _diagnosed(out: Path, record: Path, data, seed: int, say) -> tuple[str, str | None]:
    """``(status, named effect)`` of the plain GPI's diagnosis, kept in ``out/diagnosis.json`` (reused when there)."""
    diagnosis_path = out / "diagnosis.json"
    if diagnosis_path.exists():
        found = json.loads(diagnosis_path.read_text())
        return found["status"], found["missing"]
    say(f"diagnosing the plain GPI on {record}")
    result = diagnose(data, rng=np.random.default_rng(seed), progress=False)
    status, named = result.status, result.missing
    diagnosis_path.write_text(json.dumps({"status": status, "missing": named, "rms": result.rms}, indent=2) + "\n")
    return status, named


def _run_study(out: Path, record: Path, chosen: list, seed: int, study_options, say) -> Path:
    """``out/study``: the study of the GPI with the ``chosen`` effects, run as ``python -m
    identify study`` in a subprocess (resumable); a chain not converged is a result all the same."""
    study_dir = out / "study"
    say(f"study with effects {chosen or 'none'} into {study_dir}")
    argv = [
        "study",
        str(record),
        "--out",
        str(study_dir),
        "--seed",
        str(seed),
        "--progress",
        "off",
        "--no-report",
        "--effects",
        ",".join(chosen) or "none",
        *study_options,
    ]
    completed = subprocess.run(
        [sys.executable, "-m", "identify", *argv], env=package_environment(), capture_output=True, text=True
    )
    not_converged = completed.returncode == 1 and "NOT CONVERGE" in completed.stderr  # a result all the same
    if completed.returncode != 0 and not not_converged:
        raise RuntimeError(f"study exited with {completed.returncode}:\n{completed.stdout}{completed.stderr}")
    return study_dir


def _closed_loop_case(
    out: Path, name: str, target, study, truth, seed: int, n_draws: int, noise: tuple, start_line, say
) -> ClosedLoopCase:
    """One target: the compensation (written to ``out/compensate-<name>``) driven through the
    truth, beside the best linear drive, with the coverage of the predicted bands."""
    truth_model, truth_theta = truth
    sigma, rho = noise
    clock = _time.perf_counter()
    say(f"compensating {name}")
    c = compensate(study, target, n_draws=n_draws, rng=np.random.default_rng(seed))
    write_compensation(c, out / f"compensate-{name}")
    t, y = target.time, target.displacement
    span = float(np.ptp(y))

    def response(current):
        return truth_model(truth_theta, t, current)

    realised = response(c.current) - y
    measured = realised + sensor_noise(np.random.default_rng(seed + 1000), t.size, sigma, rho)
    a, b, linear = best_linear_drive(response, t, y, c.current_range, start_line)
    te = c.summary["tracking_error"]
    return ClosedLoopCase(
        target=name,
        rms_pct=100 * float(np.sqrt(np.mean(realised**2))) / span,
        max_pct=100 * float(np.abs(realised).max()) / span,
        linear_rms_pct=100 * float(np.sqrt(np.mean(linear**2))) / span,
        linear_max_pct=100 * float(np.abs(linear).max()) / span,
        linear_gain=a,
        linear_offset=b,
        credible_coverage=float(np.mean((realised >= c.error_lo) & (realised <= c.error_hi))),
        predictive_coverage=float(np.mean((measured >= c.predictive_lo) & (measured <= c.predictive_hi))),
        predicted_rms_pct=te["rms_pct"],
        predicted_max_pct=te["max_abs_pct"],
        model_samples=c.summary["model_tracking"]["samples"],
        current_min=float(c.current.min()),
        current_max=float(c.current.max()),
        seconds=_time.perf_counter() - clock,
    )

"""Build a small but real results folder with the real ``study`` command, for the report tests.

:func:`build_results_folder` simulates a short record and runs
``python -m identify study`` on it in-process (:func:`identify.cli.main`) with a tiny
step cap, so the folder is exactly what users get (docs/CONTRACTS.md) and the report at
its end is written by the same code path as theirs:

1. the paper's input (eqs. 14-17) at a low sampling rate; Table 1 through the GPI
   (:class:`model.Model`); Gaussian sensor noise of known sigma; optionally a hidden
   ripple the model cannot represent (a misfit); written with
   :func:`identify.data.records.write_record` as ``record.csv`` beside the results folder;
2. ``study record.csv --out DIR`` with one least-squares start and a step cap far below
   convergence, so ``summary["posterior"]["converged"]`` is False.

The CSV and the folder's ``data.npz`` hold the same record; ``manifest.json`` names the CSV.
"""

from __future__ import annotations

import contextlib
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import model
from identify.cli import main as identify_main
from identify.data.records import write_record

__all__ = ["FixtureSettings", "simulate_record", "build_results_folder"]


@dataclass(frozen=True)
class FixtureSettings:
    """What the fixture simulates and how long the study samples.

    Parameters
    ----------
    sampling_rate : float, default 10.0
        Hz; 70 s give 701 samples.
    noise_sigma : float, default 0.5
        Sensor noise standard deviation [um].
    hidden_ripple : float, default 0.0
        Amplitude [um] of a 0.37 Hz sinusoid added to the energised part of the data
        but not to the model; > 0 makes a misfit (residual RMS above the noise) that the
        GPI cannot absorb.
    free_noise : bool, default False
        ``--noise-sigma free``: sample sigma instead of taking it from the quiet segment.
    n_walkers : int, default 40
    max_steps : int, default 160
        The study's step cap (far below convergence).
    seed : int, default 1
        Seeds the simulated noise and the study.
    """

    sampling_rate: float = 10.0
    noise_sigma: float = 0.5
    hidden_ripple: float = 0.0
    free_noise: bool = False
    n_walkers: int = 40
    max_steps: int = 160
    seed: int = 1


def simulate_record(path, settings: FixtureSettings = FixtureSettings()) -> Path:
    """Write the simulated record (CSV ``time,current,displacement``) to ``path``."""
    rng = np.random.default_rng(settings.seed)
    time, current = model.paper_current(fs=settings.sampling_rate)
    clean = model.Model()(model.TABLE1, time, current)
    ripple = np.where(current != 0.0, settings.hidden_ripple * np.sin(2 * np.pi * 0.37 * time), 0.0)
    displacement = clean + ripple + settings.noise_sigma * rng.standard_normal(time.size)
    path = Path(path)
    write_record(path, (time, current, displacement))
    return path


def build_results_folder(directory, settings: FixtureSettings = FixtureSettings()) -> Path:
    """Simulate ``directory.parent / (directory.name + ".csv")`` and run ``study`` into ``directory``.

    Returns
    -------
    Path
        The results folder (with ``report.html``, written by the study).

    Raises
    ------
    RuntimeError
        The study did not end with exit code 1, NOT CONVERGED (its output is in the message).
    """
    out = Path(directory)
    csv = simulate_record(out.parent / f"{out.name}.csv", settings)
    argv = [
        "study",
        str(csv),
        "--out",
        str(out),
        "--seed",
        str(settings.seed),
        "--n-starts",
        "1",
        "--walkers",
        str(settings.n_walkers),
        "--max-steps",
        str(settings.max_steps),
        "--check-every",
        str(max(1, settings.max_steps // 2)),
        "--progress",
        "off",
        "--no-diagnose",  # the report's tests write their own diagnosis.json; tests/test_pages.py runs the diagnosis
    ]
    if settings.free_noise:
        argv += ["--noise-sigma", "free"]
    captured = io.StringIO()
    with contextlib.redirect_stdout(captured), contextlib.redirect_stderr(captured):
        code = identify_main(argv)
    # a step cap far below convergence: the study ends NOT CONVERGED, exit code 1 (a finding)
    if code != 1 or "NOT CONVERGE" not in captured.getvalue():
        raise RuntimeError(f"study exited with {code}, expected 1 (NOT CONVERGED):\n{captured.getvalue()}")
    return out

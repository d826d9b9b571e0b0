"""Where the wall time of one ``study`` goes: a stage breakdown, in process.

Runs :func:`identify.study` (the function behind ``python -m identify study``) on a record
with timers wrapped around the stages and the sampler's parts, and prints, with the load
average before and after (a shared 2-core machine: other processes slow everything down):

* start-up: importing the package, numba's cached kernels (the first model call), and
  the command line's start-up (``python -m identify --help``, a subprocess);
* the study's phases (noise, least squares, identifiability, posterior, report), as the
  manifest records them;
* inside the least squares: model rows evaluated and the time in the model, the Jacobian;
* inside the posterior: steps, model evaluation (the log-posterior calls, and the model
  alone), the sampler-coordinate map (forward, inverse, log-determinant), emcee's own
  bookkeeping (the rest of the sampling loop), HDF5 writes, the thread-count probes,
  the convergence checks (of which ArviZ's R-hat/ESS), the final summary and the
  ArviZ InferenceData export;
* inside the report: the figures (of which the corner plot) and the bands.

Usage::

    python benchmarks/study_stages.py data/bench_clean.csv [--effects thermal] [--seed 0]
        [--max-steps N] [--no-report] [--out DIR] [--save chain.npy]

``--save`` writes the chain (``(steps, walkers, D)``, from ``chain.h5``) for a
bit-identity comparison between two versions of the code (``np.array_equal``).
"""

from __future__ import annotations

import argparse
import functools
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

TIMES: dict[str, float] = defaultdict(float)
CALLS: dict[str, int] = defaultdict(int)


def _wrap(owner, attribute, label):
    """Time every call of ``owner.attribute`` under ``label`` (inclusive; re-entrant calls count once)."""
    original = getattr(owner, attribute)
    depth = [0]

    @functools.wraps(original)
    def timed(*args, **kwargs):
        depth[0] += 1
        t0 = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            depth[0] -= 1
            if depth[0] == 0:
                TIMES[label] += time.perf_counter() - t0
                CALLS[label] += 1

    setattr(owner, attribute, timed)


def _instrument():
    import identify.fitting.coordinates as coordinates
    import identify.fitting.inference as inference
    import identify.fitting.lsq as lsq
    import identify.fitting.posterior as posterior
    import model.composite as composite

    _wrap(composite.Model, "evaluate", "model.evaluate")
    _wrap(lsq.WhitenedResiduals, "jacobian", "lsq: forward-difference Jacobian")
    _wrap(lsq.WhitenedResiduals, "central_jacobian", "lsq: central Jacobian (covariance)")
    _wrap(lsq, "candidate_starts", "lsq: candidate starts")
    _wrap(posterior, "sample_posterior", "posterior: sample_posterior")
    _wrap(posterior.LogPosterior, "__call__", "posterior: log-posterior calls")
    _wrap(posterior, "initial_walkers", "posterior: initial walkers")
    _wrap(coordinates.CoordinateMove, "propose", "posterior: moves (incl. log-posterior)")
    for name in ("forward", "inverse", "log_det"):
        _wrap(coordinates.GPICoordinates, name, f"posterior: map {name}")
    _wrap(posterior.BufferedHDFBackend, "flush", "posterior: HDF5 flush")
    _wrap(posterior, "fastest_thread_count", "posterior: thread-count probe")
    _wrap(posterior, "_check", "posterior: convergence checks")
    _wrap(posterior, "_tau", "posterior: autocorrelation time")
    _wrap(posterior, "chain_diagnostics", "posterior: ArviZ R-hat/ESS")
    _wrap(posterior, "posterior_from_backend", "posterior: final summary (reads chain.h5)")
    _wrap(inference, "write_inference_data", "posterior: InferenceData export")
    try:
        import identify.output.plots as plots
        import identify.output.report as report

        _wrap(report, "write_report", "report: write_report")
        _wrap(plots, "corner_figure", "report: corner plot")
    except (ImportError, AttributeError):  # pragma: no cover - the report layer moved
        pass


def _load():
    return os.getloadavg()[0]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--effects", default="")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-steps", type=int, default=None)
    parser.add_argument("--no-report", action="store_true")
    parser.add_argument("--out", default=None)
    parser.add_argument("--save", default=None, help="save the chain as .npy (bit-identity checks)")
    parser.add_argument("--skip-startup", action="store_true", help="do not time the command line's start-up")
    args = parser.parse_args(argv)

    load_before = _load()
    if not args.skip_startup:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "identify", "--help"], cwd=ROOT, capture_output=True, check=True)
        cli_startup = time.perf_counter() - t0
    t0 = time.perf_counter()
    import numpy as np

    import identify
    from identify.data.records import load_record
    from identify.defaults import DEFAULT_MAX_STEPS
    from model import Model

    import_seconds = time.perf_counter() - t0
    _instrument()
    record = load_record(args.data)
    effects = [e for e in args.effects.split(",") if e]
    t0 = time.perf_counter()
    Model(effects).evaluate(Model(effects).default_theta(), record.time, record.current)
    first_call = time.perf_counter() - t0
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="study-stages-"))
    model = Model(effects, n_operators=12, reading="swapped") if effects else None
    max_steps = args.max_steps or DEFAULT_MAX_STEPS
    TIMES.clear()
    CALLS.clear()
    t0 = time.perf_counter()
    result = identify.study(
        record,
        model,
        out=out,
        seed=args.seed,
        max_steps=max_steps,
        report=not args.no_report,
        force=True,
        quiet=True,
        progress=False,
    )
    wall = time.perf_counter() - t0
    load_after = _load()

    import json

    manifest = json.loads((out / "manifest.json").read_text())
    phases = manifest["runs"][-1]["phases"] if manifest.get("runs") else manifest.get("phases", {})
    post = result.summary["posterior"]
    print(
        f"record {args.data}, effects '{args.effects or 'none'}', seed {args.seed}; {os.cpu_count()} cores, "
        f"load {load_before:.2f} before, {load_after:.2f} after"
    )
    if not args.skip_startup:
        print(
            f"start-up: python -m identify --help {cli_startup:.2f} s; import {import_seconds:.2f} s; "
            f"first model call (cached kernels) {first_call:.2f} s"
        )
    verdict = "converged" if post["converged"] else "NOT converged"
    print(
        f"study() {wall:.1f} s: {post['n_steps']} steps x {post['n_walkers']} walkers, "
        f"tau_max {post['tau_max']:.1f}, {verdict}"
    )
    for name, seconds in phases.items():
        print(f"  phase {name:<22} {seconds:8.2f} s")
    steps = max(int(post["n_steps"]), 1)
    sampling = TIMES.get("posterior: sample_posterior", 0.0)
    map_seconds = sum(TIMES.get(f"posterior: map {n}", 0.0) for n in ("forward", "inverse", "log_det"))
    for label in sorted(TIMES):
        per = f" ({1e3 * TIMES[label] / steps:.3f} ms/step)" if label.startswith("posterior: ") else ""
        print(f"  {label:<46} {TIMES[label]:8.2f} s  {CALLS[label]:7d} calls{per}")
    moves = TIMES.get("posterior: moves (incl. log-posterior)", 0.0)
    log_post = TIMES.get("posterior: log-posterior calls", 0.0)
    outside = (
        sampling
        - moves
        - sum(
            TIMES.get(k, 0.0)
            for k in (
                "posterior: HDF5 flush",
                "posterior: thread-count probe",
                "posterior: convergence checks",
                "posterior: final summary (reads chain.h5)",
                "posterior: initial walkers",
            )
        )
    )
    print(
        f"  posterior: moves less log-posterior and map          {moves - log_post - map_seconds:8.2f} s "
        f"({1e3 * (moves - log_post - map_seconds) / steps:.3f} ms/step)"
    )
    print(
        f"  posterior: emcee's loop outside the moves            {outside:8.2f} s ({1e3 * outside / steps:.3f} ms/step)"
    )
    if args.save:
        from identify.fitting.posterior import BACKEND_GROUP, ChainBackend

        chain = ChainBackend(str(out / "chain.h5"), name=BACKEND_GROUP, read_only=True).get_chain()
        np.save(args.save, chain)
        print(f"chain {chain.shape} saved to {args.save}")
    print(f"results in {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

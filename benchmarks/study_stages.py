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
  the convergence checks (of which the R-hat/ESS), the final summary and the
  InferenceData export;
* the sampling phase beside the pure forward-model time of the same evaluations: every
  batch of parameter sets the sampler passed to ``Model.evaluate`` (log-posterior calls
  and thread probes) is recorded with numba's thread count at the call, and replayed
  through ``Model.evaluate`` at the same thread counts after the study, in the same
  process (issue 70's target: sampling at most 1.5 x that time);
* inside the report: the figures (of which the corner plot) and the bands;
* the results folder's size and ``posterior.nc``'s.

Usage::

    python benchmarks/study_stages.py data/bench_clean.csv [--effects thermal] [--seed 0]
        [--max-steps N] [--no-report] [--interleaved] [--lean] [--out DIR] [--save chain.npy]

``--interleaved`` evaluates every sampler call a second time right after it, timed apart: the
sampling over the pure model at the same minute (this machine's speed drifts by a third between
minutes, which a replay after the study cannot follow).

``--lean`` installs only the timers the ratio needs (the sampler's model calls and
``sample_posterior``): the breakdown's dozen timed calls a step cost the sampler time of their own.

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

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

TIMES: dict[str, float] = defaultdict(float)
CPU: dict[str, float] = defaultdict(float)
CALLS: dict[str, int] = defaultdict(int)
#: (parameter sets, numba threads) of every model call made inside sample_posterior.
SAMPLER_BATCHES: list = []
_SAMPLING = [False]
_EVALUATE = []  # Model.evaluate before any wrapper (the replay calls it)
#: With ``--interleaved``: every sampler model call is evaluated a second time right after it, timed apart.
_INTERLEAVED = [False]
INTERLEAVED = "posterior: the sampler's calls again, interleaved"


def _charge(label, t0, c0) -> None:
    """Add the wall and CPU time since ``t0``, ``c0`` and one call to ``label``."""
    TIMES[label] += time.perf_counter() - t0
    CPU[label] += time.process_time() - c0
    CALLS[label] += 1


def _wrap(owner, attribute, label):
    """Time every call of ``owner.attribute`` under ``label`` (inclusive; re-entrant calls count once)."""
    original = getattr(owner, attribute)
    depth = [0]

    @functools.wraps(original)
    def timed(*args, **kwargs):
        depth[0] += 1
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            return original(*args, **kwargs)
        finally:
            depth[0] -= 1
            if depth[0] == 0:
                _charge(label, t0, c0)

    setattr(owner, attribute, timed)


def _record_sampler_batches(composite, posterior):
    """Record the parameter sets of every Model.evaluate call inside sample_posterior."""
    import numba

    evaluate = composite.Model.evaluate
    _EVALUATE.append(evaluate)

    @functools.wraps(evaluate)
    def recorded(self, theta, t, current):
        if not _SAMPLING[0]:
            return evaluate(self, theta, t, current)
        SAMPLER_BATCHES.append((self, np.array(theta), numba.get_num_threads()))
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            return evaluate(self, theta, t, current)
        finally:
            _charge("posterior: model.evaluate inside the sampler", t0, c0)
            if _INTERLEAVED[0]:  # the same call again at once: the pure model at the same minute
                t1, c1 = time.perf_counter(), time.process_time()
                evaluate(self, theta, t, current)
                _charge(INTERLEAVED, t1, c1)

    composite.Model.evaluate = recorded
    sample = posterior.sample_posterior

    @functools.wraps(sample)
    def sampling(*args, **kwargs):
        _SAMPLING[0] = True
        try:
            return sample(*args, **kwargs)
        finally:
            _SAMPLING[0] = False

    posterior.sample_posterior = sampling


def _replay(record) -> tuple[float, float, int, int]:
    """(wall, CPU) seconds of the recorded sampler batches through Model.evaluate at their
    thread counts, and the numbers of calls and of parameter sets."""
    import numba

    threads = numba.get_num_threads()
    wall = cpu = 0.0
    rows = 0
    try:
        for model, theta, n_threads in SAMPLER_BATCHES:
            numba.set_num_threads(n_threads)
            t0, c0 = time.perf_counter(), time.process_time()
            _EVALUATE[0](model, theta, record.time, record.current)
            wall += time.perf_counter() - t0
            cpu += time.process_time() - c0
            rows += len(np.atleast_2d(theta))
    finally:
        numba.set_num_threads(threads)
    return wall, cpu, len(SAMPLER_BATCHES), rows


def _thread_counts() -> str:
    """How many of the recorded sampler calls ran at each numba thread count."""
    counts: dict[int, int] = defaultdict(int)
    for _model, _theta, n_threads in SAMPLER_BATCHES:
        counts[n_threads] += 1
    return ", ".join(f"{n} at {k} thread{'s' if k > 1 else ''}" for k, n in sorted(counts.items()))


def _instrument(lean=False):
    """Install the timers: with ``lean``, only those the ratio needs (the sampler's model calls,
    their interleaved repeats, ``sample_posterior``), so that no other timer's own cost (two clock
    reads a call, a dozen calls a step) is charged to the sampler."""
    import identify.fitting.chain_file as chain_file
    import identify.fitting.convergence as convergence
    import identify.fitting.coordinates as coordinates
    import identify.fitting.inference as inference
    import identify.fitting.lsq as lsq
    import identify.fitting.posterior as posterior
    import model.composite as composite

    _record_sampler_batches(composite, posterior)
    if lean:
        _wrap(posterior, "sample_posterior", "posterior: sample_posterior")
        return
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
    _wrap(chain_file.BufferedHDFBackend, "flush", "posterior: HDF5 flush")
    _wrap(posterior, "fastest_thread_count", "posterior: thread-count probe")
    _wrap(posterior, "_check", "posterior: convergence checks")
    _wrap(convergence, "integrated_tau", "posterior: autocorrelation time")
    _wrap(posterior, "chain_diagnostics", "posterior: R-hat/ESS (chain_diagnostics)")
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
    parser.add_argument(
        "--interleaved",
        action="store_true",
        help="evaluate every sampler model call a second time right after it (timed apart and taken off the "
        "sampling time): the ratio at the same minute, which this machine's drifting speed makes the replay "
        "after the study miss; the other per-part times include these evaluations",
    )
    parser.add_argument(
        "--lean",
        action="store_true",
        help="time only what the sampling ratio needs (no breakdown of the parts): the other timers' own cost "
        "is then not charged to the sampler",
    )
    args = parser.parse_args(argv)
    _INTERLEAVED[0] = args.interleaved

    load_before = _load()
    if not args.skip_startup:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "identify", "--help"], cwd=ROOT, capture_output=True, check=True)
        cli_startup = time.perf_counter() - t0
    t0 = time.perf_counter()
    import identify
    from identify.data.records import load_record
    from identify.defaults import DEFAULT_MAX_STEPS
    from model import Model

    import_seconds = time.perf_counter() - t0
    _instrument(lean=args.lean)
    record = load_record(args.data)
    effects = [e for e in args.effects.split(",") if e]
    t0 = time.perf_counter()
    Model(effects).evaluate(Model(effects).default_theta(), record.time, record.current)
    first_call = time.perf_counter() - t0
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="study-stages-"))
    model = Model(effects, n_operators=12, reading="swapped") if effects else None
    max_steps = args.max_steps or DEFAULT_MAX_STEPS
    TIMES.clear()
    CPU.clear()
    CALLS.clear()
    SAMPLER_BATCHES.clear()
    t0 = time.perf_counter()
    cpu0 = time.process_time()
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
    cpu = time.process_time() - cpu0
    load_after = _load()
    replay_wall, replay_cpu, n_calls, n_rows = _replay(record)
    load_replayed = _load()

    import json

    manifest = json.loads((out / "manifest.json").read_text())
    phases = manifest["runs"][-1]["phases"] if manifest.get("runs") else manifest.get("phases", {})
    post = result.summary["posterior"]
    print(
        f"record {args.data}, effects '{args.effects or 'none'}', seed {args.seed}; {os.cpu_count()} cores, "
        f"load {load_before:.2f} before, {load_after:.2f} after the study, {load_replayed:.2f} after the replay"
    )
    if not args.skip_startup:
        print(
            f"start-up: python -m identify --help {cli_startup:.2f} s; import {import_seconds:.2f} s; "
            f"first model call (cached kernels) {first_call:.2f} s"
        )
    verdict = "converged" if post["converged"] else "NOT converged"
    print(
        f"study() {wall:.1f} s (CPU {cpu:.1f} s): {post['n_steps']} steps x {post['n_walkers']} walkers, "
        f"tau_max {post['tau_max']:.1f}, {verdict}"
    )
    for name, seconds in phases.items():
        print(f"  phase {name:<22} {seconds:8.2f} s")
    steps = max(int(post["n_steps"]), 1)
    sampling = TIMES.get("posterior: sample_posterior", 0.0)
    map_seconds = sum(TIMES.get(f"posterior: map {n}", 0.0) for n in ("forward", "inverse", "log_det"))
    for label in sorted(TIMES):
        per = f" ({1e3 * TIMES[label] / steps:.3f} ms/step)" if label.startswith("posterior: ") else ""
        print(f"  {label:<46} {TIMES[label]:8.2f} s (CPU {CPU[label]:7.2f} s) {CALLS[label]:7d} calls{per}")
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
    print(
        f"sampling {sampling:.2f} s beside the pure forward model of the same {n_calls} calls ({n_rows} parameter "
        f"sets) replayed through Model.evaluate at the sampler's thread counts: {replay_wall:.2f} s "
        f"(CPU {replay_cpu:.2f} s); ratio {sampling / max(replay_wall, 1e-9):.2f} (target <= 1.5); CPU ratio "
        f"{CPU.get('posterior: sample_posterior', 0.0) / max(replay_cpu, 1e-9):.2f}; calls {_thread_counts()}"
    )
    if args.interleaved:
        again = TIMES.get(INTERLEAVED, 0.0)
        own = sampling - again
        own_cpu = CPU.get("posterior: sample_posterior", 0.0) - CPU.get(INTERLEAVED, 0.0)
        print(
            f"interleaved: sampling {own:.2f} s (less the {again:.2f} s of the second evaluations) beside the same "
            f"{CALLS.get(INTERLEAVED, 0)} calls evaluated again right after each: ratio {own / max(again, 1e-9):.2f} "
            f"(target <= 1.5); CPU ratio "
            f"{own_cpu / max(CPU.get(INTERLEAVED, 0.0), 1e-9):.2f}"
        )
    sizes = {p.name: p.stat().st_size for p in out.rglob("*") if p.is_file()}
    print(
        f"results folder {sum(sizes.values()) / 1e6:.1f} MB (target <= 15), posterior.nc "
        f"{sizes.get('posterior.nc', 0) / 1e6:.1f} MB (target <= 10), chain.h5 {sizes.get('chain.h5', 0) / 1e6:.1f} MB"
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

"""Speed of the inverse (compensation) and of predict.

Prints, for a 7001-sample target (a 100 Hz triangle between 30 and 270 um):

* the inverse of one parameter set (the posterior median) and of 200 posterior draws
  (:func:`model.inverse.invert`, one parallel call), median and best of several repeats,
  and the whole ``compensate`` workflow (both inverses plus the 200 draws driven by the
  median's current);
* ``predict`` with 200 draws on a 70001-sample record (the bench transducer at 1 kHz,
  70 s), the computation (:func:`identify.workflows.use.predict`) and the files
  (:func:`identify.workflows.use.write_prediction`) apart.

With ``--study DIR`` (a finished study of a bench record in A and um, e.g. the bundled
``data/bench_default.csv`` with ``--effects thermal``) its model and posterior are used;
without it the inverse runs on Table 1 plus the thermal effect with 200 parameter sets
scattered around it (0.1 % relative), and predict is skipped. Targets: median set < 1 s,
200 draws < 10 s, predict < 30 s (issue 17)::

    python -m identify study data/bench_default.csv --effects thermal --out reports/bench_thermal
    python benchmarks/inverse.py --study reports/bench_thermal
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def _triangle(n=7001, fs=100.0, low=30.0, high=270.0, period=16.0):
    t = np.arange(n) / fs
    phase = (t / period) % 1.0
    return t, low + (high - low) * np.where(phase < 0.5, 2 * phase, 2 - 2 * phase)


def _timed(function, repeats):
    """``(result, wall times, CPU times)`` of ``repeats`` calls (CPU: all threads of the process)."""
    times, cpu = [], []
    result = None
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        result = function()
        times.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return result, times, cpu


def _say(label, timing, target=None):
    times, cpu = timing
    line = (
        f"{label:<58} wall median {statistics.median(times):7.3f} s, best {min(times):7.3f} s; "
        f"CPU median {statistics.median(cpu):7.3f} s"
    )
    if target is not None:
        line += f"   (target < {target:g} s: {'met' if statistics.median(times) < target else 'NOT met'})"
    print(line, flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", default=None, help="a finished study folder (bench record, A and um)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--predict-repeats", type=int, default=3)
    args = parser.parse_args(argv)

    import numba

    from model import EFFECTS, TABLE1, Model
    from model.inverse import invert

    print(f"numba threads {numba.get_num_threads()}, cpu_count {os.cpu_count()}, load average {os.getloadavg()}")
    time_axis, target = _triangle()
    study = None
    if args.study:
        from identify.workflows.use import load_study

        study = load_study(args.study)
        model = study.model
        median = study.median
        draws, _ = study.draws(200, np.random.default_rng(0))
        print(f"study {args.study}: {model!r}, {study.samples.shape[0]} posterior samples")
    else:
        model = Model(["thermal"])
        median = model.theta_from_dict(dict(zip(model.names[:19], TABLE1)) | EFFECTS["thermal"].get_test_parameters())
        rng = np.random.default_rng(0)
        draws = median[None, :] * (1.0 + 1e-3 * rng.standard_normal((200, median.size)))
        draws[:, 0] = median[0]
        print(f"no study: {model!r} at Table 1 + thermal test parameters, 200 sets scattered by 0.1 %")

    invert(model, median, time_axis[:50], target[:50])  # compile / load the cache
    one, *times = _timed(lambda: invert(model, median, time_axis, target), args.repeats)
    _say(f"inverse, median set, {time_axis.size} samples", times, 1.0)
    print(
        f"    {one.evaluations[0] / time_axis.size:.1f} model steps per sample; samples exact: {int(one.exact.sum())}"
    )
    many, *times = _timed(lambda: invert(model, draws, time_axis, target), args.repeats)
    _say(f"inverse, {draws.shape[0]} draws, {time_axis.size} samples", times, 10.0)
    print(f"    samples exact over all draws: {int(many.exact.sum())} of {many.status.size}")
    if study is None:
        return 0

    from identify.bench import simulate
    from identify.data.records import write_record
    from identify.workflows.use import Target, compensate, predict, write_prediction

    _, *times = _timed(lambda: compensate(study, Target(time_axis, target), n_draws=200), max(1, args.repeats // 2))
    _say(f"compensate workflow (both inverses + tracking), {time_axis.size} samples", times)

    import json

    sidecar = Path(str(study.record.source)).with_suffix(".json")
    if sidecar.is_file():  # the bench record's truth: the same hidden effects at 1 kHz
        effects = json.loads(sidecar.read_text()).get("effects") or None
    else:
        effects = {e: EFFECTS[e].get_test_parameters() for e in model.effect_names} or None
    print(f"1 kHz record: hidden effects {effects}")
    sim = simulate(effects, fs=1000.0, seed=3)
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "bench_1khz.csv"
        write_record(csv, sim.record)
        prediction, *times = _timed(lambda: predict(study, csv, n_draws=200), args.predict_repeats)
        _say(f"predict, 200 draws, {len(sim.record)} samples (verdict {prediction.verdict})", times, 30.0)
        _, *write_times = _timed(lambda: write_prediction(prediction, Path(tmp) / "pred"), 1)
        _say("  + writing the page and figures", write_times)
        print(f"    phases of the last predict: {', '.join(f'{k} {v:.2f} s' for k, v in prediction.seconds.items())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Wall time of ``python -m identify diagnose`` at 7001 and 70001 samples (targets: < 20 s, < 120 s).

Run from the repository root::

    python benchmarks/diagnose.py                       # both sizes, hidden creep
    python benchmarks/diagnose.py --quick               # 7001 samples only
    python benchmarks/diagnose.py --case unexplained    # the worst case: an effect outside the library
    python benchmarks/diagnose.py --case unexplained --side-by-side 2   # two at once, both wait policies

Simulates a virtual-bench record (paper input, Table 1, a hidden creep of ~2x the noise
in RMS, seed 5) at 100 Hz and 1 kHz, runs the diagnosis command in a fresh process
(numba compilation cached, so a first run on a new machine is slower), and prints the
wall time (and the child's CPU time), the verdict, and the ratio of the 70001-sample time to the 7001-sample one
(10x the samples; the screening and the short refits run on a decimated copy, so the
ratio stays well below 10). The machine is shared: the figure is one run, not a best of
several. ``--case unexplained`` adds to a clean record an offset of 1.5 um (3 sigma) while the
current exceeds 4 A whose sign flips each 10 s cycle (outside the library: the verdict is
``unexplained``, the slowest path: every refit, the other-sign refit and the pairs).
``--case overshoot`` diagnoses a record of independent origin: the independent bench's
generator (``benchmarks/independent/generator.py``, written blind to this library) draws
its effects suite with seed 5, one record per form, with ``--new-forms``, and the record of
its ``virgin_field_overshoot`` form (a first-cycle overshoot of the virgin field, 100 Hz,
7001 samples) is taken; the 70001-sample record is the same transducer driven by the paper's
input at 1 kHz (the generator's ``--like``). No library effect is its form, so every
candidate, the other sign and the pairs are refitted, the slowest path users meet.
``--case ringing``: the generator's ``resonance_ringing`` record of seed 21 (outside the
library, 1 kHz, 70001 samples; ``unexplained`` on 2026-12-02 in 132 s), at 100 Hz the same
transducer on the paper's input.
``--side-by-side N`` runs N diagnoses of the 7001-sample record at once (as the benches'
workers do on the two cores), alternating numba's OpenMP threads waiting passively between
kernel calls (``OMP_WAIT_POLICY=PASSIVE``, which the bench runners set) and as libgomp does
unless told (spinning about 3 ms after each parallel region before it sleeps, which keeps a
core busy between the calls of a diagnosis). The command itself waits passively unless
``OMP_WAIT_POLICY`` is set (:func:`identify.cli.diagnose.passive_waiting`); the empty value of
the second policy is set, so it stays libgomp's default.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def make_record(fs: float, workdir: Path, case: str = "creep") -> Path:
    """Simulate the benchmark's record at ``fs`` Hz (seed 5); the unexplained case adds the flipping offset."""
    csv = workdir / f"{case}_{int(fs)}.csv"
    effects = "creep_amplitude=0.0153" if case == "creep" else "none"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "identify",
            "simulate",
            "--out",
            str(csv),
            "--effects",
            effects,
            "--fs",
            str(fs),
            "--seed",
            "5",
        ],
        check=True,
        cwd=ROOT,
        capture_output=True,
    )
    if case == "unexplained":
        import numpy as np

        from identify.data.records import load_record, write_record

        record = load_record(csv)
        t, i = record.time, record.current
        flip = np.where(i > 4.0, 1.5 * (-1.0) ** np.floor((t - 10.0) / 10.0), 0.0)
        write_record(csv, type(record)(t, i, record.displacement + flip, source=record.source, sha256=""))
    return csv


#: The cases of independent origin: the generator's seed, its options, and the record's form.
INDEPENDENT = {
    "overshoot": (5, ["--new-forms"], "virgin_field_overshoot"),
    "ringing": (21, [], "resonance_ringing"),
}


def make_independent_record(fs: float, workdir: Path, case: str) -> Path:
    """The independent generator's record of the case's form (:data:`INDEPENDENT`: its effects
    suite, one record per form) when it is at ``fs`` Hz, else its transducer on the paper's
    input at ``fs`` Hz (the generator's ``--like``)."""
    seed, options, form = INDEPENDENT[case]
    generator = ROOT / "benchmarks" / "independent" / "generator.py"
    suite = workdir / f"independent_{seed}"
    if not (suite / "index.json").exists():
        options = ["--suite", "effects", "--seed", str(seed), "--per-form", "1", *options]
        subprocess.run([sys.executable, str(generator), "--out", str(suite), *options], check=True, capture_output=True)
    truths = [p for p in sorted(suite.glob("*.truth.json")) if json.loads(p.read_text()).get("forms") == [form]]
    if not truths:
        raise SystemExit(f"the generator wrote no {form} record")
    truth = truths[0]
    csv = truth.with_name(truth.name.removesuffix(".truth.json") + ".csv")
    if json.loads(truth.read_text()).get("fs") == fs:
        return csv
    import numpy as np

    paper = np.genfromtxt(make_record(fs, workdir, "creep"), delimiter=",", names=True)
    drive = workdir / f"paper_drive_{int(fs)}.csv"
    np.savetxt(drive, np.c_[paper["time"], paper["current"]], delimiter=",", header="time,current", comments="")
    stem = f"{case}_{int(fs)}"
    like = ["--like", str(truth), "--input", str(drive), "--stem", stem]
    subprocess.run([sys.executable, str(generator), "--out", str(suite), *like], check=True, capture_output=True)
    return suite / f"{stem}.csv"


def make_case_record(fs: float, workdir: Path, case: str) -> Path:
    """The record of ``case`` at ``fs`` Hz (simulated, or of independent origin)."""
    return make_independent_record(fs, workdir, case) if case in INDEPENDENT else make_record(fs, workdir, case)


def _children_cpu(before: os.times_result, after: os.times_result) -> float:
    """CPU seconds (user + system) of the child processes that ended between ``before`` and ``after``."""
    return (after.children_user - before.children_user) + (after.children_system - before.children_system)


def _command(csv: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "identify", "diagnose", str(csv), "--json", str(out), "--quiet"]


def run_once(fs: float, workdir: Path, case: str = "creep") -> tuple[float, float, dict]:
    """Simulate at ``fs`` Hz, diagnose in a subprocess; (wall seconds, CPU seconds, diagnosis JSON)."""
    csv = make_case_record(fs, workdir, case)
    out = workdir / f"{case}_{int(fs)}_diagnosis.json"
    started = time.perf_counter()
    before = os.times()
    subprocess.run(_command(csv, out), check=True, cwd=ROOT, capture_output=True)
    return time.perf_counter() - started, _children_cpu(before, os.times()), json.loads(out.read_text())


def run_side_by_side(csv: Path, workdir: Path, copies: int, wait_policy: str) -> tuple[list[float], float]:
    """``copies`` diagnoses of ``csv`` started together, numba's OpenMP threads waiting with
    ``wait_policy`` (``OMP_WAIT_POLICY``; an empty value, which libgomp ignores with a
    warning on the discarded stderr, is libgomp's default: spin about 3 ms after a parallel
    region, then sleep); (each one's wall seconds, their CPU seconds in all)."""
    env = dict(os.environ, OMP_WAIT_POLICY=wait_policy)
    before = os.times()
    started = time.perf_counter()
    processes = [
        subprocess.Popen(
            _command(csv, workdir / f"side_{wait_policy}_{k}.json"),
            cwd=ROOT,
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        for k in range(copies)
    ]
    walls = []
    for process in processes:
        if process.wait() != 0:
            raise SystemExit(f"a side-by-side diagnosis failed (exit code {process.returncode})")
        walls.append(time.perf_counter() - started)
    return walls, _children_cpu(before, os.times())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="7001 samples only")
    parser.add_argument("--case", choices=("creep", "unexplained", *INDEPENDENT), default="creep")
    parser.add_argument(
        "--side-by-side",
        type=int,
        default=0,
        metavar="N",
        help="run N diagnoses of the 7001-sample record at once, with numba's OpenMP threads "
        "waiting passively (as the bench runners set) and as libgomp does by default, alternating",
    )
    args = parser.parse_args(argv)
    if args.side_by_side:
        with tempfile.TemporaryDirectory() as tmp:
            csv = make_case_record(100.0, Path(tmp), args.case)
            for policy in ("PASSIVE", "", "PASSIVE", ""):
                walls, cpu = run_side_by_side(csv, Path(tmp), args.side_by_side, policy)
                print(
                    f"{args.side_by_side} diagnoses ({args.case}, 7001 samples) side by side, "
                    f"{'passive waiting' if policy else 'libgomp default':15s}: "
                    f"wall {', '.join(f'{w:.1f}' for w in walls)} s, CPU {cpu:.1f} s in all"
                )
        return 0
    sizes = [(100.0, 20.0)] if args.quick else [(100.0, 20.0), (1000.0, 120.0)]
    times = {}
    with tempfile.TemporaryDirectory() as tmp:
        for fs, target in sizes:
            seconds, cpu, result = run_once(fs, Path(tmp), args.case)
            times[fs] = seconds
            n = int(round(70 * fs)) + 1
            print(
                f"diagnose ({args.case}), {n:6d} samples: {seconds:6.1f} s wall, {cpu:6.1f} s CPU (target < "
                f"{target:.0f} s) "
                f"-> {result['status']}{' (' + result['missing'] + ')' if result['missing'] else ''}, "
                f"RMS {result['rms']:.3f} um vs noise {result['noise_sigma']:.3f} um"
            )
    if len(times) == 2:
        print(f"ratio 70001 / 7001 samples: {times[1000.0] / times[100.0]:.2f} (10x the samples)")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))  # the unexplained case edits the record with the package, installed or not
    raise SystemExit(main())

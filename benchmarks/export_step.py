"""Cost per sample of the exported C: the inverse (the compensator) and the forward model.

For each model (12 operators: the plain GPI of Table 1, Table 1 with the bench's thermal
effect, with training, initial_state, creep and thermal at their test settings, and with the lag
alone; and a study's export with ``--study DIR``) the C of ``python -m identify export`` is
compiled with the local compiler (``-O2``, as the export builds its units) together with a
small timing harness, which steps a
7001-sample target (a 100 Hz triangle between 30 and 270 um, then a 60-240 um sine) through
``msma_inverse_step`` and the current found through ``msma_forward_step``, timing every call
with ``clock_gettime(CLOCK_MONOTONIC)``. The whole run is repeated; per sample the fastest of
the repeats is its cost (the calls take the same path every time, so what the repeats add is
the scheduler's, not the algorithm's). Printed: median, 99th percentile and worst of those
per-sample costs over the samples after the first, with the model steps (``msma_inverse_step``'s
evaluations of the model) the worst sample took, the first sample's cost (once per run), the
worst single call seen in any repeat (that one is the scheduler's: milliseconds at a load above
the cores), and the model steps per sample (mean, max) and the median cost of one. The worst
samples are the target's reversals, where the inverse searches both sides of Omega's switch:
their cost is their model steps times the cost of one, which moves with the machine's load (a
shared core runs slower), so compare the steps, or costs measured in one run. Target (issue 68):
under 2 us per sample for the inverse::

    python benchmarks/export_step.py [--repeats 7] [--study DIR] [--each]
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import model
from identify.export import export_spec
from identify.export.compiler import executable
from identify.export.sources import c_sources

HARNESS = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "msma_gpi.h"

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e9 + ts.tv_nsec;
}

int main(int argc, char **argv) {
    int n = atoi(argv[1]), repeats = atoi(argv[2]), k, r, status;
    double lo = atof(argv[3]), hi = atof(argv[4]), scale = atof(argv[5]);
    double *t = malloc(n * sizeof *t), *y = malloc(n * sizeof *y);
    double *inv = malloc(n * sizeof *inv), *fwd = malloc(n * sizeof *fwd), worst_inv = 0, worst_fwd = 0;
    long long evaluations = 0, *steps = malloc(n * sizeof *steps);
    msma_params p;
    static msma_inverse c;
    static msma_forward m;
    FILE *in = fopen(argv[6], "r");
    for (k = 0; k < n; k++) {
        if (fscanf(in, "%lf %lf", &t[k], &y[k]) != 2) return 2;
        inv[k] = fwd[k] = 1e300;
    }
    fclose(in);
    msma_default_params(&p);
    for (r = 0; r < repeats; r++) {
        if (msma_inverse_init(&c, &p, lo, hi, scale) || msma_forward_init(&m, &p)) return 1;
        for (k = 0; k < n; k++) {
            long long before = c.evaluations;
            double a = now(), i = msma_inverse_step(&c, t[k], y[k], &status), b = now(), d;
            steps[k] = c.evaluations - before;
            msma_forward_step(&m, t[k], i);
            d = now() - b;
            if (b - a < inv[k]) inv[k] = b - a;
            if (b - a > worst_inv) worst_inv = b - a;
            if (d < fwd[k]) fwd[k] = d;
            if (d > worst_fwd) worst_fwd = d;
        }
        evaluations = c.evaluations;
    }
    printf("%.17g %.17g %lld\n", worst_inv, worst_fwd, evaluations);
    for (k = 0; k < n; k++) printf("%.17g %.17g %lld\n", inv[k], fwd[k], steps[k]);
    return 0;
}
"""


def targets(fs=100.0, n=7001):
    """A triangle 30-270 um (16 s period) for the first half, a 60-240 um sine (0.1 Hz) after."""
    t = np.arange(n) / fs
    phase = (t / 16.0) % 1.0
    triangle = 30.0 + 240.0 * np.where(phase < 0.5, 2 * phase, 2 - 2 * phase)
    sine = 150.0 - 90.0 * np.cos(2 * np.pi * 0.1 * t)
    return t, np.where(t < t[n // 2], triangle, sine)


def table1_models(each: bool = False):
    """(label, Model, theta): Table 1 alone, with the bench's thermal effect, with every exportable
    effect but the lag at its test setting, and with the lag alone; ``each``: also with each of
    those effects alone at its test setting (what a model step costs per effect)."""
    gpi = dict(zip(model.THETA_NAMES, model.TABLE1))

    def at(effects, **extra):
        m = model.Model(effects)
        values = dict(gpi)
        for name in effects:
            values.update(model.EFFECTS[name].get_test_parameters())
        return m, m.theta_from_dict({**values, **extra})

    bench = {"thermal_tau": 30.0, "thermal_sensitivity": 0.08, "thermal_expansion": 1.5}
    return [
        ("GPI, no effect", *at([])),
        ("GPI + thermal (the bench's)", *at(["thermal"], **bench)),
        ("GPI + training, initial_state, creep, thermal", *at(["training", "initial_state", "creep", "thermal"])),
        ("GPI + lag (tau 0.05 s)", *at(["lag"])),
    ] + ([(f"GPI + {name}", *at([name])) for name in ("training", "initial_state", "creep", "thermal")] if each else [])


def measure(c_dir: Path, work: Path, time, target, current_range, scale, repeats):
    harness = work / "harness.c"
    harness.write_text(HARNESS)
    program = executable([harness, c_dir / "msma_gpi.c", c_dir / "msma_params.c"], work / "harness")
    data = work / "target.txt"
    data.write_text("".join(f"{a!r} {b!r}\n" for a, b in zip(time.tolist(), target.tolist())))
    lo, hi = current_range
    args = [str(program), str(time.size), str(repeats), repr(lo), repr(hi), repr(scale), str(data)]
    done = subprocess.run(args, capture_output=True, text=True, check=True)
    lines = done.stdout.splitlines()
    worst_inv, worst_fwd, evaluations = lines[0].split()
    costs = np.array([[float(x) for x in line.split()] for line in lines[1:]]) / 1000.0  # us
    return costs, float(worst_inv) / 1000.0, float(worst_fwd) / 1000.0, int(evaluations) / time.size


def _row(label, costs, worst_inv, worst_fwd, evaluations):
    """One line: the first sample apart (once per run: the initial memory in every model step)."""
    inv, fwd, steps = costs[1:, 0], costs[1:, 1], costs[1:, 2] * 1000.0
    median = "met" if np.median(inv) < 2.0 else "NOT met"
    worst = "met" if inv.max() < 2.0 else "NOT met"
    k = int(np.argmax(inv))
    per_step = np.median(inv[steps > 0] / steps[steps > 0]) * 1000.0
    print(
        f"{label:<52} inverse median {np.median(inv):5.2f} us, p99 {np.percentile(inv, 99):5.2f}, worst "
        f"{inv.max():5.2f} (sample {k + 1}: {steps[k]:.0f} model steps), first sample {costs[0, 0]:5.2f}, any call "
        f"{worst_inv:7.1f}; model steps/sample {evaluations:4.1f} mean, {steps.max():.0f} max, "
        f"{per_step:.0f} ns each (median) | forward median {np.median(fwd):5.3f} us, worst "
        f"{fwd.max():5.2f} (any call {worst_fwd:6.1f}) | < 2 us: median {median}, worst {worst}"
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--study", default=None, help="also time the export of this finished study")
    parser.add_argument("--each", action="store_true", help="also each effect alone at its test setting")
    args = parser.parse_args()
    print(
        f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()} {platform.release()}, "
        f"load {os.getloadavg()[0]:.1f}; {args.repeats} repeats of 7001 samples"
    )
    time, target = targets()
    scale = max(1.0, float(np.abs(target).max()))
    with tempfile.TemporaryDirectory(prefix="export-step-") as work:
        work = Path(work)
        cases = []
        for label, m, theta in table1_models(args.each):
            spec = export_spec(m, theta, horizon=float(time[-1]), current_range=(0.0, 5.0), output_scale=scale)
            cases.append((label, spec))
        if args.study:
            from identify.export import study_spec

            cases.append((f"study {args.study}", study_spec(args.study)))
        for n, (label, spec) in enumerate(cases):
            c_dir = work / f"case{n}"
            c_dir.mkdir()
            for name, text in c_sources(spec).items():
                (c_dir / name).write_text(text)
            (work / "msma_gpi.h").write_text((c_dir / "msma_gpi.h").read_text())  # the harness's include
            result = measure(c_dir, work, time, target, spec.current_range, scale, args.repeats)
            _row(label, *result)


if __name__ == "__main__":
    main()

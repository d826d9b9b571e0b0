"""The GPI kernel of another checkout against this one's, in one process, alternated.

This machine's speed moves by a third between two processes a minute apart, so two versions of
the kernel are timed in one process: ``model/gpi_kernels.py`` of ``OTHER`` (a checkout of this
repository) is loaded as a module of its own beside this checkout's, both compiled (numba's
cache keeps each), and each call of one is followed by a call of the other on the same
arrays. Prints, for W parameter sets around Table 1 on the paper's input (N = 12, every set a
leader), whether the two outputs are the same bit for bit, and the minimum and median times on
1 and 2 threads with their ratios (this checkout over the other).

Usage::

    python benchmarks/kernel_ab.py OTHER [--sets 18,64] [--calls 200]
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def load_kernels(path: Path, name: str):
    """``model/gpi_kernels.py`` under ``path`` as the module ``name``."""
    spec = importlib.util.spec_from_file_location(name, path / "model" / "gpi_kernels.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def kernel_arguments(n_sets: int, rng) -> tuple:
    """The kernel's arguments for ``n_sets`` leaders on the paper's input, the output last."""
    from model import TABLE1, paper_current

    _time, current = paper_current()
    theta = np.ascontiguousarray(TABLE1 * (1 + 0.02 * rng.standard_normal((n_sets, 19))))
    zeros = np.zeros(n_sets)
    rows = np.zeros(n_sets, dtype=np.int64)
    every = np.arange(n_sets, dtype=np.int64)
    return (
        theta,
        np.ascontiguousarray(current[None, :]),
        rows,
        12,
        True,
        zeros,
        zeros.copy(),
        np.zeros((1, 1)),
        np.ones((1, 1)),
        rows.copy(),
        every,
        np.full(n_sets, -1, dtype=np.int64),
        np.zeros(0, dtype=np.int64),
        every.copy(),
        np.empty((0, 1)),
        np.empty((n_sets, current.size)),
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("other", type=Path, help="another checkout of this repository")
    parser.add_argument("--sets", default="18,64", help="parameter-set counts, comma-separated")
    parser.add_argument("--calls", type=int, default=200, help="calls of each kernel per count and thread count")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))  # this checkout's model package, installed or not
    other = load_kernels(args.other.resolve(), "other_gpi_kernels")
    present = load_kernels(ROOT, "present_gpi_kernels")
    rng = np.random.default_rng(5)
    threads = numba.get_num_threads()
    print(f"{args.other.resolve()} (other) against {ROOT} (present); {threads} threads available")
    for n_sets in (int(text) for text in args.sets.split(",")):
        a = kernel_arguments(n_sets, rng)
        b = a[:-1] + (np.empty_like(a[-1]),)
        other.gpi_kernel(*a)
        present.gpi_kernel(*b)
        print(f"W = {n_sets}: the same bits: {np.array_equal(a[-1].view(np.int64), b[-1].view(np.int64))}")
        for count in sorted({1, threads}):
            numba.set_num_threads(count)
            times_other, times_present = [], []
            for _ in range(args.calls):
                t0 = time.perf_counter()
                other.gpi_kernel(*a)
                times_other.append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                present.gpi_kernel(*b)
                times_present.append(time.perf_counter() - t0)
            lo_o, lo_p = min(times_other), min(times_present)
            md_o, md_p = np.median(times_other), np.median(times_present)
            print(
                f"  {count} thread(s): other {1e3 * lo_o:.3f} ms (median {1e3 * md_o:.3f}), present "
                f"{1e3 * lo_p:.3f} ms (median {1e3 * md_p:.3f}); ratio {lo_p / lo_o:.3f} (medians {md_p / md_o:.3f})"
            )
        numba.set_num_threads(threads)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

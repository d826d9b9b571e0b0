"""Speed and memory of the GPI forward model, :func:`model.gpi`, against numpy baselines.

Run from the repository root::

    python benchmarks/forward.py            # full run, about a minute on 2 cores
    python benchmarks/forward.py --quick    # fewer repeats and sizes

Prints, for ``W`` parameter sets (default 64, perturbed around Table 1) on the
paper's input at ``T = 7001`` (100 Hz) and ``T = 70001`` (1 kHz) samples:

* the time of ``model.gpi`` and of a numpy loop over time vectorised over walkers and
  operators (:func:`numpy_time_loop`, the issue's baseline), both checked to agree with
  ``gpi`` to 1e-9 first, and their ratio (target >= 8x); also a stronger numpy
  baseline that precomputes every envelope for the whole record at once
  (:func:`numpy_precomputed_envelopes`, for context);
* throughput in operator updates per second, ``W * T * N / seconds``;
* time per unit of ``T``, ``N`` and ``W`` over a few sizes (linear cost: constant
  time per unit);
* the peak memory growth of one ``gpi`` call at ``W = 64``, ``T = 70001`` after warm-up,
  from :mod:`tracemalloc` (numpy allocations are traced) and from the resident-set
  high-water mark of a fresh process, against the size of the ``(W, T)`` output
  (target < 2x).

Every time is the best of several repeats (the machine is shared and noisy).
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time
import tracemalloc
from dataclasses import dataclass

import numpy as np

import model
from model import TABLE1, THETA_NAMES, gpi, paper_current

__all__ = ["numpy_time_loop", "numpy_precomputed_envelopes", "benchmark_theta", "best_time", "main"]

_RISING = {"swapped": slice(3, 7), "literal": slice(7, 11)}
_FALLING = {"swapped": slice(7, 11), "literal": slice(3, 7)}


def _envelope_columns(coefficients, v):
    """``k0 tanh(k1 v + k2) + k3`` for coefficient rows ``(W, 4)`` and a scalar or ``(W, 1)``/``(W, T)`` ``v``."""
    return coefficients[:, 0:1] * np.tanh(coefficients[:, 1:2] * v + coefficients[:, 2:3]) + coefficients[:, 3:4]


def _thresholds_and_weights(theta, n_operators):
    thresholds = theta[:, 0:1] * np.arange(1, n_operators + 1)  # (W, N)
    weights = theta[:, 1:2] * np.exp(-theta[:, 2:3] * thresholds)
    return thresholds, weights


def numpy_time_loop(theta, current, n_operators=12, reading="swapped"):
    """The baseline: a Python loop over time, each step vectorised over walkers and operators.

    Same equations as :func:`model.gpi` (no bound check, which only makes it faster).

    Parameters
    ----------
    theta : ndarray, shape (W, 19)
    current : ndarray, shape (T,)
        Shared by all walkers.
    n_operators : int, default 12
    reading : {"swapped", "literal"}, default "swapped"

    Returns
    -------
    ndarray, shape (W, T)
    """
    theta = np.atleast_2d(theta)
    rising, falling = theta[:, _RISING[reading]], theta[:, _FALLING[reading]]
    omega_up, omega_down = theta[:, 11:15], theta[:, 15:19]
    thresholds, weights = _thresholds_and_weights(theta, n_operators)
    out = np.empty((theta.shape[0], current.size))
    v = current[0]
    lower = _envelope_columns(rising, v) - thresholds
    upper = _envelope_columns(falling, v) + thresholds
    memory = np.maximum(lower, np.minimum(upper, 0.0))
    out[:, 0] = _envelope_columns(omega_up, v)[:, 0] + np.einsum("wn,wn->w", weights, memory)
    for k in range(1, current.size):
        v = current[k]
        step = v - current[k - 1]
        if step > 0:
            np.maximum(memory, _envelope_columns(rising, v) - thresholds, out=memory)
        elif step < 0:
            np.minimum(memory, _envelope_columns(falling, v) + thresholds, out=memory)
        omega = _envelope_columns(omega_up if step >= 0 else omega_down, v)[:, 0]
        out[:, k] = omega + np.einsum("wn,wn->w", weights, memory)
    return out


def numpy_precomputed_envelopes(theta, current, n_operators=12, reading="swapped"):
    """A stronger numpy baseline: every envelope and Omega for the whole record at once
    (four ``(W, T)`` arrays, SIMD ``tanh``), then a time loop doing only the operator updates.

    Same parameters and result as :func:`numpy_time_loop`.
    """
    theta = np.atleast_2d(theta)
    thresholds, weights = _thresholds_and_weights(theta, n_operators)
    rising = _envelope_columns(theta[:, _RISING[reading]], current[None, :])
    falling = _envelope_columns(theta[:, _FALLING[reading]], current[None, :])
    step = np.diff(current, prepend=current[0])
    omega = np.where(
        step >= 0,
        _envelope_columns(theta[:, 11:15], current[None, :]),
        _envelope_columns(theta[:, 15:19], current[None, :]),
    )
    out_t = np.empty((current.size, theta.shape[0]))  # time-major: contiguous rows per step
    memory = np.maximum(rising[:, 0:1] - thresholds, np.minimum(falling[:, 0:1] + thresholds, 0.0))
    scratch = np.empty_like(memory)
    rising_t, falling_t = np.ascontiguousarray(rising.T), np.ascontiguousarray(falling.T)
    np.einsum("wn,wn->w", weights, memory, out=out_t[0])
    for k in range(1, current.size):
        if step[k] > 0:
            np.subtract(rising_t[k][:, None], thresholds, out=scratch)
            np.maximum(memory, scratch, out=memory)
        elif step[k] < 0:
            np.add(falling_t[k][:, None], thresholds, out=scratch)
            np.minimum(memory, scratch, out=memory)
        np.einsum("wn,wn->w", weights, memory, out=out_t[k])
    return out_t.T + omega


def benchmark_theta(n_walkers, rng):
    """``(W, 19)`` parameter sets around Table 1 that keep the operator bounds apart on 0-5 A.

    ``rho``, ``tau`` and the Omega coefficients get +-5 % jitter; ``alpha`` is shrunk by up
    to 10 % (a smaller ``|alpha|`` only widens the margin between the bounds); the
    envelopes stay at Table 1.
    """
    theta = np.tile(TABLE1, (n_walkers, 1))
    jitter = [THETA_NAMES.index(n) for n in ("rho", "tau")] + list(range(11, 19))
    theta[:, jitter] *= 1.0 + 0.05 * rng.uniform(-1.0, 1.0, (n_walkers, len(jitter)))
    theta[:, 0] *= rng.uniform(0.9, 1.0, n_walkers)
    return theta


@dataclass(frozen=True)
class Timing:
    """Best-of-repeats wall-clock and CPU time of one call [s] (CPU time sums all threads)."""

    wall: float
    cpu: float


def best_time(function, repeats):
    """Best wall-clock and best CPU time of ``repeats`` calls of ``function()``, as :class:`Timing`."""
    wall = cpu = np.inf
    for _ in range(repeats):
        wall_start, cpu_start = time.perf_counter(), time.process_time()
        function()
        wall = min(wall, time.perf_counter() - wall_start)
        cpu = min(cpu, time.process_time() - cpu_start)
    return Timing(wall, cpu)


@dataclass(frozen=True)
class SpeedFigures:
    """One side-by-side timing of gpi (all threads and one thread) and the numpy baselines."""

    n_walkers: int
    n_samples: int
    n_operators: int
    gpi: Timing
    gpi_one_thread: Timing
    baseline: Timing
    precomputed: Timing

    @property
    def ratio(self):
        """Wall-clock speed-up over the numpy time loop (the issue's target: >= 8)."""
        return self.baseline.wall / self.gpi.wall

    @property
    def updates_per_second(self):
        return self.n_walkers * self.n_samples * self.n_operators / self.gpi.wall


def compare_speed(theta, current, n_operators, repeats, baseline_repeats):
    """Check the baselines agree with gpi to 1e-9, then time all of them."""
    import numba

    fast = gpi(theta, current, n_operators=n_operators)
    for baseline in (numpy_time_loop, numpy_precomputed_envelopes):
        slow = baseline(theta, current, n_operators)
        error = float(np.max(np.abs(fast - slow)))
        scale = 1.0 + float(np.max(np.abs(fast)))
        if not error <= 1e-9 * scale:
            raise SystemExit(f"{baseline.__name__} disagrees with model.gpi: max |difference| {error:.3g}")
    threads = numba.get_num_threads()
    gpi_all = best_time(lambda: gpi(theta, current, n_operators=n_operators), repeats)
    numba.set_num_threads(1)
    try:
        gpi_one = best_time(lambda: gpi(theta, current, n_operators=n_operators), repeats)
    finally:
        numba.set_num_threads(threads)
    return SpeedFigures(
        n_walkers=theta.shape[0],
        n_samples=current.size,
        n_operators=n_operators,
        gpi=gpi_all,
        gpi_one_thread=gpi_one,
        baseline=best_time(lambda: numpy_time_loop(theta, current, n_operators), baseline_repeats),
        precomputed=best_time(lambda: numpy_precomputed_envelopes(theta, current, n_operators), baseline_repeats),
    )


def single_thread_cpu(function, repeats):
    """Best CPU time [s] of ``function()`` with numba on one thread (least sensitive to other load)."""
    import numba

    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        return best_time(function, repeats).cpu
    finally:
        numba.set_num_threads(threads)


def _rss_growth_in_fresh_process(theta_file, fs):
    """Resident-set high-water-mark growth [bytes] of one gpi call in a fresh process, or None.

    The process loads ``theta`` from ``theta_file``, loads the compiled kernel with a tiny
    call, then records ``VmHWM`` before and after one full-size call.
    """
    if not os.path.exists("/proc/self/status"):
        return None
    code = f"""
import numpy as np
from model import gpi, paper_current
def high_water_mark():
    for line in open('/proc/self/status'):
        if line.startswith('VmHWM:'):
            return int(line.split()[1]) * 1024
theta = np.load({theta_file!r})
current = paper_current({fs!r})[1]
gpi(theta[:2], current[:100])
before = high_water_mark()
out = gpi(theta, current)
print(high_water_mark() - before)
"""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    if result.returncode != 0:
        print(f"  (resident-set measurement failed: {result.stderr.strip()[-200:]})")
        return None
    return int(result.stdout.split()[-1])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--walkers", type=int, default=64, help="batch size W (default 64)")
    parser.add_argument("--operators", type=int, default=12, help="number of operators N (default 12)")
    parser.add_argument("--repeats", type=int, default=15, help="repeats per gpi timing (best of; default 15)")
    parser.add_argument("--quick", action="store_true", help="fewer repeats and sizes")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    repeats = 3 if args.quick else args.repeats
    rng = np.random.default_rng(args.seed)
    n_operators = args.operators
    theta = benchmark_theta(args.walkers, rng)

    import numba

    print(
        f"model.gpi benchmark  ({time.strftime('%Y-%m-%d')}, {platform.machine()}, {os.cpu_count()} cores, "
        f"numba {numba.__version__} with {numba.get_num_threads()} threads, numpy {np.__version__})"
    )
    gpi(theta[:2], paper_current(100.0)[1][:100])  # compile or load the cached kernel

    print("\n== speed against numpy (best of repeats; baselines checked to agree with gpi to 1e-9) ==")
    print("   times in ms, wall-clock (CPU time summed over threads in brackets)")
    for fs in (100.0, 1000.0):
        current = paper_current(fs)[1]
        f = compare_speed(theta, current, n_operators, repeats, 2 if fs > 100 or args.quick else 3)
        print(f"W = {f.n_walkers}, T = {f.n_samples}, N = {n_operators}:")
        print(
            f"  gpi, {numba.get_num_threads()} threads:        {f.gpi.wall * 1e3:9.2f}  ({f.gpi.cpu * 1e3:9.2f})   "
            f"{f.updates_per_second:.3g} operator updates/s"
        )
        print(f"  gpi, 1 thread:          {f.gpi_one_thread.wall * 1e3:9.2f}  ({f.gpi_one_thread.cpu * 1e3:9.2f})")
        print(
            f"  numpy time loop:        {f.baseline.wall * 1e3:9.2f}  ({f.baseline.cpu * 1e3:9.2f})   "
            f"ratio {f.ratio:.1f}x wall; against gpi on 1 thread {f.baseline.wall / f.gpi_one_thread.wall:.1f}x wall, "
            f"{f.baseline.cpu / f.gpi_one_thread.cpu:.1f}x CPU time"
        )
        print(
            f"  numpy, envelopes first: {f.precomputed.wall * 1e3:9.2f}  ({f.precomputed.cpu * 1e3:9.2f})   "
            f"ratio {f.precomputed.wall / f.gpi.wall:.1f}x wall"
        )

    print("\n== linearity (gpi; numba on 1 thread, best CPU time: constant time per unit = linear cost) ==")
    base_current = paper_current(100.0)[1]
    sizes_t = (100.0, 200.0, 400.0) if args.quick else (100.0, 200.0, 400.0, 800.0)
    print(f"T sweep (W = {args.walkers}, N = {n_operators}):")
    for fs in sizes_t:
        current = paper_current(fs)[1]
        seconds = single_thread_cpu(lambda: gpi(theta, current, n_operators), repeats)
        print(
            f"  T = {current.size:>6}: {seconds * 1e3:8.2f} ms  {seconds / (args.walkers * current.size) * 1e9:6.2f} "
            "ns per walker-sample"
        )
    print(f"N sweep (W = {args.walkers}, T = {base_current.size}); cost = per-sample part + per-operator part:")
    n_values = (1, 6, 12, 24) if args.quick else (1, 6, 12, 24, 48)
    per_walker_sample = []
    for n in n_values:
        seconds = single_thread_cpu(lambda: gpi(theta, base_current, n), repeats)
        per_walker_sample.append(seconds / (args.walkers * base_current.size))
        print(f"  N = {n:>3}: {seconds * 1e3:8.2f} ms  {per_walker_sample[-1] * 1e9:6.2f} ns per walker-sample")
    slope, intercept = np.polyfit(n_values, per_walker_sample, 1)
    print(f"  least-squares fit: {intercept * 1e9:.2f} ns per walker-sample + {slope * 1e9:.3f} ns per operator update")
    print(f"W sweep (T = {base_current.size}, N = {n_operators}):")
    for n_walkers in (16, 32, 64, 128):
        batch = benchmark_theta(n_walkers, np.random.default_rng(args.seed + 1))
        seconds = single_thread_cpu(lambda: gpi(batch, base_current, n_operators), repeats)
        print(f"  W = {n_walkers:>4}: {seconds * 1e3:8.2f} ms  {seconds / n_walkers * 1e6:8.1f} us per walker")

    print(f"\n== memory of one gpi call (W = {args.walkers}, T = 70001, after warm-up) ==")
    current = paper_current(1000.0)[1]
    gpi(theta, current)  # warm-up at full size
    tracemalloc.start()
    tracemalloc.reset_peak()
    start_bytes, _ = tracemalloc.get_traced_memory()
    out = gpi(theta, current)
    _, peak_bytes = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    growth = peak_bytes - start_bytes
    print(f"  output (W, T) float64:           {out.nbytes / 2**20:8.2f} MiB")
    print(f"  tracemalloc peak growth:         {growth / 2**20:8.2f} MiB  = {growth / out.nbytes:.3f} x output")
    del out

    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        theta_file = os.path.join(folder, "theta.npy")
        np.save(theta_file, theta)
        rss = _rss_growth_in_fresh_process(theta_file, 1000.0)
    if rss is not None:
        output_bytes = args.walkers * current.size * 8
        print(
            f"  resident-set high-water growth:  {rss / 2**20:8.2f} MiB  = {rss / output_bytes:.3f} x output "
            "(fresh process, kernel loaded, includes the output itself)"
        )
    print(f"\nmodel package: {os.path.dirname(model.__file__)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Reading ``chain.h5`` while a study writes it never stops the study.

HDF5 locks an open file (a reader takes a shared lock, a writer an exclusive one) and an
open refused by a lock failed at once ("unable to lock file, errno = 11"): a person
polling the chain with emcee's ``HDFBackend`` (as tests/test_interrupt.py does every
0.05 s) once crashed the study it was watching. The writer now waits for the reader with
a short back-off (:func:`identify.data.hdf5.open_hdf5`), and the package's own readers
take no lock. The readers here are other processes using the stock h5py/emcee, which do
take the lock: the worst case.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import emcee
import h5py
import numpy as np
import pytest

from identify.bench import simulate
from identify.data import hdf5
from identify.data.records import write_record
from identify.fitting.chain_file import (
    CHAIN_DTYPE,
    LAST_STEP,
    LOG_PROB_QUANTUM,
    ChainFileError,
    chain_info,
    stored_log_prob,
)
from identify.fitting.posterior import BACKEND_GROUP, BufferedHDFBackend, ChainBackend

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: A process that opens the file as emcee's read-only backend does (h5py, with the HDF5
#: lock), over and over, until the file ``stop`` exists; prints how often it read.
HAMMER = """
import os, sys, time, h5py
path, stop, pause = sys.argv[1], sys.argv[2], float(sys.argv[3])
reads = 0
while not os.path.exists(stop):
    try:
        with h5py.File(path, "r") as f:
            f["mcmc"].attrs["iteration"]
            reads += 1
    except (OSError, KeyError):
        pass  # not created yet, or held by the writer this instant
    if pause:
        time.sleep(pause)
print(reads)
"""

#: A process that holds the file open (with its lock) for ``seconds``, after saying so.
HOLDER = """
import sys, time, h5py
with h5py.File(sys.argv[1], "r") as f:
    print("open", flush=True)
    time.sleep(float(sys.argv[2]))
"""


def _python(code, *args, **kwargs):
    return subprocess.Popen([sys.executable, "-c", code, *map(str, args)], stdout=subprocess.PIPE, text=True, **kwargs)


def _new_chain(path, n_walkers=8, ndim=3, **kwargs) -> BufferedHDFBackend:
    backend = BufferedHDFBackend(path, name=BACKEND_GROUP, **kwargs)
    backend.reset(n_walkers, ndim)
    return backend


def _as_stored(coords) -> np.ndarray:
    """Coordinates as the chain file stores them (CHAIN_DTYPE), read back as float64."""
    return np.stack(coords).astype(CHAIN_DTYPE).astype(np.float64)


def test_stored_log_probabilities_lie_within_half_a_step_and_keep_what_is_not_finite():
    log_prob = np.array([-1708826.5623137, -12345.678901, 0.3, 4e-4, -np.inf, np.nan])
    kept = stored_log_prob(log_prob)
    assert np.all(np.abs(kept[:4] - log_prob[:4]) <= LOG_PROB_QUANTUM / 2)
    assert np.array_equal(np.round(kept[:4] / LOG_PROB_QUANTUM), kept[:4] / LOG_PROB_QUANTUM)  # multiples
    assert kept[3] == 0.0 and kept[4] == -np.inf and np.isnan(kept[5])


def _steps(n, n_walkers=8, ndim=3, seed=0):
    rng = np.random.default_rng(seed)
    state = np.random.RandomState(seed).get_state()
    for _ in range(n):
        yield emcee.State(rng.normal(size=(n_walkers, ndim)), log_prob=rng.normal(size=n_walkers), random_state=state)


def test_the_writer_waits_for_a_reader_holding_the_lock(tmp_path):
    """A reader keeps the file open (and locked) for 0.5 s: the flush waits and then writes."""
    path = tmp_path / "chain.h5"
    backend = _new_chain(path, flush_every=10**6, flush_seconds=1e9)
    backend.grow(5, None)
    steps = list(_steps(5))
    for state in steps:
        backend.save_step(state, np.ones(8, dtype=bool))
    holder = _python(HOLDER, path, 0.5)
    assert holder.stdout.readline().strip() == "open"
    started = time.monotonic()
    backend.flush()
    assert time.monotonic() - started > 0.2  # it did wait for the reader
    holder.wait(timeout=30)
    stored = ChainBackend(str(path), name=BACKEND_GROUP, read_only=True)
    assert stored.iteration == 5
    assert np.array_equal(stored.get_chain(), _as_stored([s.coords for s in steps]))
    assert np.array_equal(stored.get_log_prob(), stored_log_prob([s.log_prob for s in steps]))
    # the last step also in full precision: what a resumed run continues from
    last = stored.get_last_sample()
    assert np.array_equal(last.coords, steps[-1].coords) and np.array_equal(last.log_prob, steps[-1].log_prob)


def test_a_reader_holding_the_file_too_long_is_one_clear_error_and_no_step_is_lost(tmp_path):
    path = tmp_path / "chain.h5"
    backend = _new_chain(path, flush_every=10**6, flush_seconds=1e9)
    backend.lock_wait = 0.3
    backend.grow(3, None)
    for state in _steps(3):
        backend.save_step(state, np.ones(8, dtype=bool))
    holder = _python(HOLDER, path, 3.0)
    try:
        assert holder.stdout.readline().strip() == "open"
        with pytest.raises(BlockingIOError, match="held open by another process.*rerun"):
            backend.flush()
    finally:
        holder.kill()
        holder.wait(timeout=30)
    backend.flush()  # the lock is gone: the steps kept in memory are written now
    assert ChainBackend(str(path), name=BACKEND_GROUP, read_only=True).iteration == 3


def test_the_package_reads_a_chain_without_blocking_a_writer(tmp_path):
    """While another process holds the file open for writing, the package's reader opens it
    at once (no lock taken) instead of failing or waiting."""
    path = tmp_path / "chain.h5"
    backend = _new_chain(path)
    backend.grow(2, None)
    for state in _steps(2):
        backend.save_step(state, np.ones(8, dtype=bool))
    backend.flush()
    writer = _python(
        'import sys, time, h5py\nf = h5py.File(sys.argv[1], "a")\nprint("open", flush=True)\ntime.sleep(5)\n', path
    )
    try:
        assert writer.stdout.readline().strip() == "open"
        with pytest.raises(OSError):  # the stock reader is refused by the writer's lock
            h5py.File(path, "r")
        started = time.monotonic()
        with hdf5.open_hdf5(path, "r") as f:
            assert int(f[BACKEND_GROUP].attrs["iteration"]) == 2
        assert time.monotonic() - started < 1.0
    finally:
        writer.kill()
        writer.wait(timeout=30)


def test_buffered_writes_under_a_hammering_reader_are_all_kept(tmp_path, monkeypatch):
    """400 flushes (one per step) while another process opens the file in a tight loop."""
    lock_errors = []
    real = hdf5.is_lock_error
    monkeypatch.setattr(hdf5, "is_lock_error", lambda exc: lock_errors.append(exc) or real(exc))
    path, stop = tmp_path / "chain.h5", tmp_path / "stop"
    backend = _new_chain(path, flush_every=1)
    reader = _python(HAMMER, path, stop, 0)
    try:
        steps = list(_steps(400))
        backend.grow(len(steps), None)
        for state in steps:
            backend.save_step(state, np.ones(8, dtype=bool))
        backend.flush()
    finally:
        stop.touch()
        reads = int(reader.communicate(timeout=60)[0])
    assert reads > 0
    stored = ChainBackend(str(path), name=BACKEND_GROUP, read_only=True)
    assert stored.iteration == 400
    assert np.array_equal(stored.get_chain(), _as_stored([s.coords for s in steps]))
    assert np.array_equal(stored.get_log_prob(), stored_log_prob([s.log_prob for s in steps]))
    print(f"{reads} reads, {len(lock_errors)} opens refused by the reader's lock and retried")


def test_a_study_finishes_while_its_chain_is_read_all_the_time(tmp_path):
    """The regression: a real ``study`` process, its chain.h5 polled by another process
    with emcee's read-only backend every millisecond; the study ends normally (exit code 1:
    400 steps do not converge, a finding) with the whole chain written."""
    csv = tmp_path / "small.csv"
    write_record(csv, simulate(fs=5.0, seed=4).record)
    out, stop = tmp_path / "run", tmp_path / "stop"
    out.mkdir()
    env = dict(os.environ, PYTHONUNBUFFERED="1")  # this work tree's code, wherever the package is installed from
    env["PYTHONPATH"] = ROOT + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.pop("IDENTIFY_DEBUG", None)
    reader = _python(HAMMER, out / "chain.h5", stop, 0.001)
    try:
        study = subprocess.run(
            [
                sys.executable,
                "-m",
                "identify",
                "study",
                str(csv),
                "--out",
                str(out),
                "--max-steps",
                "400",
                "--check-every",
                "20",
                "--n-starts",
                "1",
                "--progress",
                "off",
                "--no-report",
            ],
            capture_output=True,
            text=True,
            env=env,
            cwd=ROOT,
            timeout=600,
        )
    finally:
        stop.touch()
        reads = int(reader.communicate(timeout=60)[0])
    assert study.returncode == 1, study.stderr[-3000:]
    assert "NOT CONVERGE" in study.stderr and "error" not in study.stderr.lower(), study.stderr[-3000:]
    assert reads > 0
    stored = ChainBackend(str(out / "chain.h5"), name=BACKEND_GROUP, read_only=True)
    assert stored.iteration == 400
    assert np.isfinite(stored.get_chain()).all() and np.isfinite(stored.get_log_prob()).all()
    assert (out / "summary.json").is_file() and (out / "posterior.nc").is_file()


def test_open_hdf5_backs_off_and_gives_up_after_its_wait(tmp_path, monkeypatch):
    """The back-off on a lock error, with a fake clock: 5 ms doubling to 0.25 s, within ``wait``."""
    import errno

    calls = []

    def locked(path, mode, **kwargs):
        calls.append(mode)
        raise BlockingIOError(errno.EAGAIN, "Unable to synchronously open file (unable to lock file, errno = 11)")

    monkeypatch.setattr(h5py, "File", locked)
    now, slept = [0.0], []

    def sleep(seconds):
        slept.append(seconds)
        now[0] += seconds

    with pytest.raises(BlockingIOError, match="for more than 2 s"):
        hdf5.open_hdf5(tmp_path / "x.h5", "a", wait=2.0, sleep=sleep, clock=lambda: now[0])
    assert slept[:3] == [0.005, 0.01, 0.02] and max(slept) == 0.25 and sum(slept) <= 2.0
    assert len(calls) == len(slept) + 1

    def missing(path, mode, **kwargs):
        raise FileNotFoundError(errno.ENOENT, "no such file")

    monkeypatch.setattr(h5py, "File", missing)
    with pytest.raises(FileNotFoundError):  # not a lock error: raised at once
        hdf5.open_hdf5(tmp_path / "x.h5", "a", sleep=lambda s: pytest.fail("slept"))


def test_the_last_step_is_kept_in_full_precision_in_two_slots(tmp_path):
    """Each flush writes the slot not holding the present count's step; a slot that does not round
    to the stored last step is damage that chain_info names."""
    path = tmp_path / "chain.h5"
    backend = _new_chain(path, flush_every=10**6, flush_seconds=1e9)
    steps = list(_steps(6))
    backend.grow(6, None)
    for k, state in enumerate(steps):
        backend.save_step(state, np.ones(8, dtype=bool))
        if k in (2, 5):
            backend.flush()
    with h5py.File(path, "r") as f:
        slots = f[BACKEND_GROUP][LAST_STEP]
        assert sorted(slots.attrs["iterations"]) == [3, 6]
        assert f[BACKEND_GROUP]["chain"].dtype == CHAIN_DTYPE
    assert chain_info(path)[0] == 6
    last = ChainBackend(str(path), name=BACKEND_GROUP, read_only=True).get_last_sample()
    assert np.array_equal(last.coords, steps[-1].coords)
    with h5py.File(path, "r+") as f:
        slots = f[BACKEND_GROUP][LAST_STEP]
        which = list(slots.attrs["iterations"]).index(6)
        slots[which, 0, 0] += 1.0
    with pytest.raises(ChainFileError, match="full-precision copy of its last step"):
        chain_info(path)


def test_a_signal_during_a_flush_takes_effect_when_the_flush_ends(tmp_path, monkeypatch):
    """A SIGTERM that lands between the acceptance counts and the step count (here: while the
    random state is written) interrupts only once the flush is whole; the flush done again
    after it (sample_posterior's final one) then has nothing to write, so no step's acceptance
    is counted twice."""
    import signal

    path = tmp_path / "chain.h5"
    backend = _new_chain(path, n_walkers=4, ndim=2, flush_every=10**6, flush_seconds=1e9)
    state = np.random.RandomState(0).get_state()
    for k in range(3):
        backend.save_step(
            emcee.State(np.full((4, 2), float(k)), log_prob=np.zeros(4), random_state=state), np.ones(4, bool)
        )
    setitem = h5py.AttributeManager.__setitem__

    def signalling(self, name, value):
        setitem(self, name, value)
        if name == "random_state_0":
            os.kill(os.getpid(), signal.SIGTERM)

    def interrupt(signum, frame):
        raise KeyboardInterrupt("SIGTERM")

    monkeypatch.setattr(h5py.AttributeManager, "__setitem__", signalling)
    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        with pytest.raises(KeyboardInterrupt):
            backend.flush()
    finally:
        signal.signal(signal.SIGTERM, previous)
    monkeypatch.undo()
    backend.flush()
    with h5py.File(path, "r") as f:
        group = f[BACKEND_GROUP]
        assert group.attrs["iteration"] == 3
        np.testing.assert_array_equal(group["accepted"][:], [3, 3, 3, 3])

"""The chain file ``chain.h5``: emcee's HDF5 backend as the package writes and reads it.

* :class:`ChainBackend`: emcee's :class:`emcee.backends.HDFBackend` opening the file through
  :func:`identify.data.hdf5.open_hdf5` (readers take no lock, writers wait for one, free disk
  space checked before HDF5 writes).
* :class:`BufferedHDFBackend`: the sampler's writer, steps buffered and written in batches,
  the chain stored in float32 and the log-probabilities in float64 rounded to a stated
  precision (:func:`stored_log_prob`), compressed (chunked, shuffle + gzip), the last step
  also in full precision (what a resumed run continues from),
  the step count written after the steps it claims, a CRC-32 of the last step with it.
* :func:`compact_chain_file`: the finished chain rewritten without the unused space its
  batched writes left in the file (same data, bit for bit).
* :func:`chain_info`: the shape of a stored chain, every claimed step checked readable and
  written (what a resumed run needs), :class:`identify.data.hdf5.ChainFileError` otherwise.

The sampling that writes it is :func:`identify.fitting.posterior.sample_posterior`.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import threading
import time as _time
import zlib

import emcee
import h5py
import numpy as np

from ..data.fileio import require_space, write_via_temporary
from ..data.hdf5 import LOCK_WAIT_SECONDS, ChainFileError, open_hdf5

__all__ = [
    "BACKEND_GROUP",
    "CHAIN_CHUNK_STEPS",
    "CHAIN_DTYPE",
    "CHAIN_GZIP_LEVEL",
    "LAST_STEP",
    "CHAIN_METADATA_BYTES",
    "LOG_PROB_QUANTUM",
    "stored_log_prob",
    "LAST_STEP_CHECK",
    "ChainBackend",
    "BufferedHDFBackend",
    "ChainFileError",
    "chain_info",
    "compact_chain_file",
    "signals_after",
    "signal_handlers",
    "last_step",
]


#: HDF5 group of the emcee backend in ``chain.h5``.
BACKEND_GROUP = "mcmc"


#: Steps per HDF5 chunk of the stored chain (the unit of compression and of partial reads). A
#: flush (about one a second) rewrites the chunk being filled whole, compressed again, so its
#: cost grows with the chunk: 64 steps keep a flush a few milliseconds, for a file a few percent
#: larger than with chunks several times longer.
CHAIN_CHUNK_STEPS = 64
#: Type of the stored chain's coordinates. float32 keeps 24 bits of each coordinate (a relative
#: rounding of at most 6e-8, far below the spread of any posterior the chain describes) and
#: halves the file's largest part; the sampler itself runs in float64, and the last step is
#: also kept in float64 (:data:`LAST_STEP`), so a resumed run continues exactly where it stopped.
CHAIN_DTYPE = np.float32
#: Dataset of the emcee group: the last step in full precision, in two slots written in turn,
#: shape ``(2, walkers, dimension + 1)`` (the coordinates, then the log-probability); its
#: attribute ``iterations`` holds each slot's step count. The slot whose count is the group's
#: ``iteration`` is the one a resumed run continues from.
LAST_STEP = "last_step"
#: The stored log-probabilities are rounded to a multiple of this [nats] (2^-10, about 1e-3).
#: Their digits below it are noise and cost half of their share of the file; the posterior's
#: own spread of log-probabilities is about sqrt(dimension / 2) nats, and a resumed run
#: continues from the full-precision last step (:data:`LAST_STEP`), never from these.
LOG_PROB_QUANTUM = 2.0**-10
#: gzip level of the stored chain (4: within a few percent of level 9's size, several times faster).
CHAIN_GZIP_LEVEL = 4
#: Bytes kept free for HDF5's own bookkeeping (chunk index, attributes) beyond the chain's data [B].
CHAIN_METADATA_BYTES = 256 * 1024
#: Attribute of the emcee group: ``"<iteration>:<crc32>"`` of the last step, written with the count.
LAST_STEP_CHECK = "last_step_check"


class ChainBackend(emcee.backends.HDFBackend):
    """emcee's HDF5 backend opening the file through :func:`identify.data.hdf5.open_hdf5`:
    reading takes no HDF5 file lock (a reader never blocks the study writing the chain),
    and a write waits, with a short back-off, for a lock another process holds (a person
    reading ``chain.h5`` while the study runs) instead of failing. Same file format;
    ``ChainBackend(path, name, read_only=True)`` is the package's reader of a chain.

    A write never meets a full disk inside HDF5 (whose failed cache write ends the process
    by a signal and leaves a chain that claims steps it does not hold): an open for
    writing first checks that :data:`CHAIN_METADATA_BYTES` are free, and a flush of
    :class:`BufferedHDFBackend` the whole of what it may write
    (:func:`identify.data.fileio.require_space`); short of that, it raises
    :class:`identify.data.fileio.DiskFullError` naming the file, with nothing written.
    A link at the path is refused (:func:`identify.data.hdf5.open_hdf5`)."""

    #: Longest wait [s] for another process's lock on the file before a write fails
    #: (:data:`identify.data.hdf5.LOCK_WAIT_SECONDS`).
    lock_wait = LOCK_WAIT_SECONDS

    def open(self, mode="r"):
        if self.read_only and mode != "r":
            raise RuntimeError(
                "The backend has been loaded in read-only mode. Set `read_only = False` to make changes."
            )
        if mode != "r":
            require_space(self.filename, CHAIN_METADATA_BYTES)
        return open_hdf5(self.filename, mode, wait=self.lock_wait)

    def get_value(self, name, flat=False, thin=1, discard=0):
        """emcee's reader, the chain given as float64 (stored in :data:`CHAIN_DTYPE`): every
        computation on it runs in double precision, whatever the file holds."""
        value = super().get_value(name, flat=flat, thin=thin, discard=discard)
        return value if value is None or value.dtype == np.float64 else value.astype(np.float64)

    def get_last_sample(self):
        """The last stored step with its random state: its full-precision slot (:data:`LAST_STEP`)
        when the file has one for the present count, else the stored chain's last row."""
        last = last_step(self.filename, self.name)
        if last is None:
            return super().get_last_sample()
        return emcee.State(last[0], log_prob=last[1], blobs=None, random_state=self.random_state)


class BufferedHDFBackend(ChainBackend):
    """emcee's HDF5 backend, writing steps in batches instead of opening the file per step.

    The stock :class:`emcee.backends.HDFBackend` opens, writes and closes the file for
    every step (about 3-10 ms, as much as a 36-walker model evaluation). This subclass
    keeps completed steps in memory and writes them in one go every ``flush_every``
    steps or ``flush_seconds`` seconds, before the chain grows, and whenever
    :meth:`flush` is called: :func:`identify.fitting.posterior.sample_posterior` flushes after every chunk and on
    any exception, including ``KeyboardInterrupt`` (Ctrl-C) and the ``SIGTERM`` that
    ``study`` turns into one. Only a hard kill (``SIGKILL``, power loss) can lose the
    unflushed steps, at most ``flush_seconds`` of work. The file format is emcee's,
    readable by the stock backend.

    The chain is stored in :data:`CHAIN_DTYPE` (float32) and the log-probabilities in
    float64 rounded to :data:`LOG_PROB_QUANTUM` (:func:`stored_log_prob`), compressed (HDF5
    chunks of :data:`CHAIN_CHUNK_STEPS` steps, byte shuffle and
    gzip level :data:`CHAIN_GZIP_LEVEL`): a rejected proposal repeats the walker's previous
    position exactly, so a chain compresses several fold (a 6000-step, 36 x 18 chain: 15.6
    MB raw in float32, 2.5 MB stored). The last step is kept in float64 as well
    (:data:`LAST_STEP`, two slots written in turn, so a write cut short leaves the previous
    count's slot whole): a resumed run continues from exactly the walkers an uninterrupted
    run would, and its chain is bit for bit the same. HDF5 readers decompress transparently.

    A flush writes the steps' data first and hands them to the operating system
    (``H5Fflush``), and only then the acceptance counts, the random state and the step count
    ``iteration`` that claims them: a process that dies in between (a full disk, a signal)
    leaves the previous count, whose steps are all stored, and the rerun resumes from it.
    """

    def __init__(self, filename, name=BACKEND_GROUP, *, flush_every=200, flush_seconds=1.0, **kwargs):
        super().__init__(str(filename), name=name, **kwargs)
        self.flush_every = int(flush_every)
        self.flush_seconds = float(flush_seconds)
        self._pending = []
        self._last_flush = _time.monotonic()

    def reset(self, nwalkers, ndim):
        """emcee's :meth:`~emcee.backends.HDFBackend.reset` (same group, datasets and
        attributes) with chunked, compressed ``chain`` and ``log_prob`` datasets, in a file
        created by :func:`_create_chain_file` when there is none."""
        if not os.path.lexists(self.filename):
            _create_chain_file(self.filename)
        with self.open("a") as f:
            if self.name in f:
                del f[self.name]
            g = f.create_group(self.name)
            g.attrs["version"] = emcee.__version__
            g.attrs["nwalkers"] = nwalkers
            g.attrs["ndim"] = ndim
            g.attrs["has_blobs"] = False
            g.attrs["iteration"] = 0
            g.create_dataset("accepted", data=np.zeros(nwalkers))
            packed = dict(compression="gzip", compression_opts=CHAIN_GZIP_LEVEL, shuffle=True)
            g.create_dataset(
                "chain",
                (0, nwalkers, ndim),
                maxshape=(None, nwalkers, ndim),
                chunks=(CHAIN_CHUNK_STEPS, nwalkers, ndim),
                dtype=CHAIN_DTYPE,
                **packed,
            )
            g.create_dataset(
                "log_prob",
                (0, nwalkers),
                maxshape=(None, nwalkers),
                chunks=(CHAIN_CHUNK_STEPS, nwalkers),
                dtype=np.float64,
                **packed,
            )
            last = g.create_dataset(LAST_STEP, data=np.zeros((2, nwalkers, ndim + 1)))
            last.attrs["iterations"] = np.array([-1, -1])

    def save_step(self, state, accepted):
        if state.blobs is not None:
            raise ValueError("BufferedHDFBackend does not store blobs")
        self._pending.append((np.array(state.coords), np.array(state.log_prob), np.array(accepted), state.random_state))
        if len(self._pending) >= self.flush_every or _time.monotonic() - self._last_flush > self.flush_seconds:
            self.flush()

    def flush(self) -> None:
        """Write the buffered steps (one file open); a no-op when nothing is pending.

        The open waits for a lock held by another process's reader (:class:`ChainBackend`);
        the steps leave the buffer only once written. A Ctrl-C or SIGTERM that arrives during
        the write takes effect when it ends (:func:`signals_after`): a write cut between the
        acceptance counts and the step count that claims them, then done again, would count
        its steps' acceptances twice."""
        self._last_flush = _time.monotonic()
        if not self._pending:
            return
        with signals_after():
            self._write_pending()

    def _write_pending(self) -> None:
        pending = self._pending
        n = len(pending)
        with self.open("a") as f:
            g = f[self.name]
            chain, log_prob = g["chain"], g["log_prob"]
            start = int(g.attrs["iteration"])
            slot_bytes = g[LAST_STEP].nbytes if LAST_STEP in g else 0  # rewritten in place: its size at most
            require_space(self.filename, CHAIN_METADATA_BYTES + slot_bytes + _bytes_to_write(chain, start, n, log_prob))
            if chain.shape[0] < start + n:
                chain.resize(start + n, axis=0)
                log_prob.resize(start + n, axis=0)
            log_probs = stored_log_prob(np.stack([p[1] for p in pending]))
            chain[start : start + n] = np.stack([p[0] for p in pending])
            log_prob[start : start + n] = log_probs
            if LAST_STEP in g:  # the slot not holding the present count's step: that one stays intact
                slots = g[LAST_STEP]
                counts = np.array(slots.attrs["iterations"])
                slot = 1 if counts[0] == start else 0
                slots[slot] = np.column_stack([pending[-1][0], pending[-1][1]])
                counts[slot] = start + n
                slots.attrs["iterations"] = counts
            f.flush()  # the steps' data reach the file before the count that claims them
            g["accepted"][:] += np.sum([p[2] for p in pending], axis=0)
            for i, value in enumerate(pending[-1][3]):
                g.attrs[f"random_state_{i}"] = value
            last = pending[-1][0]
            g.attrs[LAST_STEP_CHECK] = _step_check(start + n, last, log_probs[-1], chain.dtype, log_prob.dtype)
            g.attrs["iteration"] = start + n
        self._pending = []

    def grow(self, ngrow, blobs):
        self.flush()
        super().grow(ngrow, blobs)


@contextlib.contextmanager
def signal_handlers(handler):
    """Within the block, ``handler(signum, frame)`` handles SIGINT (Ctrl-C) and SIGTERM; the
    handlers before it are put back at its end. Yields whether it was put in: only in the main
    thread (elsewhere Python runs no signal handler, and nothing changes). A signal the process
    ignores stays ignored, and a handler installed outside Python (``getsignal``: None), which
    could not be put back, is left alone."""
    if threading.current_thread() is not threading.main_thread():
        yield False
        return
    catch = [sig for sig in (signal.SIGINT, signal.SIGTERM) if signal.getsignal(sig) not in (signal.SIG_IGN, None)]
    previous = {sig: signal.signal(sig, handler) for sig in catch}
    try:
        yield True
    finally:
        for sig, kept in previous.items():
            signal.signal(sig, kept)


@contextlib.contextmanager
def signals_after():
    """Within the block, SIGINT (Ctrl-C) and SIGTERM are held and handled when it ends, by the
    handlers in place before it, in the order they came (:func:`signal_handlers`: main thread
    only)."""
    held = []
    try:
        with signal_handlers(lambda signum, frame: held.append(signum)):
            yield
    finally:
        for signum in held:
            signal.raise_signal(signum)


def last_step(path, name=BACKEND_GROUP):
    """``(coordinates (walkers, dimension), log-probabilities (walkers,))`` of the last stored step
    in full precision, or None when the file has no slot for its present count (an empty
    chain, or a file written without one)."""
    with open_hdf5(os.fspath(path), "r") as f:
        g = f[name]
        if LAST_STEP not in g:
            return None
        steps = int(g.attrs["iteration"])
        counts = list(np.array(g[LAST_STEP].attrs["iterations"]))
        if steps <= 0 or steps not in counts:
            return None
        values = g[LAST_STEP][counts.index(steps)]
    return values[:, :-1], values[:, -1]


def stored_log_prob(log_prob) -> np.ndarray:
    """Log-probabilities as the chain file stores them: rounded to the nearest multiple of
    :data:`LOG_PROB_QUANTUM` (a power of two, so the division and product are exact),
    non-finite values kept."""
    return np.round(np.asarray(log_prob, dtype=float) / LOG_PROB_QUANTUM) * LOG_PROB_QUANTUM


def _create_chain_file(path) -> None:
    """A new, empty HDF5 file at ``path`` that keeps its free space across opens (HDF5's
    free-space manager, persistent): every flush rewrites the chunk being filled, and
    without it the old copy's space is lost once the file closes, so a chain written
    every second grew to several times its data (34.5 MB for 6.0 MB at load 12). ``"x"``
    refuses anything already at the path, a link included."""
    require_space(path, CHAIN_METADATA_BYTES)
    with h5py.File(os.fspath(path), "x", fs_strategy="fsm", fs_persist=True):
        pass


def compact_chain_file(path) -> tuple[int, int]:
    """Rewrite the finished chain file ``path`` without the space its batched writes left
    behind; returns its size in bytes before and after.

    Every flush of :class:`BufferedHDFBackend` rewrites the HDF5 chunk being filled, and
    the free-space manager reuses only part of the old copies' space: a finished chain's
    file holds some 15-20 % of unused space beyond its compressed data. The group is
    copied, chunks as stored (HDF5's object copy: same datasets, chunking, filters,
    maximum shape and attributes, so the chain, its random state and step count are
    bit for bit the same and the file can be extended or resumed as before), into a new
    file in the same folder (:func:`_create_chain_file`'s free-space settings), which
    then replaces ``path`` (:func:`identify.data.fileio.write_via_temporary`: the old
    file is intact until the rename; a reader holding it open keeps reading it).

    Raises
    ------
    OSError
        Including :class:`identify.data.fileio.DiskFullError` (less free space than the
        file's size): ``path`` is then unchanged.
    """
    path = os.fspath(path)
    before = os.path.getsize(path)

    def copy(tmp):
        with open_hdf5(path, "r") as src, h5py.File(tmp, "w", fs_strategy="fsm", fs_persist=True) as dst:
            for name in src:
                src.copy(src[name], dst, name)
            dst.attrs.update(src.attrs)

    write_via_temporary(path, copy, need_bytes=before + CHAIN_METADATA_BYTES)
    return before, os.path.getsize(path)


def _step_check(iteration, coords, log_prob, chain_dtype, log_prob_dtype) -> str:
    """``"<iteration>:<crc32>"`` of the last stored step's walkers and log-probabilities as stored
    (a text attribute: :mod:`identify.workflows.reproduce` compares numeric attributes only)."""
    data = np.ascontiguousarray(coords, dtype=chain_dtype).tobytes()
    data += np.ascontiguousarray(log_prob, dtype=log_prob_dtype).tobytes()
    return f"{int(iteration)}:{zlib.crc32(data):08x}"


def _bytes_to_write(chain, start, n, *others) -> int:
    """Most bytes writing steps ``[start, start + n)`` of ``chain`` (and of ``others``, datasets
    of the same steps) can add to the file: every HDF5 chunk they touch is rewritten whole,
    and a compressed chunk is never larger than the raw one by more than a small header."""
    total = 0
    for ds in (chain, *others):
        item = ds.dtype.itemsize
        if ds.chunks is None:  # contiguous: written in place, at most the steps themselves
            total += n * math.prod(ds.shape[1:]) * item
            continue
        per_chunk = math.prod(ds.chunks) * item + 1024
        rows = ds.chunks[0]
        across = math.prod(-(-size // c) for size, c in zip(ds.shape[1:], ds.chunks[1:]))
        touched = (start + n - 1) // rows - start // rows + 1 if n > 0 else 0
        total += touched * across * per_chunk
    return total


def chain_info(path, *, block_steps=2000) -> tuple[int, int, int] | None:
    """``(steps, walkers, dimension)`` of the chain stored in ``path``, checked readable.

    Opens the file read-only and reads every stored step (in blocks of ``block_steps``,
    so memory stays small), the log-probabilities, acceptance counts and the random state
    a resumed run needs, and checks that the steps the count ``iteration`` claims are
    stored: every value finite, no step all zeros (HDF5's fill value: a step counted but
    never written, as a write cut short by a full disk or a crash leaves), and the last
    step the one written with the count (its CRC-32, attribute :data:`LAST_STEP_CHECK`,
    when the file has it). Returns None when there is no file.

    Raises
    ------
    ChainFileError
        The file cannot be opened or read, lacks what emcee's backend writes, holds steps
        that were never written, or is a link (never followed).
    """
    path = os.fspath(path)
    if not os.path.lexists(path):
        return None
    if os.path.islink(path):
        raise ChainFileError(f"{path} is a symbolic link, not a chain written by study (a link is never followed)")
    try:
        with open_hdf5(path, "r") as f:
            if BACKEND_GROUP not in f:
                raise ChainFileError(f"{path} is damaged (no group {BACKEND_GROUP!r}: not a chain written by study)")
            g = f[BACKEND_GROUP]
            n_walkers, n_dim = int(g.attrs["nwalkers"]), int(g.attrs["ndim"])
            steps = int(g.attrs["iteration"])
            chain, log_prob, accepted = g["chain"], g["log_prob"], g["accepted"]
            if (
                chain.shape[1:] != (n_walkers, n_dim)
                or log_prob.shape[1:] != (n_walkers,)
                or accepted.shape != (n_walkers,)
                or not 0 <= steps <= min(chain.shape[0], log_prob.shape[0])
            ):
                raise ChainFileError(
                    f"{path} is damaged (inconsistent shapes: {steps} steps, chain {chain.shape}, "
                    f"log_prob {log_prob.shape}, accepted {accepted.shape})"
                )
            accepted[()]
            for start in range(0, steps, int(block_steps)):
                stop = min(steps, start + int(block_steps))
                block, block_log_prob = chain[start:stop], log_prob[start:stop]
                _check_stored(path, steps, start, block, block_log_prob)
            recorded = str(g.attrs.get(LAST_STEP_CHECK, ""))
            if steps > 0 and recorded.startswith(f"{steps}:"):  # the check written with this count
                found = _step_check(steps, block[-1], block_log_prob[-1], chain.dtype, log_prob.dtype)
                if found != recorded:
                    raise ChainFileError(
                        f"{path} is damaged: its last stored step (step {steps}) is not the one written with its "
                        f"count (checksum {found.partition(':')[2]}, written {recorded.partition(':')[2]}); it cannot "
                        "be resumed"
                    )
            if steps > 0 and LAST_STEP in g:
                _check_last_slot(path, g, steps, block[-1], chain.dtype)
            if steps > 0:
                for i in range(5):
                    g.attrs[f"random_state_{i}"]
    except ChainFileError:
        raise
    except (OSError, KeyError, ValueError, TypeError, RuntimeError) as exc:
        detail = " ".join(str(exc).split())[:200]
        raise ChainFileError(f"{path} is damaged ({type(exc).__name__}: {detail})") from None
    return steps, n_walkers, n_dim


def _check_last_slot(path, g, steps: int, stored_last, chain_dtype) -> None:
    """The full-precision slot of the present count, where the file has one, must round to the
    chain's stored last step."""
    counts = list(np.array(g[LAST_STEP].attrs["iterations"]))
    if steps not in counts:
        return
    coords = g[LAST_STEP][counts.index(steps)][:, :-1]
    if not np.array_equal(coords.astype(chain_dtype), np.asarray(stored_last, dtype=chain_dtype)):
        raise ChainFileError(
            f"{path} is damaged: the full-precision copy of its last step (step {steps}) is not that step; "
            "it cannot be resumed"
        )


def _check_stored(path, steps, start, chain, log_prob) -> None:
    """Steps ``start, start + 1, ...`` of a chain that claims ``steps``: raise :class:`ChainFileError`
    at the first one that holds a non-finite value or was never written (all zeros)."""
    finite = np.isfinite(chain).all(axis=(1, 2)) & np.isfinite(log_prob).all(axis=1)
    blank = ~chain.any(axis=(1, 2)) & ~log_prob.any(axis=1)
    bad = np.flatnonzero(~finite | blank)
    if bad.size:
        k = start + int(bad[0])
        what = "holds non-finite values" if not finite[bad[0]] else "was never written (all zeros)"
        raise ChainFileError(
            f"{path} is damaged: it claims {steps} steps, but step {k} {what} (a write cut short by a full disk "
            "or a crash); it cannot be resumed"
        )

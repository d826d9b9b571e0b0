"""Opening HDF5 files (``chain.h5``, MATLAB v7.3 records) so that reading one never stops
a process writing it.

HDF5 locks a file while it is open (``flock``): a writer takes an exclusive lock, a
reader a shared one, and an open that cannot get its lock fails at once with
``errno = 11`` ("unable to lock file"). A person who looks at ``chain.h5`` while a study
runs (``h5py.File``, emcee's ``HDFBackend``, a notebook polling the chain) therefore made
the study's next write fail. Two rules remove that:

* the package's readers open without taking the lock (:func:`open_hdf5` with mode
  ``"r"``: ``locking=False``), so they never block a writer, nor wait for one;
* the package's writers retry an open refused by another process's lock, with a short
  back-off (5 ms doubling to 0.25 s), for up to :data:`LOCK_WAIT_SECONDS`: a reader
  holds the file for milliseconds, so the write goes through on a later try. Only a
  file held open longer than that (e.g. an ``h5py.File`` left open in a notebook) ends
  the run, with a message saying so; its completed steps are kept and a rerun resumes.

A file opened for writing is never reached through a link: a symbolic link (or a file with
a second hard link) at that path is refused (:func:`identify.data.fileio.refuse_link`), so a
link planted in a results folder cannot make a study write into another file.
"""

from __future__ import annotations

import errno
import os
import time

from .fileio import refuse_link

__all__ = ["LOCK_WAIT_SECONDS", "ChainFileError", "open_hdf5", "is_lock_error"]

#: Longest wait [s] for another process to release an HDF5 file a writer must open.
LOCK_WAIT_SECONDS = 60.0
_FIRST_DELAY, _MAX_DELAY = 0.005, 0.25


class ChainFileError(ValueError):
    """A ``chain.h5`` that cannot be read back (truncated, overwritten, not emcee's format), or
    whose stored steps are not those its step count claims (:func:`identify.fitting.posterior.chain_info`;
    defined here, with no heavy import, for the command line's list of input errors)."""


def is_lock_error(exc: BaseException) -> bool:
    """Whether ``exc`` is HDF5 refusing an open because another process holds the file's lock."""
    if not isinstance(exc, OSError):
        return False
    return exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK) or "unable to lock file" in str(exc)


def open_hdf5(path, mode: str = "r", *, wait: float = LOCK_WAIT_SECONDS, sleep=time.sleep, clock=time.monotonic):
    """``h5py.File(path, mode)`` that neither blocks a writer (reading) nor fails on a reader's lock (writing).

    Parameters
    ----------
    path : str or path-like
        The HDF5 file.
    mode : str, default "r"
        ``"r"``: read without taking the file lock (``locking=False``; where the HDF5
        library cannot, a lock refused by a writer is retried as for writing). Any other
        mode (``"a"``, ``"r+"``, ``"w"``): an open refused by another process's lock is
        retried with a back-off for up to ``wait`` seconds.
    wait : float, default :data:`LOCK_WAIT_SECONDS`
        Longest total wait for the lock [s].
    sleep, clock : callable
        ``time.sleep`` and ``time.monotonic``; replaceable in tests.

    Returns
    -------
    h5py.File

    Raises
    ------
    BlockingIOError
        The file stayed locked by another process for ``wait`` seconds (the message names
        the file and what to do).
    OSError
        Any other failure to open (missing or damaged file), as h5py raises it.
    identify.data.fileio.LinkedFileError
        Writing, and ``path`` is a symbolic link or has another hard link.
    """
    import h5py  # deferred: ~0.6 s to import, and cli.app imports this module for its error type

    path = os.fspath(path)
    if mode != "r":
        refuse_link(path)
    if mode == "r":
        try:
            return h5py.File(path, "r", locking=False)
        except (TypeError, ValueError):  # an HDF5 library without the option: take the lock, retried
            pass
    deadline = clock() + float(wait)
    delay = _FIRST_DELAY
    while True:
        try:
            return h5py.File(path, mode)
        except OSError as exc:
            if not is_lock_error(exc):
                raise
            if clock() + delay > deadline:
                raise BlockingIOError(
                    errno.EAGAIN,
                    f"{path} is held open by another process (HDF5 file lock) for more than {wait:g} s; close it "
                    "(an h5py.File or emcee HDFBackend left open) and rerun the same command: completed work is kept",
                ) from exc
        sleep(delay)
        delay = min(2 * delay, _MAX_DELAY)

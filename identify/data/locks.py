"""One writer per folder: an exclusive lock file in every results folder and batch folder.

A command that writes into a folder (``study --out DIR``, ``fit --out DIR``,
``diagnose --out DIR``, ``report DIR``, ``paper --out DIR``, ``batch`` for its ``out``
folder and each run folder, ``reproduce`` for the original and the new folder) first
takes :class:`FolderLock` on it, before it writes anything there. The lock is the file
``DIR/.identify.lock``:

* created with ``O_CREAT`` and ``O_NOFOLLOW`` (a symbolic link of that name, or a file
  with another hard link, is refused before anything is written: the lock never writes
  through a link into another file), and locked with ``fcntl.flock(LOCK_EX | LOCK_NB)``: the kernel
  holds the lock for the open file, so it is released when the process ends in any way
  (``kill -9`` included) and can never be held by a dead process;
* holding, as JSON, the holder's PID, host, start time and command line, so a second
  writer is refused at once with a message naming the holder
  (:class:`FolderBusyError`);
* removed when the holder releases it, and when taking it fails (e.g. a full disk: the
  file this process created is removed again). A lock file left by a process that died
  (``kill -9``, power loss) is *stale*: the next writer takes it over and
  :attr:`FolderLock.stale_holder` says whose it was.

A batch passes the lock of a run folder on to the command it runs there
(:meth:`FolderLock.child_environment`): the child inherits the locked file descriptor and
recognises it (:data:`INHERIT_VARIABLE`), so the run folder stays locked from the batch's
first write to its last marker, and still while the command runs, even if the batch
itself is killed.

POSIX only (``fcntl``); elsewhere :class:`FolderLock` only writes the lock file and
checks the PID it names.
"""

from __future__ import annotations

import datetime as _dt
import errno
import json
import os
import socket
import sys
import time
from pathlib import Path

from .fileio import DiskFullError, is_disk_full, open_no_follow

try:  # POSIX
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None

__all__ = ["LOCK_NAME", "INHERIT_VARIABLE", "FolderBusyError", "FolderLock", "lock_holder", "pid_alive"]

#: The lock file inside a locked folder.
LOCK_NAME = ".identify.lock"
#: Environment variable naming a lock a child process inherits: ``"<fd>:<lock path>"``.
INHERIT_VARIABLE = "IDENTIFY_INHERITED_LOCK"


class FolderBusyError(RuntimeError):
    """The folder is locked by another live process; the message names it."""


def pid_alive(pid) -> bool:
    """True when a process with this PID exists on this host."""
    try:
        pid = int(pid)
    except (TypeError, ValueError):
        return False
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def _read_info(fd) -> dict:
    try:
        size = os.fstat(fd).st_size
        data = os.pread(fd, max(size, 1), 0)
        info = json.loads(data.decode("utf-8")) if data.strip() else {}
    except (OSError, ValueError, UnicodeDecodeError):
        return {}
    return info if isinstance(info, dict) else {}


def lock_holder(folder) -> dict | None:
    """The lock file's content (``pid``, ``host``, ``started``, ``command``) or None."""
    path = Path(folder) / LOCK_NAME
    try:
        fd = open_no_follow(path, os.O_RDONLY)
    except (OSError, ValueError):
        return None
    try:
        return _read_info(fd) or None
    finally:
        os.close(fd)


def _describe(folder: Path, info: dict) -> str:
    pid = info.get("pid", "?")
    host = info.get("host")
    command = info.get("command")
    started = info.get("started")
    via = info.get("via")
    parts = [f"process {pid}" + (f" on {host}" if host and host != socket.gethostname() else "")]
    if via:
        parts.append(f"(started by process {via})")
    if command:
        parts.append(f"running '{command}'")
    if started:
        parts.append(f"since {started}")
    who = " ".join(parts)
    return (
        f"{folder} is in use by {who}; one process at a time may write into a folder: wait for it to finish "
        f"or stop it (kill {pid}), or use another folder"
    )


class FolderLock:
    """An exclusive lock on a folder (see the module docstring).

    Parameters
    ----------
    folder : path-like
        The folder (created when missing, with its parents).
    command : str, optional
        What holds the lock, for the message a second writer gets; default the
        command line of this process.

    Use as a context manager, or :meth:`acquire` / :meth:`release`.

    Attributes
    ----------
    stale_holder : dict or None
        The content of a stale lock file taken over (its holder had died), else None.
    inherited : bool
        The lock was passed on by the parent process (a batch), which releases it.
    """

    def __init__(self, folder, command: str | None = None):
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self.command = command if command is not None else " ".join(["python -m identify", *sys.argv[1:]])
        self.stale_holder = None
        self.inherited = False
        self.created = False
        self._fd = None

    # -- acquiring --------------------------------------------------------------------------

    def _info(self, **extra) -> bytes:
        info = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "command": self.command,
            **extra,
        }
        return (json.dumps(info) + "\n").encode("utf-8")

    def _write_info(self, fd, **extra) -> None:
        data = self._info(**extra)
        os.ftruncate(fd, 0)
        os.pwrite(fd, data, 0)
        os.fsync(fd)

    def _take_inherited(self) -> bool:
        value = os.environ.get(INHERIT_VARIABLE, "")
        fd_text, _, path_text = value.partition(":")
        if not fd_text.isdigit() or not path_text:
            return False
        try:
            if Path(path_text).resolve() != self.path.resolve():
                return False
            fd = int(fd_text)
            st_fd, st_path = os.fstat(fd), os.stat(self.path)
        except OSError:
            return False
        if (st_fd.st_dev, st_fd.st_ino) != (st_path.st_dev, st_path.st_ino):
            return False
        if fcntl is not None:
            try:  # the shared open file holds the lock already (the parent's): this is a no-op then
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                return False
        holder = _read_info(fd)
        try:
            self._write_info(fd, via=holder.get("pid"))
        except OSError:
            pass
        self.inherited = True
        return True

    def acquire(self) -> FolderLock:
        """Take the lock, or raise :class:`FolderBusyError` at once (never waits)."""
        if self._fd is not None or self.inherited:
            return self
        if not self.folder.is_dir():
            self.folder.mkdir(parents=True, exist_ok=True)
            self.created = True
        if self._take_inherited():
            return self
        try:
            return self._acquire()
        except BaseException:
            if self.created:  # a folder this lock created and left empty goes again
                try:
                    self.folder.rmdir()
                except OSError:
                    pass
            raise

    def _open(self) -> tuple[int, bool]:
        """The lock file's descriptor (never through a link) and whether this call created it."""
        try:
            return open_no_follow(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644), True
        except FileExistsError:
            pass
        try:
            return open_no_follow(self.path, os.O_RDWR), False
        except FileNotFoundError:  # released meanwhile: create it after all
            return open_no_follow(self.path, os.O_RDWR | os.O_CREAT, 0o644), False

    def _acquire(self) -> FolderLock:
        for _attempt in range(100):
            fd, made = self._open()
            locked = False
            try:
                if fcntl is not None:
                    try:
                        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                        locked = True
                    except OSError as exc:
                        if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                            raise
                        info = {}
                        for _ in range(20):  # the holder may be writing its details this instant
                            info = _read_info(fd)
                            if info:
                                break
                            time.sleep(0.01)
                        raise FolderBusyError(_describe(self.folder, info)) from None
                else:  # pragma: no cover - no flock: trust a live PID in the file
                    info = _read_info(fd)
                    if info and info.get("pid") != os.getpid() and pid_alive(info.get("pid")):
                        raise FolderBusyError(_describe(self.folder, info))
                # the file may have been released (unlinked) and replaced meanwhile
                try:
                    st_path = os.lstat(self.path)
                except FileNotFoundError:
                    os.close(fd)
                    continue
                st_fd = os.fstat(fd)
                if (st_fd.st_dev, st_fd.st_ino) != (st_path.st_dev, st_path.st_ino):
                    os.close(fd)
                    continue
                previous = _read_info(fd)
                if previous:
                    self.stale_holder = previous
                self._write_info(fd)
            except BaseException as exc:
                if made and locked:  # a file this call created and locked (e.g. left empty by a full disk) goes
                    self._unlink_if_same(fd)
                try:
                    os.close(fd)
                except OSError:
                    pass
                if is_disk_full(exc) and not isinstance(exc, DiskFullError):
                    raise DiskFullError(self.path) from None
                raise
            self._fd = fd
            return self
        raise FolderBusyError(f"{self.folder}: could not take the lock {self.path} (it kept being replaced)")

    def _unlink_if_same(self, fd) -> None:
        """Remove the lock file when it is still the file open as ``fd``."""
        try:
            st_fd, st_path = os.fstat(fd), os.lstat(self.path)
            if (st_fd.st_dev, st_fd.st_ino) == (st_path.st_dev, st_path.st_ino):
                os.unlink(self.path)
        except OSError:
            pass

    def release(self, *, remove_if_empty: bool = True) -> None:
        """Remove the lock file and unlock (a no-op for an inherited or released lock).

        A folder this lock created is removed again when it is left empty (a command that
        failed before writing anything leaves nothing behind)."""
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:
            self._unlink_if_same(fd)
        finally:
            os.close(fd)
        if remove_if_empty and self.created:
            try:
                self.folder.rmdir()  # only succeeds when empty
            except OSError:
                pass

    @property
    def held(self) -> bool:
        return self._fd is not None or self.inherited

    def stale_note(self) -> str | None:
        """One line about a stale lock taken over, or None."""
        info = self.stale_holder
        if not info:
            return None
        pid = info.get("pid", "?")
        host = info.get("host")
        where = f" on {host}" if host and host != socket.gethostname() else ""
        since = f", started {info['started']}" if info.get("started") else ""
        return f"{self.folder}: took over the lock of process {pid}{where}, which is no longer running{since}"

    def child_environment(self, env: dict | None = None) -> tuple[dict, tuple]:
        """``(env, pass_fds)`` for a subprocess that is to write into the same folder under this lock."""
        env = dict(os.environ if env is None else env)
        if self._fd is None:
            return env, ()
        env[INHERIT_VARIABLE] = f"{self._fd}:{self.path.resolve()}"
        return env, (self._fd,)

    def __enter__(self) -> FolderLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()

    def __del__(self):  # pragma: no cover - a lock not released explicitly
        try:
            self.release()
        except Exception:
            pass

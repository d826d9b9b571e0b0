"""Atomic file writes, the package's one home for them: every file the project writes
appears whole or not at all, never through a link, and a full disk is one error naming the file.

A write goes to a temporary file in the destination's folder (``.<name>.<random>.tmp``),
is flushed and fsync'ed, and is then renamed over the destination (``os.replace``, atomic
on POSIX and Windows); the folder is fsync'ed too, so after a crash or power loss the
destination holds either the old content or the new one, never a mixture. On any
error, including ``KeyboardInterrupt``, the temporary file is removed and the
destination is left as it was.

:func:`atomic_write` takes bytes, text or a function that writes into an open binary
file (e.g. ``np.savez`` or ``figure.savefig``), so large content is streamed to disk
instead of being built in memory first. :func:`write_via_temporary` does the same for
libraries that must open the file by name (netCDF): the name is a fresh ``mkstemp`` name,
never a fixed one, so a link planted in the folder cannot redirect the write.

Links: a temporary file is created with ``O_EXCL`` under an unpredictable name, and the
rename replaces a link at the destination by the file (it never writes through it). A
file that is written in place (``chain.h5``, a lock, a log) is opened with
:func:`open_no_follow` or checked with :func:`refuse_link`: a symbolic link, or a file
with a second hard link, is refused with :class:`LinkedFileError`.

A full disk: every writer turns ``ENOSPC`` into :class:`DiskFullError`, an ``OSError``
whose message names the file and says what to do; writers whose library cannot survive
a full disk (HDF5) first check that the bytes they may need are free
(:func:`require_space`).
"""

from __future__ import annotations

import errno
import os
import shutil
import stat
import tempfile
from pathlib import Path

try:
    import tomllib  # Python >= 3.11
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = [
    "atomic_write",
    "atomic_write_bytes",
    "atomic_write_text",
    "write_via_temporary",
    "temporary_files",
    "toml_module",
    "DiskFullError",
    "LinkedFileError",
    "free_bytes",
    "require_space",
    "refuse_link",
    "open_no_follow",
    "is_disk_full",
    "move_folder_into_place",
]

#: Glob of the temporary files :func:`atomic_write` creates (and removes).
TEMPORARY_GLOB = ".*.tmp"


class DiskFullError(OSError):
    """``ENOSPC`` while writing ``filename``: one line naming the file and what to do.

    Parameters
    ----------
    path : path-like
        The file that could not be written.
    detail : str, optional
        E.g. ``"1.4 MB needed, 0.9 MB free"``.
    """

    def __init__(self, path=None, detail: str = ""):
        super().__init__(errno.ENOSPC, "No space left on device", None if path is None else os.fspath(path))
        self.detail = detail

    def __str__(self) -> str:
        detail = f" ({self.detail})" if self.detail else ""
        if self.filename is None:
            return f"no space left on the device{detail}; free space on that disk and rerun the same command"
        return (
            f"{self.filename}: no space left on the device{detail}; the file was left as it was. Free space on "
            "that disk (or use another folder) and rerun the same command: completed work is kept"
        )


class LinkedFileError(ValueError):
    """A file a command would write in place is a symbolic link or has another hard link: refused."""


def _mb(n: float) -> str:
    return f"{n / 1e6:.2g} MB" if n < 1e7 else f"{n / 1e6:.0f} MB"


def free_bytes(folder) -> int | None:
    """Bytes an unprivileged writer may still use on ``folder``'s file system (None: unknown)."""
    try:
        st = os.statvfs(folder)
    except (OSError, AttributeError):  # pragma: no cover - no statvfs (Windows)
        return None
    return int(st.f_bavail) * int(st.f_frsize)


def require_space(path, need: int) -> None:
    """Raise :class:`DiskFullError` naming ``path`` unless ``need`` bytes are free in its folder.

    For writers that cannot fail cleanly on a full disk (the HDF5 library ends the process
    by a signal when a write of its cache fails): checked before they write, nothing is
    written when the space is short."""
    free = free_bytes(Path(path).parent)
    if free is not None and free < need:
        raise DiskFullError(path, f"up to {_mb(need)} needed, {_mb(free)} free")


def is_disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` is a full disk (``ENOSPC``/``EDQUOT``, also as the HDF5 library words it)."""
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)):
        return True
    text = str(exc)
    return "errno = 28" in text or "No space left on device" in text


def _refusal(path, st) -> str | None:
    if stat.S_ISLNK(st.st_mode):
        return f"{path} is a symbolic link; a file the package writes in place is never followed: remove the link"
    if not stat.S_ISREG(st.st_mode):
        return f"{path} is not a regular file; remove it"
    if st.st_nlink > 1:
        return (
            f"{path} has {st.st_nlink} hard links (it is also another file); a file the package writes in place "
            "must be its own: remove it"
        )
    return None


def refuse_link(path) -> None:
    """Raise :class:`LinkedFileError` when ``path`` is a symbolic link, not a regular file, or
    hard-linked elsewhere; a missing ``path`` is fine."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    reason = _refusal(path, st)
    if reason:
        raise LinkedFileError(reason)


def open_no_follow(path, flags: int, mode: int = 0o666) -> int:
    """``os.open`` that never follows a link: ``O_NOFOLLOW`` (a symbolic link is refused), then
    the open file checked to be a regular file with no other hard link. Returns the descriptor.

    Raises
    ------
    LinkedFileError
        ``path`` is a link (or not a regular file).
    """
    truncate = bool(flags & os.O_TRUNC)  # only once the file is known to be its own
    flags = (flags & ~os.O_TRUNC) | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags, mode)
    except OSError as exc:
        if exc.errno == errno.ELOOP or (exc.errno == errno.EMLINK and os.path.islink(path)):
            raise LinkedFileError(_refusal(path, os.lstat(path)) or f"{path} is a link") from None
        raise
    try:
        reason = _refusal(path, os.fstat(fd))
    except OSError:
        os.close(fd)
        raise
    if reason:
        os.close(fd)
        raise LinkedFileError(reason)
    if truncate:
        os.ftruncate(fd, 0)
    return fd


def _named(exc: BaseException, path) -> BaseException:
    """``exc`` as :class:`DiskFullError` when the disk is full, or with ``path`` as its file name."""
    if isinstance(exc, DiskFullError):
        return exc
    if is_disk_full(exc):
        return DiskFullError(path)
    if isinstance(exc, OSError) and exc.filename is None and exc.errno:
        return OSError(exc.errno, exc.strerror or str(exc), os.fspath(path))
    return exc


def _current_umask() -> int:
    """The process umask (read by setting and restoring it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable (no-op where folders cannot be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write(path, content, *, make_parents: bool = False) -> None:
    """Write ``content`` to ``path`` via a temporary file in the same folder and a rename.

    Parameters
    ----------
    path : path-like
        The destination.
    content : bytes, str or callable
        Bytes, text (written as UTF-8) or ``f(fh)`` writing into an open binary file.
    make_parents : bool, default False
        Create the destination's folder first.

    The file gets the usual mode (``0o666`` less the umask; ``mkstemp`` alone makes it
    ``0o600``). A link at ``path`` is replaced by the file, never written through.

    Raises
    ------
    DiskFullError
        The disk is full (the temporary file is removed, ``path`` left as it was).
    OSError
        Any other failure to write, with ``path`` as its file name.
    """
    path = Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(content, str):
        content = content.encode("utf-8")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.chmod(tmp, 0o666 & ~_current_umask())
        with os.fdopen(fd, "wb") as fh:
            if callable(content):
                content(fh)
            else:
                fh.write(content)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        named = _named(exc, path)
        if named is exc:
            raise
        raise named from None
    _fsync_folder(path.parent)


def write_via_temporary(path, write, *, need_bytes: int = 0) -> None:
    """Write ``path`` with ``write(temporary_path)`` for libraries that open a file by name
    (netCDF): a fresh file in the destination's folder under a ``mkstemp`` name, fsync'ed
    and renamed over ``path``; removed on any error.

    Parameters
    ----------
    path : path-like
        The destination.
    write : callable
        ``write(str)`` writes the whole file at that path (it exists, empty).
    need_bytes : int, default 0
        Bytes the write may take at most: checked free first (:func:`require_space`), so a
        library that cannot survive a full disk never meets one.

    Raises
    ------
    DiskFullError
        Too little space, or the disk filled while writing (temporary file removed).
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        os.chmod(tmp, 0o666 & ~_current_umask())
        if need_bytes:
            require_space(path, int(need_bytes))
        write(tmp)
        fd = open_no_follow(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        named = _named(exc, path)
        if named is exc:
            raise
        raise named from None
    _fsync_folder(path.parent)


def atomic_write_bytes(path, data: bytes) -> None:
    """:func:`atomic_write` of bytes."""
    atomic_write(path, bytes(data))


def atomic_write_text(path, text: str) -> None:
    """:func:`atomic_write` of ``text`` encoded as UTF-8."""
    atomic_write(path, text.encode("utf-8"))


def temporary_files(folder) -> list[Path]:
    """Temporary files of :func:`atomic_write` left in ``folder`` (only a hard kill leaves any)."""
    return sorted(Path(folder).glob(TEMPORARY_GLOB))


def toml_module():
    """The TOML reader: :mod:`tomllib` (Python >= 3.11) or its backport ``tomli`` (3.10)."""
    return tomllib


def move_folder_into_place(staging, out) -> None:
    """Give the finished folder ``staging`` the usual mode and rename it to ``out``.

    ``staging`` is a folder beside ``out`` made by :func:`tempfile.mkdtemp` (mode ``0o700``);
    it gets ``0o777`` less the umask, as a folder made as usual. An existing ``out`` is renamed
    aside first and removed only after the new folder is in place, so a failure leaves one of the
    two whole.
    """
    staging, out = Path(staging), Path(out)
    staging.chmod(0o777 & ~_current_umask())
    old = None
    if out.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
        old.rmdir()
        out.rename(old)
    staging.rename(out)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)

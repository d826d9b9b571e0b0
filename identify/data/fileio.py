"""Atomic file writes, the package's one home for them: every file the project writes
appears whole or not at all.

A write goes to a temporary file in the destination's folder (``.<name>.<random>.tmp``),
is flushed and fsync'ed, and is then renamed over the destination (``os.replace``, atomic
on POSIX and Windows); the folder is fsync'ed too, so after a crash or power loss the
destination holds either the old content or the new one, never a mixture. On any
error, including ``KeyboardInterrupt``, the temporary file is removed and the
destination is left as it was.

:func:`atomic_write` takes bytes, text or a function that writes into an open binary
file (e.g. ``np.savez`` or ``figure.savefig``), so large content is streamed to disk
instead of being built in memory first.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text", "temporary_files", "toml_module"]

#: Glob of the temporary files :func:`atomic_write` creates (and removes).
TEMPORARY_GLOB = ".*.tmp"


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
    ``0o600``).
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
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
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
    try:
        import tomllib  # Python >= 3.11
    except ModuleNotFoundError:  # pragma: no cover - Python 3.10
        import tomli as tomllib
    return tomllib

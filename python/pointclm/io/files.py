"""Opening a file with the errors every reader shares, and writing one without leaving a
partial file behind.

Readers work on the file's bytes, so the checks that name the path (missing, a directory,
not a regular file, empty) live here once, before any format code runs. Only regular files
are read: a FIFO would block the reader forever and a device such as ``/dev/zero`` never
ends, so both are refused from ``os.stat`` before the file is opened. Reading the whole file
bounds every later allocation by its length, which is what the format readers check their
declared sizes against.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

from ..errors import PathNotFoundError

__all__ = ["as_path", "atomic_path", "check_output_path", "read_checked", "regular_file"]


def as_path(path: object, name: str = "path") -> Path:
    """``path`` as a :class:`~pathlib.Path`, or a ValueError naming the argument."""
    if not isinstance(path, str | os.PathLike):
        raise ValueError(f"{name} must be a str or os.PathLike, got {type(path).__name__}")
    fs = os.fspath(path)
    if not isinstance(fs, str):
        raise ValueError(f"{name} must be a text path, got {type(fs).__name__}")
    if fs == "" or "\x00" in fs:
        raise ValueError(f"{name} {fs!r} is not a valid path")
    return Path(fs)


def regular_file(path: str | os.PathLike[str], what: str = "file") -> Path:
    """The path of an existing regular file, checked without opening it.

    Raises
    ------
    PathNotFoundError
        If nothing exists at ``path`` (a FileNotFoundError and a ValueError; the message and
        ``filename`` carry the path).
    IsADirectoryError
        If ``path`` is a directory.
    ValueError
        If ``path`` is something else that is not a regular file (a FIFO, a socket, a device).
    """
    file = as_path(path)
    try:
        mode = os.stat(file).st_mode
    except FileNotFoundError:
        raise PathNotFoundError(errno.ENOENT, f"no such {what}", str(file)) from None
    except NotADirectoryError:  # a path through a regular file: "a.txt/b.ply"
        raise PathNotFoundError(errno.ENOENT, f"no such {what}", str(file)) from None
    if stat.S_ISDIR(mode):
        raise IsADirectoryError(errno.EISDIR, "expected a file, got a directory", str(file))
    if not stat.S_ISREG(mode):
        kind = (
            "a FIFO (named pipe)"
            if stat.S_ISFIFO(mode)
            else "a device"
            if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "a socket"
            if stat.S_ISSOCK(mode)
            else "not a regular file"
        )
        raise ValueError(f"{file}: {kind}, not a regular file; only regular files are read")
    return file


def read_checked(
    path: str | os.PathLike[str], what: str = "point cloud file"
) -> tuple[Path, bytes]:
    """Return the path and the whole file's bytes (a regular file only).

    Raises
    ------
    PathNotFoundError
        If nothing exists at ``path`` (a FileNotFoundError and a ValueError; the message and
        ``filename`` carry the path).
    IsADirectoryError
        If ``path`` is a directory.
    ValueError
        If the file is empty, or not a regular file (FIFO, device, socket).
    """
    file = regular_file(path, what)
    # O_NONBLOCK: if the path was swapped for a FIFO after the stat, open() must not block.
    fd = os.open(file, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
            raise ValueError(f"{file}: not a regular file; only regular files are read")
        raw = fh.read()
    if not raw:
        raise ValueError(f"{file}: the file is empty (0 bytes)")
    return file, raw


def check_output_path(path: str | os.PathLike[str], what: str = "output") -> Path:
    """Check, before any work, that a file can be written at ``path``: its folder exists and
    is writable, and the path is not a directory (an existing file is overwritten).

    Raises
    ------
    ValueError
        Naming ``what`` and the path, with the reason.
    """
    file = as_path(path, what)
    if file.name in ("", ".", ".."):
        raise ValueError(f"{what} {str(path)!r} is not a file name")
    parent = file.parent
    if file.is_dir():
        raise ValueError(f"{what} {file} is a directory; give a file name")
    if not parent.is_dir():
        raise ValueError(f"{what} {file}: the folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{what} {file}: the folder {parent} is not writable{_why_not(parent)}")
    if file.exists() and not os.access(file, os.W_OK):
        raise ValueError(f"{what} {file} exists and is not writable")
    return file


def _why_not(folder: Path) -> str:
    """ " (a read-only filesystem)" where that is why `folder` cannot be written to."""
    try:
        read_only = bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except (OSError, AttributeError):  # no statvfs (Windows): the plain message
        return ""
    return " (a read-only filesystem)" if read_only else ""


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix, so writers that pick a format by
    extension still do); on success it replaces ``path`` in one step, on an error it is
    removed. Readers of ``path`` therefore see the old file or the whole new one, never a
    partial one.
    """
    file = Path(os.fspath(path))
    fd, tmp = tempfile.mkstemp(
        prefix=f".{file.name}.", suffix=f".tmp{file.suffix}", dir=file.parent
    )
    os.close(fd)
    # mkstemp makes the file private (0600); give it the mode a plain open() would have.
    with contextlib.suppress(OSError):
        os.chmod(tmp, 0o666 & ~_umask())
    try:
        yield Path(tmp)
        os.replace(tmp, file)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _umask() -> int:
    """The process umask, read without changing it (os.umask would race with threads)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    return 0o022

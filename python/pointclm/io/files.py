"""Opening a file with the errors every reader shares.

Readers work on the file's bytes, so the checks that name the path (missing, a directory,
empty) live here once, before any format code runs.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

__all__ = ["read_checked"]


def read_checked(path: str | os.PathLike[str]) -> tuple[Path, bytes]:
    """Return the path and the whole file's bytes.

    Raises
    ------
    FileNotFoundError
        If nothing exists at ``path`` (the message and ``filename`` carry the path).
    IsADirectoryError
        If ``path`` is a directory.
    ValueError
        If the file is empty.
    """
    file = Path(os.fspath(path))
    if not file.exists():
        raise FileNotFoundError(errno.ENOENT, "no such point cloud file", str(file))
    if file.is_dir():
        raise IsADirectoryError(errno.EISDIR, "expected a file, got a directory", str(file))
    raw = file.read_bytes()
    if not raw:
        raise ValueError(f"{file}: the file is empty (0 bytes)")
    return file, raw

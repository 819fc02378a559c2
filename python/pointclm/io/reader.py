"""Choosing a reader by file extension, and the errors users see.

Format readers raise :class:`ValueError` with what is wrong; this layer prefixes the path
so a message from a batch job says which of thousands of files is bad, and turns the few
low-level exceptions a malformed file can provoke into the same :class:`ValueError`.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .arrays import parse_npy, parse_npz
from .files import as_path, read_checked
from .mesh import check_n_samples
from .off import parse_off
from .pcd import parse_pcd
from .ply import parse_ply
from .pointcloud import PointCloud
from .text import parse_text

__all__ = ["SUPPORTED_SUFFIXES", "load_points", "read_point_cloud"]

#: Readers of formats that may hold a mesh (sampled with ``n_samples`` and ``seed``).
_MESH_READERS: dict[str, Callable[[bytes, int | None, int | None], PointCloud]] = {
    ".ply": parse_ply,
    ".off": parse_off,
}
#: Readers of point-only formats.
_CLOUD_READERS: dict[str, Callable[[bytes], PointCloud]] = {
    ".pcd": parse_pcd,
    ".xyz": parse_text,
    ".txt": parse_text,
    ".pts": parse_text,
    ".npy": parse_npy,
    ".npz": parse_npz,
}

#: File extensions :func:`read_point_cloud` reads (matched case-insensitively).
SUPPORTED_SUFFIXES: tuple[str, ...] = (*_MESH_READERS, *_CLOUD_READERS)


def read_point_cloud(
    path: str | os.PathLike[str], *, n_samples: int | None = None, seed: int | None = 0
) -> PointCloud:
    """Read a point cloud or mesh file into a :class:`PointCloud` of finite points.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.ply``, ``.pcd``, ``.off``, ``.xyz``/``.txt``/``.pts``, ``.npy`` or ``.npz``
        file (the extension picks the reader).
    n_samples : int, optional
        Points to draw from a mesh's surface (PLY or OFF with faces); default
        ``max(10_000, number of vertices)``. Point clouds return all their finite points
        and ignore it.
    seed : int or None
        Seed for mesh sampling: the same seed gives the same points (``None``: fresh
        entropy).

    Returns
    -------
    PointCloud
        Points (N, 3) float64, plus normals and colours when the file has them. Points
        with NaN/inf coordinates (missing pixels of organised clouds) are dropped.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If the file is empty, truncated or malformed, not a regular file (a FIFO, a
        device), its extension is not supported, or it has no finite point; the message
        starts with the path. Sizes a file declares are checked against its length before
        anything is allocated, and integer fields that their type cannot hold are errors
        naming the line.
    """
    if n_samples is not None:
        check_n_samples(n_samples)
    if seed is not None and (
        isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0
    ):
        raise ValueError(f"seed must be a non-negative int or None, got {seed!r}")
    file, raw = _open(path)
    suffix = file.suffix.lower()
    try:
        if suffix in _MESH_READERS:
            return _MESH_READERS[suffix](raw, n_samples, seed)
        return _CLOUD_READERS[suffix](raw)
    except (ValueError, struct.error, EOFError) as exc:
        raise ValueError(f"{file}: {exc}") from exc


def load_points(
    path: str | os.PathLike[str], *, n_samples: int | None = None, seed: int | None = 0
) -> np.ndarray:
    """Just the (N, 3) float64 points of :func:`read_point_cloud` (same arguments)."""
    return read_point_cloud(path, n_samples=n_samples, seed=seed).points


def _open(path: str | os.PathLike[str]) -> tuple[Path, bytes]:
    file = as_path(path)
    if file.suffix.lower() not in SUPPORTED_SUFFIXES:
        # Checked before reading, so a wrong extension fails fast even on a huge file.
        if not file.exists():
            read_checked(file)  # raises FileNotFoundError with the path
        raise ValueError(
            f"{file}: unsupported file extension {file.suffix!r}; supported: "
            + ", ".join(SUPPORTED_SUFFIXES)
        )
    return read_checked(file)

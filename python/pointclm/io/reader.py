"""Choosing a reader by file extension, and the errors users see.

Format readers raise :class:`ValueError` with what is wrong; this layer prefixes the path
so a message from a batch job says which of thousands of files is bad, and turns the few
low-level exceptions a malformed file can provoke into the same :class:`ValueError`.
"""

from __future__ import annotations

import os
import struct
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import PathNotFoundError
from ..interop.open3d import from_open3d, is_open3d_geometry
from .arrays import parse_npy, parse_npz, read_npy, read_npz_members
from .files import as_path, read_checked
from .mesh import Mesh, check_n_samples
from .off import off_mesh, parse_off
from .pcd import parse_pcd
from .ply import parse_ply, ply_mesh
from .pointcloud import NonFinitePointsWarning, PointCloud
from .scanner import SCANNER_SUFFIXES, read_scanner_file
from .text import parse_text

__all__ = ["MESH_SUFFIXES", "SUPPORTED_SUFFIXES", "load_points", "read_mesh", "read_point_cloud"]

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
SUPPORTED_SUFFIXES: tuple[str, ...] = (*_MESH_READERS, *_CLOUD_READERS, *SCANNER_SUFFIXES)

#: File extensions :func:`read_mesh` reads: PLY, OFF and numpy arrays here, OBJ and STL with
#: trimesh (an optional dependency, imported only for them).
MESH_SUFFIXES: tuple[str, ...] = (".ply", ".off", ".obj", ".stl", ".npy", ".npz")
_TRIMESH_SUFFIXES = (".obj", ".stl")


def read_point_cloud(
    path: str | os.PathLike[str] | Any, *, n_samples: int | None = None, seed: int | None = 0
) -> PointCloud:
    """Read a point cloud or mesh file into a :class:`PointCloud` of finite points.

    Parameters
    ----------
    path : str or os.PathLike, or an Open3D geometry
        A ``.ply``, ``.pcd``, ``.off``, ``.xyz``/``.txt``/``.pts``, ``.npy`` or ``.npz``
        file (the extension picks the reader); ``.las``/``.laz`` and ``.e57`` scanner files
        with the ``[io]`` extra (:mod:`pointclm.io.scanner`); or an Open3D ``PointCloud`` or
        ``TriangleMesh`` (legacy or tensor), read as a file of that format would be
        (:func:`pointclm.io.from_open3d`).
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
        with NaN/inf coordinates (a scanner's missing returns, the missing pixels of
        organised clouds) are dropped, with a :class:`NonFinitePointsWarning` naming the
        file and the count (also in ``PointCloud.dropped``); so are a mesh's vertices with
        NaN/inf coordinates (the triangles touching them get no samples).

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
    if is_open3d_geometry(path):
        return from_open3d(path, n_samples=n_samples, seed=seed)
    if as_path(path).suffix.lower() in SCANNER_SUFFIXES:
        # Read by their libraries from the path, not from bytes: their errors name the file.
        file, cloud = read_scanner_file(path)
    else:
        file, cloud = _read_bytes(path, n_samples, seed)
    if cloud.dropped:
        _warn_dropped(file, cloud)
    return cloud


def _read_bytes(
    path: str | os.PathLike[str], n_samples: int | None, seed: int | None
) -> tuple[Path, PointCloud]:
    file, raw = _open(path)
    suffix = file.suffix.lower()
    try:
        if suffix in _MESH_READERS:
            cloud = _MESH_READERS[suffix](raw, n_samples, seed)
        else:
            cloud = _CLOUD_READERS[suffix](raw)
    except (ValueError, struct.error, EOFError) as exc:
        raise ValueError(f"{file}: {exc}") from exc
    return file, cloud


def _warn_dropped(file: Path, cloud: PointCloud) -> None:
    """The :class:`NonFinitePointsWarning` of a file whose NaN/inf rows were dropped, shown
    at the line that called :func:`read_point_cloud` (or :func:`load_points`)."""
    n = cloud.dropped
    warnings.warn(
        f"{file}: dropped {n} {'row' if n == 1 else 'rows'} with NaN/inf coordinates "
        f"(missing returns), kept {len(cloud)} points",
        NonFinitePointsWarning,
        stacklevel=3,
    )


def load_points(
    path: str | os.PathLike[str] | Any, *, n_samples: int | None = None, seed: int | None = 0
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


def read_mesh(path: str | os.PathLike[str]) -> Mesh:
    """Read a mesh or point file's vertices and triangles, unsampled.

    ``.ply`` and ``.off`` are read here (polygons fan-triangulated); ``.npy`` holds an
    (N, 3) cloud and ``.npz`` ``vertices`` and optionally ``faces`` (the packaged format);
    ``.obj`` and ``.stl`` are read with trimesh (imported only for them,
    ``pip install pointclm[io]``), a scene being merged into one mesh.

    Returns
    -------
    Mesh
        Vertices (V, 3) float64, all finite; triangles (T, 3) int64 naming vertices, or
        None for a point-only file (or one whose face list is empty).

    Raises
    ------
    PathNotFoundError
        If the file is missing (a FileNotFoundError and a ValueError).
    ValueError
        If the file is of an unknown type, unreadable or empty, its vertices are not (N, 3)
        or not finite, or a face names no vertex; the message starts with the path.
    ImportError
        If trimesh is needed and not installed.
    """
    file = as_path(path)
    suffix = file.suffix.lower()
    if not file.is_file():
        raise PathNotFoundError(f"{file}: no such file")
    if suffix not in MESH_SUFFIXES:
        raise ValueError(
            f"{file}: unsupported file type {suffix!r} (use {', '.join(MESH_SUFFIXES)})"
        )
    try:
        vertices, faces = _mesh_arrays(file, suffix)
    except ImportError:
        raise
    except Exception as err:  # noqa: BLE001 - any parser failure becomes a ValueError
        raise ValueError(f"{file}: cannot read it ({type(err).__name__}: {err})") from err
    return _checked_mesh(file, vertices, faces)


def _mesh_arrays(file: Path, suffix: str) -> tuple[np.ndarray, np.ndarray | None]:
    """The file's vertices and faces, by the reader its suffix names."""
    if suffix in _TRIMESH_SUFFIXES:
        return _trimesh_arrays(file)
    _, raw = read_checked(file, "mesh file")
    if suffix in (".ply", ".off"):
        mesh = ply_mesh(raw) if suffix == ".ply" else off_mesh(raw)
        return mesh.vertices, mesh.triangles
    # pointclm's own .npy/.npz readers: no pickle, declared sizes checked before anything is
    # allocated, only the members needed decompressed.
    if suffix == ".npy":
        return read_npy(raw), None
    arrays, names = read_npz_members(raw, ("vertices", "faces"))
    if "vertices" not in arrays:
        raise ValueError(f"no 'vertices' array (arrays: {', '.join(names) or 'none'})")
    return arrays["vertices"], arrays.get("faces")


def _checked_mesh(file: Path, vertices: np.ndarray, faces: np.ndarray | None) -> Mesh:
    verts = np.asarray(vertices, dtype=np.float64)
    if verts.ndim != 2 or verts.shape[1] != 3 or len(verts) == 0:
        raise ValueError(f"{file}: no 3D points in the file (vertex array shape {verts.shape})")
    if not np.all(np.isfinite(verts)):
        raise ValueError(f"{file}: vertices contain NaN or infinity")
    if faces is not None:
        faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        if len(faces) == 0:
            faces = None
        elif faces.min() < 0 or faces.max() >= len(verts):
            raise ValueError(f"{file}: face indices out of range")
    return Mesh(verts, faces)


def _trimesh_arrays(file: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """The optional fallback for the formats this package does not parse (OBJ, STL)."""
    try:
        import trimesh
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError(
            f"reading {file.suffix} files needs trimesh: pip install pointclm[io]  "
            "(or pip install trimesh)"
        ) from err
    loaded = trimesh.load(str(file), process=False)
    # A scene (e.g. an OBJ with several objects) is flattened with its transforms applied.
    geoms = loaded.dump() if isinstance(loaded, trimesh.Scene) else [loaded]
    verts, faces, offset = [], [], 0
    for g in geoms:
        v = np.asarray(getattr(g, "vertices", np.empty((0, 3))), dtype=np.float64)
        f = getattr(g, "faces", None)
        if f is not None and len(f):
            faces.append(np.asarray(f, dtype=np.int64) + offset)
        verts.append(v.reshape(-1, 3))
        offset += len(v)
    if not verts:
        return np.empty((0, 3)), None
    return np.vstack(verts), (np.vstack(faces) if faces else None)

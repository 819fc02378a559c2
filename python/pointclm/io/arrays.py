"""NumPy array files: ``.npy`` and ``.npz`` holding (N, 3) points or (N, 6) points+normals.

Pickled object arrays are refused (``allow_pickle=False``): loading a pickle runs code from
the file, which a point cloud reader must never do.
"""

from __future__ import annotations

import io

import numpy as np

from .pointcloud import PointCloud, finite_cloud, unit_colors

__all__ = ["parse_npy", "parse_npz"]


def _numeric(arr: np.ndarray, what: str) -> np.ndarray:
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"{what} has dtype {arr.dtype}, expected a numeric array")
    return arr


def _split(arr: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray | None]:
    """(N, 3) -> points; (N, 6) -> points and normals."""
    arr = _numeric(arr, what)
    if arr.ndim != 2 or arr.shape[1] not in (3, 6):
        raise ValueError(
            f"{what} has shape {arr.shape}; expected (N, 3) points or (N, 6) points+normals"
        )
    return arr[:, :3], (arr[:, 3:6] if arr.shape[1] == 6 else None)


def parse_npy(raw: bytes) -> PointCloud:
    """Read a ``.npy`` file's bytes.

    Raises
    ------
    ValueError
        Not a ``.npy`` file, a pickled array, or a shape other than (N, 3) / (N, 6).
    """
    try:
        arr = np.load(io.BytesIO(raw), allow_pickle=False)
    except Exception as exc:  # a corrupt header can raise from numpy's header parser
        raise ValueError(f"not a readable .npy array ({type(exc).__name__}: {exc})") from None
    if not isinstance(arr, np.ndarray):
        arr.close()
        raise ValueError("not a .npy array (an .npz archive with a .npy name?)")
    points, normals = _split(arr, "the array")
    return finite_cloud(points, normals)


def parse_npz(raw: bytes) -> PointCloud:
    """Read a ``.npz`` archive: key ``points`` (or its only array), optional ``normals``
    and ``colors`` (floats in [0, 1] or 8-bit integers).

    Raises
    ------
    ValueError
        Not an archive, no ``points`` key among several arrays, or mismatched shapes.
    """
    try:
        loaded = np.load(io.BytesIO(raw), allow_pickle=False)
        if isinstance(loaded, np.ndarray):
            arrays = {"points": loaded}  # a bare .npy saved under an .npz name
        else:
            with loaded as archive:
                arrays = {key: archive[key] for key in archive.files}
    except Exception as exc:  # zipfile, zlib and numpy's header parser each raise their own
        raise ValueError(f"not a readable .npz archive ({type(exc).__name__}: {exc})") from None
    if "points" in arrays:
        key = "points"
    elif len(arrays) == 1:
        key = next(iter(arrays))
    else:
        raise ValueError(
            f"archive has no 'points' array and {len(arrays)} arrays "
            f"({', '.join(sorted(arrays)) or 'none'}); expected 'points' or a single array"
        )
    points, normals = _split(arrays[key], f"array {key!r}")
    for name in ("normals", "colors"):
        extra = arrays.get(name)
        if extra is None or key == name:
            continue
        extra = _numeric(extra, f"array {name!r}")
        if extra.shape != points.shape:
            raise ValueError(
                f"array {name!r} has shape {extra.shape}, the points have {points.shape}"
            )
    colors = arrays.get("colors")
    if "normals" in arrays and key != "normals":
        normals = arrays["normals"]
    return finite_cloud(points, normals, None if colors is None else unit_colors(colors))

"""The :class:`PointCloud` every reader returns.

One small, validated container means callers never have to ask which reader produced a
cloud: the points are always a C-contiguous (N, 3) float64 array with only finite values
(so they go straight into :func:`pointclm.register` or a KD-tree), and the optional per-point
attributes are always aligned with them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["NonFinitePointsWarning", "PointCloud", "check_integers", "finite_cloud", "unit_colors"]


class NonFinitePointsWarning(UserWarning):
    """A file held points (or mesh vertices) with NaN/inf coordinates, which were dropped.

    Scanners and depth cameras write NaN for a missing return, so such a file is read, not
    refused; the warning gives the file and the count, and the cloud's
    :attr:`PointCloud.dropped` keeps it. Turn it into an error with
    ``warnings.simplefilter("error", NonFinitePointsWarning)``, or silence it with
    ``"ignore"``. Arrays passed to pointclm directly are never cleaned: a NaN in them raises
    :class:`~pointclm.errors.InputError`.
    """


@dataclass(frozen=True, eq=False)
class PointCloud:
    """Points with optional per-point normals and colours.

    Attributes
    ----------
    points : numpy.ndarray
        (N, 3) float64, C-contiguous, all finite, N >= 1.
    normals : numpy.ndarray or None
        (N, 3) float64 as stored in the file (not renormalised). For a sampled mesh, the unit
        normal of the triangle each point lies on (orientation from the winding order). A
        zero row marks a point whose normal the file gives as NaN/inf.
    colors : numpy.ndarray or None
        (N, 3) float64 RGB in [0, 1] (8-bit channels are divided by 255).
    dropped : int
        How many rows of the file had NaN/inf coordinates and were left out: points of a
        point cloud, or vertices of a mesh (the triangles touching them get no samples).
        0 for a cloud built from arrays.

    Raises
    ------
    ValueError
        If the shapes disagree, the cloud is empty, or a value is not finite (points),
        not finite (normals), or outside [0, 1] (colours).

    Notes
    -----
    ``eq=False``: element-wise array comparison has no single truth value, so two clouds
    compare by identity; compare the arrays with :func:`numpy.array_equal` instead.
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    dropped: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.dropped, bool) or not isinstance(self.dropped, int | np.integer):
            raise ValueError(f"dropped must be a non-negative int, got {self.dropped!r}")
        if self.dropped < 0:
            raise ValueError(f"dropped must be a non-negative int, got {self.dropped!r}")
        object.__setattr__(self, "dropped", int(self.dropped))
        pts = _real_array(self.points, "points")
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points must be (N, 3), got shape {pts.shape}")
        if len(pts) == 0:
            raise ValueError("a point cloud needs at least one point")
        if not np.isfinite(pts).all():
            raise ValueError("points must be finite (drop NaN/inf rows first)")
        object.__setattr__(self, "points", pts)
        for name in ("normals", "colors"):
            value = getattr(self, name)
            if value is None:
                continue
            arr = _real_array(value, name)
            if arr.shape != pts.shape:
                raise ValueError(f"{name} must have the points' shape {pts.shape}, got {arr.shape}")
            if not np.isfinite(arr).all():
                raise ValueError(f"{name} must be finite")
            if name == "colors" and len(arr) and (arr.min() < 0.0 or arr.max() > 1.0):
                raise ValueError("colors must lie in [0, 1]")
            object.__setattr__(self, name, arr)

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def __repr__(self) -> str:
        extras = [name for name in ("normals", "colors") if getattr(self, name) is not None]
        with_ = f" with {' and '.join(extras)}" if extras else ""
        return f"PointCloud({len(self)} points{with_})"


def _real_array(value: object, name: str) -> np.ndarray:
    """A C-contiguous float64 array of real numbers, or a ValueError naming ``name``."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as e:  # ragged nested lists and the like
        raise ValueError(f"{name} could not be read as an array: {e}") from None
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"{name} must hold real numbers, got dtype {arr.dtype}")
    return np.ascontiguousarray(arr, dtype=np.float64)


def finite_cloud(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    colors: np.ndarray | None = None,
) -> PointCloud:
    """Build a cloud from raw file columns, dropping rows whose xyz is not finite.

    Files legitimately hold NaN points (organised depth-camera clouds mark missing pixels
    that way), so readers drop them here, once, keeping the attributes aligned, and count
    them in :attr:`PointCloud.dropped` (:func:`pointclm.io.read_point_cloud` warns with the
    count). Normals that are non-finite on a kept point become zero rows rather than failing
    the whole file.

    Raises
    ------
    ValueError
        If no point has finite coordinates (message without the path; the caller adds it).
    """
    pts = np.asarray(points, dtype=np.float64)
    keep = np.isfinite(pts).all(axis=1)
    if not keep.any():
        total = len(pts)
        raise ValueError(
            "no points with finite coordinates"
            + (f" (all {total} points are NaN/inf)" if total else " (the cloud is empty)")
        )
    all_kept = bool(keep.all())
    pts = pts if all_kept else pts[keep]
    if normals is not None:
        nrm = np.asarray(normals, dtype=np.float64)
        nrm = nrm if all_kept else nrm[keep]
        bad = ~np.isfinite(nrm).all(axis=1)
        if bad.any():
            nrm = nrm.copy()
            nrm[bad] = 0.0
        normals = nrm
    if colors is not None:
        col = np.asarray(colors, dtype=np.float64)
        colors = col if all_kept else col[keep]
    return PointCloud(points=pts, normals=normals, colors=colors, dropped=int((~keep).sum()))


def unit_colors(channels: np.ndarray) -> np.ndarray:
    """Map colour channels of any stored type to float64 in [0, 1].

    Integer channels are scaled by their type's maximum (255 for uchar, 65535 for ushort),
    which is what every viewer does; float channels are taken as already in [0, 1] and
    clipped, with NaN read as 0, so one odd value cannot make the whole file unreadable.
    """
    arr = np.asarray(channels)
    if np.issubdtype(arr.dtype, np.integer):
        top = float(np.iinfo(arr.dtype).max)
        return np.clip(arr.astype(np.float64) / top, 0.0, 1.0)
    out = np.nan_to_num(arr.astype(np.float64), nan=0.0, posinf=1.0, neginf=0.0)
    return np.clip(out, 0.0, 1.0)


def check_integers(values: np.ndarray, dtype: np.dtype | str) -> tuple[int, str, str] | None:
    """Find the first value of an ASCII integer field that its declared type cannot hold.

    Text readers parse numbers as float64 (exact for integers up to 2**53, beyond every
    32-bit type PLY and PCD declare). A value that is NaN/inf, not a whole number, or outside
    the type's range would otherwise be silently wrapped or truncated by ``astype``.

    Returns
    -------
    tuple or None
        ``(row, value, reason)`` of the first bad value (row index along the first axis), or
        None when every value fits.
    """
    arr = np.asarray(values, dtype=np.float64)
    info = np.iinfo(np.dtype(dtype))
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(arr) | (arr != np.floor(arr)) | (arr < info.min) | (arr > info.max)
    if not bad.any():
        return None
    index = np.unravel_index(int(np.argmax(bad.reshape(-1))), arr.shape)
    value = float(arr[index])
    if not np.isfinite(value):
        shown, why = str(value), "not a finite number, which an integer field cannot hold"
    elif value != np.floor(value):
        shown, why = f"{value:.17g}", "not a whole number, which an integer field cannot hold"
    else:
        kind = np.dtype(dtype).name
        shown, why = f"{value:.0f}", f"outside the range of {kind} [{info.min}, {info.max}]"
    return (int(index[0]) if arr.ndim else 0), shown, why

"""The scan as a sensor delivers it, and the sensor position it states itself: a file that
records its ``VIEWPOINT``, or an organised frame (an (H, W, 3) array or an organised PCD
file), whose points are in its sensor's coordinates, so that its sensor is the origin."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import preprocessing as pp
from ..errors import InputError

__all__ = ["Scan", "file_viewpoint", "frame_points", "load_cloud", "read_scan"]

#: How the result and the warnings name a viewpoint the scan stated.
BY_FILE = "the scan file's VIEWPOINT"
BY_FRAME = "the organised frame's sensor"


@dataclass(frozen=True)
class Scan:
    """A scan's points (N, 3), the viewpoint it is judged from, and who stated it when the
    caller did not (:data:`BY_FILE`, :data:`BY_FRAME`; "" for the caller's or none)."""

    points: np.ndarray
    viewpoint: tuple[float, float, float] | None
    stated_by: str = ""


def load_cloud(cloud: Any, name: str) -> np.ndarray:
    """(N, 3) float64 points of an array, an Open3D cloud or mesh, or a file
    (:func:`pointclm.io.load_points`)."""
    if isinstance(cloud, str | os.PathLike):
        from ..io import load_points

        return load_points(cloud)
    return pp.as_points(cloud, name)


def file_viewpoint(path: str | os.PathLike[str]) -> np.ndarray | None:
    """The sensor position a scan file records, or None: a PCD file's ``VIEWPOINT``
    translation (:func:`pointclm.io.pcd.read_pcd_viewpoint`; PCL's default, the origin with
    no rotation, counts only for an organised cloud, a depth frame in its sensor's
    coordinates, since PCL writes it for every cloud whatever its sensor). Other formats
    record none."""
    if not str(path).lower().endswith(".pcd"):
        return None
    from ..io.pcd import read_pcd_viewpoint

    return read_pcd_viewpoint(path)


def is_frame(scan: Any) -> bool:
    """Whether `scan` is an organised frame: a numpy array (H, W, 3)."""
    return isinstance(scan, np.ndarray) and scan.ndim == 3 and scan.shape[-1] == 3


def frame_points(frame: np.ndarray, name: str = "target") -> np.ndarray:
    """The returns of an organised frame (H, W, 3), row by row: the pixels without a return
    dropped, whether marked by NaN or infinity (Open3D, ROS, PCL) or by the sensor's own
    position, the origin (cameras that write zeros), since no sensor returns a point where it
    stands. The frame itself is not modified."""
    flat = np.asarray(frame, dtype=np.float64).reshape(-1, 3)
    kept = flat[np.isfinite(flat).all(axis=1) & flat.any(axis=1)]
    if len(kept) == 0:
        raise InputError(
            f"{name}: the organised frame {frame.shape} holds no return (every pixel NaN, "
            "infinite or zero)"
        )
    return pp.as_points(np.ascontiguousarray(kept), name)


def read_scan(target: Any, viewpoint: tuple[float, float, float] | None) -> Scan:
    """`target`'s points and the viewpoint to judge them from: the caller's `viewpoint`,
    else the one the scan states (:func:`file_viewpoint`, or the origin for an organised
    frame), else None."""
    if is_frame(target):
        points = frame_points(target)
        if viewpoint is None:
            return Scan(points, (0.0, 0.0, 0.0), BY_FRAME)
        return Scan(points, viewpoint)
    points = load_cloud(target, "target")
    if viewpoint is not None or not isinstance(target, str | os.PathLike):
        return Scan(points, viewpoint)
    found = file_viewpoint(target)
    if found is None:
        return Scan(points, None)
    by = BY_FRAME if not np.any(found) and _organised_file(target) else BY_FILE
    return Scan(points, pp.as_point(found, "viewpoint"), by)


def _organised_file(path: str | os.PathLike[str]) -> bool:
    from ..io.pcd import pcd_is_organised

    return pcd_is_organised(path)

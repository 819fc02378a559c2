"""Open3D's binary feature files (``*.fpfh.bin`` in Open3D's test data and 3DMatch demos).

Layout, as ``open3d.pipelines.registration.Feature`` is written by Open3D's ``WriteFeature``:
int32 ``dim``, int32 ``n``, then the ``dim x n`` column-major Eigen matrix as float64,
which is the same bytes as an (n, dim) row-major array: one feature vector per point.
"""

from __future__ import annotations

import os

import numpy as np

from .files import read_checked

__all__ = ["read_open3d_feature"]


def read_open3d_feature(path: str | os.PathLike[str]) -> np.ndarray:
    """Read an Open3D feature file into an (n, dim) float64 array (row i: point i).

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If it is empty, shorter or longer than its header says, or has a negative size.
    """
    file, raw = read_checked(path)
    if len(raw) < 8:
        raise ValueError(f"{file}: too short for an Open3D feature header ({len(raw)} bytes)")
    dim, n = (int(v) for v in np.frombuffer(raw, "<i4", 2))
    if dim < 0 or n < 0:
        raise ValueError(f"{file}: not an Open3D feature file (header dim={dim}, n={n})")
    need = 8 + dim * n * 8
    if len(raw) != need:
        state = "truncated" if len(raw) < need else "longer than its header says"
        raise ValueError(
            f"{file}: Open3D feature file is {state}: dim={dim}, n={n} need {need} bytes, "
            f"the file has {len(raw)}"
        )
    return np.frombuffer(raw, "<f8", dim * n, 8).reshape(n, dim).copy()

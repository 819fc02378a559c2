"""The stage after poses when the clouds are at hand: ICP refinement and verification.

A pose fitted to a few descriptor matches is off by a few voxels and degrees, and realistic
scenes hold consistent groups of wrong matches that yield wrong poses. The clouds settle
both: ICP pulls each pose onto its copy, and the share of the model the scan then explains
(Open3D's ``fitness``) rejects poses over clutter and duplicates of one copy. On realistic
validation scenes this raises MF by about 10 points (BENCHMARKS.md, "Refinement on the
clouds").
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from . import _core
from . import preprocessing as pp
from .registration import _as_threads

__all__ = ["MIN_FITNESS", "MIN_RELATIVE_FITNESS", "RefinedPoses", "refine_poses"]

#: Poses explaining less of the model are rejected whatever the rest of the scene holds.
MIN_FITNESS = 0.3
#: Poses explaining less than this share of the best pose's fitness are rejected: copies of
#: one object under one sensor are seen alike, whatever the object. Chosen on the realistic
#: scenes of the training models (dragon, happy, bathtub; 0.7 / 0.8 / 0.9 compared), checked
#: on the validation models (armadillo, bed); never on the bunny.
MIN_RELATIVE_FITNESS = 0.8


class RefinedPoses(NamedTuple):
    """The accepted poses, best fitness first."""

    #: (M, 4, 4) T_target_source after ICP.
    transformations: np.ndarray
    #: (M,) share of the source points with a target point within 1.5 voxels.
    fitness: np.ndarray
    #: (M,) RMS distance of those source points to their nearest target points.
    inlier_rmse: np.ndarray
    #: (M,) index of the input pose each one came from.
    origin: np.ndarray


def refine_poses(
    source_points: ArrayLike,
    target_points: ArrayLike,
    transformations: ArrayLike,
    voxel_size: float,
    *,
    icp: bool = True,
    min_fitness: float = MIN_FITNESS,
    min_relative_fitness: float = MIN_RELATIVE_FITNESS,
    max_shared: float = 0.5,
    num_threads: int | None = None,
) -> RefinedPoses:
    """Refine poses of `source_points` in `target_points` by ICP and keep those the scan
    supports.

    Parameters
    ----------
    source_points, target_points : (N, 3), (M, 3) array_like
        The model and the scan, downsampled at `voxel_size` (as
        :func:`pointclm.register_point_clouds` returns them).
    transformations : (K, 4, 4) array_like
        Candidate poses ``T_target_source`` (rigid).
    voxel_size : float
        Sets the lengths: ICP at 3, 2 and 1.5 voxels, a model point explained within 1.5.
    icp : bool
        False: verification only, the poses are kept as given.
    min_fitness, min_relative_fitness : float in [0, 1]
        Reject a pose explaining less than `min_fitness` of the model, or less than
        `min_relative_fitness` times the best pose's fitness. Both 0: nothing is rejected for
        its fitness, only duplicates (a pose whose explained scan points are mostly explained
        by a better pose).
    max_shared : float in [0, 1]
        A pose is a duplicate when more than this share of the scan points it explains are
        explained by a better pose; 1 keeps duplicates.
    """
    src = pp._points(source_points, "source_points")
    tgt = pp._points(target_points, "target_points")
    voxel = pp._positive(voxel_size, "voxel_size")
    try:
        poses = np.asarray(transformations, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(
            f"transformations must be a (K, 4, 4) array of numbers, got {type(transformations)}"
        ) from None
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        if poses.size == 0:
            poses = np.zeros((0, 4, 4))
        else:
            raise ValueError(f"transformations must have shape (K, 4, 4), got {poses.shape}")
    out: Any = _core.refine_poses(
        src,
        tgt,
        np.ascontiguousarray(poses),
        voxel,
        pp._flag(icp, "icp"),
        _number(min_fitness, "min_fitness"),
        _number(min_relative_fitness, "min_relative_fitness"),
        _number(max_shared, "max_shared"),
        num_threads=_as_threads(num_threads),
    )
    return RefinedPoses(*out)


def _number(value: float, name: str) -> float:
    """A float for the core, which checks the range ([0, 1]) itself."""
    if isinstance(value, bool | str | bytes) or not isinstance(
        value, int | float | np.integer | np.floating
    ):
        raise ValueError(f"{name} must be a number in [0, 1], got {value!r}")
    try:
        return float(value)
    except OverflowError:
        raise ValueError(f"{name} must be a number in [0, 1], got {value!r}") from None

"""Turned alternatives of verified poses: a part close to a symmetry is often posed turned, and
the few discrete hypotheses (half turns about the model's principal axes, quarter turns about
those that leave most of it in place, and the scene's own alternatives) are refined and scored
like the pose, the one the scan supports best kept (:func:`resolve_flips`). The arithmetic is
the core's (``pointclm::scene::flips``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from . import _core
from . import preprocessing as pp
from .refinement import (
    MAX_QUARTER_TURN_CHANGE,
    MIN_FLIP_CHANGE,
    RefinedPoses,
    RefinementContext,
    _refined_poses,
)
from .registration import as_threads
from .scene_rules import SceneRules

__all__ = ["flip_turns", "quarter_turns", "resolve_flips"]


def flip_turns(
    source_points: ArrayLike, voxel_size: float, min_change: float = MIN_FLIP_CHANGE
) -> np.ndarray:
    """(F, 4, 4) half turns of the model about its principal axes through its centroid that
    verification can tell from the model itself (at least `min_change` of the turned model
    farther than 1.5 voxels from it, `MIN_FLIP_CHANGE`); F <= 3, by ascending variance of
    the axis."""
    src = pp.as_points(source_points, "source_points")
    voxel = pp.as_positive(voxel_size, "voxel_size")
    return _core.flip_turns(src, voxel, _share(min_change, "min_change"))


def quarter_turns(
    source_points: ArrayLike,
    voxel_size: float,
    min_change: float = MIN_FLIP_CHANGE,
    max_change: float = MAX_QUARTER_TURN_CHANGE,
) -> np.ndarray:
    """(Q, 4, 4) quarter turns of the model, either way about its principal axes through its
    centroid, that move at least `min_change` and at most `max_change` of it farther than 1.5
    voxels from it (near-symmetries, `MAX_QUARTER_TURN_CHANGE`); Q <= 6. Axes by ascending
    variance, each signed so that its first component off zero is positive, +90 degrees about
    it before -90."""
    src = pp.as_points(source_points, "source_points")
    voxel = pp.as_positive(voxel_size, "voxel_size")
    low, high = _share(min_change, "min_change"), _share(max_change, "max_change")
    return _core.quarter_turns(src, voxel, low, high)


def _share(value: float, name: str) -> float:
    share = float(value)
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"{name} must lie in [0, 1], got {value!r}")
    return share


def _as_rotations(rotations: ArrayLike | None) -> np.ndarray:
    """(K, 3, 3) finite rotations, each made exactly orthonormal (the nearest rotation), as
    the core takes the rotation block of a pose: within `MAX_ROTATION_DEVIATION` of
    orthonormal (``||R^T R - I||_F``) with a positive determinant, so that a scaled matrix or
    a reflection is an error, not silently made a rotation."""
    if rotations is None:
        return np.empty((0, 3, 3))
    rot = np.asarray(rotations, dtype=np.float64)
    if rot.size == 0:
        return np.empty((0, 3, 3))
    if rot.ndim != 3 or rot.shape[1:] != (3, 3):
        raise ValueError(f"rotations must have shape (K, 3, 3), got {rot.shape}")
    if not np.isfinite(rot).all():
        raise ValueError("rotations has a non-finite value (NaN or inf)")
    bad = np.flatnonzero(~pp.are_rotations(rot))
    if len(bad):
        k = int(bad[0])
        deviation = pp.rotation_deviation(rot[k : k + 1])[0]
        raise ValueError(
            f"rotations[{k}] is not a rotation (||R^T R - I|| = {deviation:.2e}, at most "
            f"{_core.MAX_ROTATION_DEVIATION:.0e} is taken for rounding; determinant must be "
            "positive)"
        )
    u, _, vt = np.linalg.svd(rot)
    sign = np.sign(np.linalg.det(u @ vt))
    u[:, :, 2] *= sign[:, None]
    return u @ vt


def resolve_flips(
    source_points: ArrayLike,
    target_points: ArrayLike,
    poses: RefinedPoses,
    voxel_size: float,
    *,
    viewpoint: ArrayLike | None = None,
    target_normals: ArrayLike | None = None,
    num_threads: int | None = None,
    context: RefinementContext | None = None,
    rotations: ArrayLike | None = None,
    scene: SceneRules | None = None,
) -> tuple[RefinedPoses, np.ndarray]:
    """Verified `poses` with each replaced by a turned alternative the scan supports better,
    surest first, and the row of `poses` each came from.

    Why: a part close to a symmetry (a bathtub end for end, a bed or a box with a block on one
    corner a quarter turn about its vertical axis) is often posed turned: ICP settles it on the
    copy and it passes verification, yet its rotation is wrong. The few discrete hypotheses
    (the pose times a half turn about each principal axis of the model, :func:`flip_turns`,
    and a quarter turn either way about those that leave most of the model in place,
    :func:`quarter_turns`) are refined by ICP and scored like the pose. A turned pose that
    explains at least as much of the whole model (``fitness``; visible fitness alone rewards a
    pose that turns the unexplained part away from the sensor) replaces it when

    * it is a half turn and surer (``confidence``), or
    * it would itself pass verification (`MIN_VISIBLE_FITNESS`, `MAX_CONTRADICTION` when
      judged by the sensor) and explains far more of the points that tell the two apart: the
      model points each puts where the other has no surface (`FLIP_EVIDENCE_RATIO`,
      `FLIP_EVIDENCE_SIGMAS`).

    A pose that stays is one of several hypotheses when some of its turns pass the same
    conditions and the points that tell them apart decide neither way (the sensor did not see
    the part that differs): its ``confidence`` is divided by one plus their number, so poses
    whose rotation the scan settles come first. Turns mapping the model onto itself are not
    tried (`MIN_FLIP_CHANGE`; `MIN_FLIP_CHANGE_BY_FITNESS` without a viewpoint). `context`: a
    :class:`RefinementContext` of the same clouds, voxel and viewpoint, to reuse. `rotations`
    (K x 3 x 3): the scene's own alternatives, tried like the quarter turns (`SCENE_TURN_DEG`).
    `scene`: the turns' rules (:class:`pointclm.SceneRules`; None: the defaults)."""
    src = pp.as_points(source_points, "source_points")
    voxel = pp.as_positive(voxel_size, "voxel_size")
    rules = SceneRules.resolve(scene)
    turns = _as_rotations(rotations)
    n = len(poses.transformations)
    if n == 0:
        return poses, np.arange(n)
    if context is None:
        context = RefinementContext(
            src,
            target_points,
            voxel,
            viewpoint=viewpoint,
            target_normals=target_normals,
            num_threads=num_threads,
        )
    return _resolved(context, poses, turns, rules, num_threads)


def _resolved(
    context: RefinementContext,
    poses: RefinedPoses,
    turns: np.ndarray,
    rules: SceneRules,
    num_threads: int | None,
) -> tuple[RefinedPoses, np.ndarray]:
    """The core's :func:`resolve_flips` of `poses` against `context`'s clouds."""
    scores = [
        poses.confidence,
        poses.fitness,
        poses.visible_fitness,
        poses.contradiction,
        poses.seen,
        poses.inlier_rmse,
        poses.visible_rmse,
    ]
    (mats, columns, origin, *_), order = context._core.resolve_flips(
        np.asarray(poses.transformations, dtype=np.float64),
        [np.asarray(c, dtype=np.float64) for c in scores],
        np.asarray(poses.origin, dtype=np.int64),
        bool(poses.by_visibility),
        turns,
        rules.to_dict(),
        num_threads=as_threads(num_threads),
    )
    return _refined_poses(mats, columns, origin, poses.by_visibility), order

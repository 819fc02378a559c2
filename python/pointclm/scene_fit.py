"""How a scene's poses compare with each other once verification is done: the loosest fits
dropped, and each pose made less sure the looser it fits and the less firmly the scan pins it
down than the scene's median pose (the scene parameters ``max_relative_visible_rmse`` and
``min_poses_to_compare`` say why). :mod:`pointclm.refinement` names these too."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from . import _core
from .scene_rules import SCENE_DEFAULTS

__all__ = ["fit_tightness", "loose_poses", "stability_factor"]

MAX_RELATIVE_VISIBLE_RMSE = SCENE_DEFAULTS.max_relative_visible_rmse
MIN_POSES_TO_COMPARE = SCENE_DEFAULTS.min_poses_to_compare


def loose_poses(
    visible_rmse: ArrayLike,
    max_relative: float = MAX_RELATIVE_VISIBLE_RMSE,
    min_poses: int = MIN_POSES_TO_COMPARE,
) -> np.ndarray:
    """Which of a scene's poses fit the scan loosely against the others: ``visible_rmse``
    (`RefinedPoses.visible_rmse`) above `max_relative` times its median over the poses where
    it is known. None among fewer than `min_poses` known values (the scene parameters
    ``max_relative_visible_rmse`` and ``min_poses_to_compare`` say why)."""
    return _core.loose_poses(_values(visible_rmse), float(max_relative), int(min_poses))


def fit_tightness(visible_rmse: ArrayLike, min_poses: int = MIN_POSES_TO_COMPARE) -> np.ndarray:
    """Each pose's factor of sureness from how tightly its visible side lies on the scan
    against the scene's median pose: ``min(1, median / visible_rmse)``, 1 where unknown or
    among fewer than `min_poses` known values. `register_point_clouds` multiplies
    ``confidence`` by it, after :func:`loose_poses` dropped the loosest.

    Why: visible fitness saturates near 1 for every copy a heap shows well, so it cannot order
    them, while a pose turned a little about a near-symmetry (a Buddha 17 degrees about its
    axis, a bed end for end) still pairs its points with its copy's surface, a little looser
    than the right poses of the same scan do. On the 72 validation bins, wrong poses sat at a
    median 1.15 times the scene's median and right ones at 1.0 (BENCHMARKS.md)."""
    return _core.fit_tightness(_values(visible_rmse), int(min_poses))


def stability_factor(stability: ArrayLike, min_poses: int = MIN_POSES_TO_COMPARE) -> np.ndarray:
    """Each pose's factor of sureness from :func:`pointclm.refinement.pose_stability` against
    the scene's median pose: ``min(1, stability / median)``, 1 where unknown (NaN) or among
    fewer than `min_poses` known values. `register_point_clouds` multiplies ``confidence`` by
    it, with :func:`fit_tightness`.

    Why relative: copies of one part show the scan alike, so a right pose is pinned about as
    firmly as the scene's median copy, whatever the part's shape; a pose resting on one face of
    a copy or of the bin is pinned less. On the validation bins the first five were all right
    in 71 of 72 scenes against 68 with :func:`fit_tightness` alone (BENCHMARKS.md)."""
    return _core.stability_factor(_values(stability), int(min_poses))


def _values(values: ArrayLike) -> np.ndarray:
    """A 1-D float64 array of `values` (NaN: unknown)."""
    return np.ascontiguousarray(np.asarray(values, dtype=np.float64).reshape(-1))

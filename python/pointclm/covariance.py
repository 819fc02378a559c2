"""How well the scan determines each refined pose: the 6 x 6 information matrix of
point-to-plane ICP at the pose and the pose covariance it gives.

Order and frame: ``(rx, ry, rz, x, y, z)``, a small rotation (radians, about the scan frame's
axes) then a translation (the clouds' units), perturbing a pose ``T_target_source = (R, t)``
as ``R <- exp([r]x) R``, ``t <- t + dt``: the rotation turns the model about its own origin,
so the blocks are a ROS ``PoseWithCovariance``'s (which puts the translation first,
:mod:`pointclm.ros`).

``information`` is ``sum J^T J`` over the model points with a scan point within 1.5 voxels
(the pairs ``fitness`` counts), ``J = [((p - t) x n)^T, n^T]`` for the posed model point ``p``
and the unit normal ``n`` of its nearest scan point, as is: a box lying on one face has a
(near) null direction along each slide. ``covariance`` is ``sigma^2`` times its inverse, with
``sigma^2 = sum r^2 / (pairs - 6)`` of the point-to-plane residuals. A direction whose
eigenvalue is below :data:`MIN_RELATIVE_EIGENVALUE` of the largest (rotations counted as arcs
at the explained points' spread about their centroid) is unobservable: the covariance there is
a pseudo-inverse plus a standard deviation of :data:`UNOBSERVABLE_SPREADS` spreads
(translations) or radians (rotations), large and finite so that JSON and ROS carry it; the
count of such directions is ``unobservable`` (all six with six pairs or fewer).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from .registration import as_threads

if TYPE_CHECKING:
    from .refinement import RefinementContext

__all__ = ["MIN_RELATIVE_EIGENVALUE", "UNOBSERVABLE_SPREADS", "PoseCovariances", "pose_covariances"]

#: See the module documentation (``pointclm::pointcloud::covariance`` in the Rust core).
MIN_RELATIVE_EIGENVALUE = 5e-3
UNOBSERVABLE_SPREADS = 10.0

#: Pairs are model points within this many voxels of a scan point, as for ``fitness``.
_PAIR_VOXELS = 1.5


class PoseCovariances(NamedTuple):
    """Per pose, in the order ``(rx, ry, rz, x, y, z)`` (module documentation)."""

    #: (P, 6, 6) ``sum J^T J`` at each pose.
    information: np.ndarray
    #: (P, 6, 6) symmetric positive semi-definite, finite.
    covariance: np.ndarray
    #: (P,) how many directions the scan does not determine.
    unobservable: np.ndarray
    #: (P,) ``sigma^2`` of the point-to-plane residuals (0 with six pairs or fewer).
    residual_variance: np.ndarray


def pose_covariances(
    source_points: ArrayLike,
    target_points: ArrayLike,
    transformations: ArrayLike,
    voxel_size: float,
    *,
    target_normals: ArrayLike | None = None,
    num_threads: int | None = None,
    context: RefinementContext | None = None,
) -> PoseCovariances:
    """The information and covariance of each pose ``T_target_source`` (P x 4 x 4) of
    `source_points` in `target_points` (downsampled at `voxel_size`; `target_normals` are
    estimated as :func:`pointclm.refine_poses` does when omitted). `context`: a
    :class:`pointclm.refinement.RefinementContext` of the same clouds, to reuse its index and
    normals (the clouds are then not read)."""
    from .refinement import RefinementContext, _as_poses

    if context is None:
        context = RefinementContext(
            source_points,
            target_points,
            voxel_size,
            target_normals=target_normals,
            num_threads=num_threads,
        )
    poses = _as_poses(transformations)
    radius = _PAIR_VOXELS * context.voxel_size
    info, cov, unobservable, variance = context._core.pose_covariances(
        poses, radius, num_threads=as_threads(num_threads)
    )
    return PoseCovariances(info, cov, unobservable, variance)

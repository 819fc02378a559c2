"""The results of `register_point_clouds`: each copy found, each pass of the correspondence
stage, and the whole registration."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._core import Instance, RegistrationResult
from ..config import Config
from ..poses import PoseForms
from ..symmetry import Symmetry

#: A model point is explained within this many voxels of a scan point: the radius of
#: ``fitness`` and ``inlier_rmse`` (:func:`pointclm.refine_poses`).
FITNESS_VOXELS = 1.5


@dataclass(frozen=True)
class CloudInstance(PoseForms):
    """One copy of the model in the scan, refined and verified on the clouds.

    ``transformation`` is ``T_target_source`` (4 x 4); ``quaternion(order="xyzw")`` (or
    ``"wxyz"``, unit norm, sign canonical ``w >= 0``), ``rotation`` and ``translation`` give
    it in other forms (:mod:`pointclm.poses`). ``transformation``, ``fitness``,
    ``inlier_rmse`` and ``correspondence_set`` are named and defined as in Open3D's
    ``RegistrationResult``.

    ``fitness`` and ``inlier_rmse`` follow Open3D's ``evaluate_registration``: the share of the
    (downsampled) model's points with a scan point within 1.5 voxels, and their RMS distance.
    ``confidence`` in [0, 1] says how sure the pose is (instances come surest first): with a
    trusted viewpoint, the share of what the sensor could see of the copy at that pose that the
    scan explains, times one minus the share where the sensor saw free space
    (``visible_fitness``, ``contradiction``); without one, ``fitness``
    (:func:`pointclm.refinement.refine_poses`). With ``flips``, it is divided by one plus the
    number of turns of the pose that the scan supports as well (a near-symmetric part whose
    differing side the sensor did not see, :func:`pointclm.refinement.resolve_flips`).
    ``visible_rmse`` is the RMS distance of the explained model points the sensor could see (NaN
    without a trusted viewpoint): copies whose visible side fits more than 1.3 times as loosely
    as the scene's median copy are not returned (:func:`pointclm.refinement.loose_poses`), and
    among three or more, ``confidence`` is multiplied by ``min(1, median / visible_rmse)``
    (:func:`pointclm.refinement.fit_tightness`) and by how firmly the scan pins the pose down
    against the median copy (:func:`pointclm.refinement.stability_factor` of
    :func:`pointclm.refinement.pose_stability`).
    ``matches`` is the correspondence-stage instance the pose was refined from (its ``inliers``
    index the correspondences of the pass that proposed it,
    ``PointCloudRegistration.passes[pass_index].correspondences``; pass 0's are
    ``PointCloudRegistration.correspondences``), or None when the pose was proposed by point
    pair voting in a heap (`HEAP_VOTED_POSES`; no correspondence inliers).
    ``information`` and ``covariance`` (6 x 6, order rx, ry, rz in radians then x, y, z in the
    clouds' units, rotations about the model's origin in the scan's axes) say how well the scan
    pins the pose down; ``unobservable`` counts the directions it does not
    (:func:`pointclm.covariance.pose_covariances`).
    """

    transformation: np.ndarray
    fitness: float
    inlier_rmse: float
    matches: Instance | None
    confidence: float = float("nan")
    visible_fitness: float = float("nan")
    contradiction: float = float("nan")
    pass_index: int = 0
    visible_rmse: float = float("nan")
    #: (6, 6) point-to-plane information and pose covariance at ``transformation``, order
    #: (rx, ry, rz, x, y, z) (:mod:`pointclm.covariance`); None when not computed.
    information: np.ndarray | None = field(default=None, repr=False, compare=False)
    covariance: np.ndarray | None = field(default=None, repr=False, compare=False)
    #: How many of the six directions the scan does not determine (a box on one face: 3).
    unobservable: int = 0
    #: What the model slid along the face it explains still explains, as a share of what it
    #: explains in place (NaN where not measured); above ``max_slid_fitness`` (0.9) the copy
    #: is among :attr:`PointCloudRegistration.ambiguous`.
    slid_fitness: float = float("nan")
    # The registration's clouds and voxel, set by `PointCloudRegistration`, for
    # `correspondence_set`: computed on demand, since few callers want the pairs.
    _clouds: tuple[np.ndarray, np.ndarray, float] | None = field(
        default=None, init=False, repr=False, compare=False
    )

    @property
    def correspondence_set(self) -> np.ndarray | None:
        """(K, 2) int64 pairs (model point, its nearest scan point) within 1.5 voxels under
        ``transformation``, as Open3D's ``evaluate_registration`` reports them: rows of
        ``PointCloudRegistration.source_points`` and ``target_points``. ``K / len(
        source_points)`` is ``fitness`` and the pairs' RMS distance ``inlier_rmse``. None for
        an instance not taken from a :class:`PointCloudRegistration`."""
        if self._clouds is None:
            return None
        from scipy.spatial import cKDTree

        source, target, voxel = self._clouds
        posed = source @ self.rotation.T + self.translation
        radius = FITNESS_VOXELS * voxel
        dist, nearest = cKDTree(target).query(posed, distance_upper_bound=radius)
        near = np.flatnonzero(dist < radius)
        return np.stack([near, nearest[near]], axis=1).astype(np.int64)

    @property
    def inliers(self) -> np.ndarray:
        if self.matches is None:
            return np.empty(0, dtype=np.int64)
        return np.asarray(self.matches.inliers)

    def __len__(self) -> int:
        return 0 if self.matches is None else len(self.matches)

    def __repr__(self) -> str:
        # One line a person reads: the scores and where the copy sits, not the 4 x 4 matrix.
        t = ", ".join(f"{v:.4g}" for v in np.asarray(self.transformation)[:3, 3])
        return (
            f"CloudInstance(fitness={self.fitness:.3f}, confidence={self.confidence:.3f}, "
            f"inlier_rmse={self.inlier_rmse:.3g}, pass_index={self.pass_index}, "
            f"matches={len(self)}, translation=[{t}])"
        )


@dataclass(frozen=True)
class Pass:
    """One pass of the correspondence stage over the scan points no accepted copy explained
    yet (pass 0: the whole scan)."""

    #: (N, 6) rows: downsampled model point | downsampled scan point.
    correspondences: np.ndarray
    result: RegistrationResult
    #: Indices into ``PointCloudRegistration.target_points`` of the scan points matched.
    scan_points: np.ndarray
    #: Copies this pass added to the accepted ones.
    added: int
    #: (K, 4, 4) poses proposed by point pair voting over ``scan_points`` (heap passes,
    #: `HEAP_VOTED_POSES`; empty otherwise), judged beside ``result``'s: an accepted pose's
    #: ``CloudInstance.matches`` is None when it came from here.
    voted: np.ndarray = field(default_factory=lambda: np.empty((0, 4, 4)))
    #: (F, 4, 4) poses laying a model face on a planar patch of ``scan_points``
    #: (``proposals``), judged after ``voted``: an accepted pose's ``CloudInstance.matches``
    #: is None when it came from here too.
    faces: np.ndarray = field(default_factory=lambda: np.empty((0, 4, 4)))
    #: (D, 4, 4) poses of this pass that passed verification on a copy already accepted
    #: (peeling's duplicate check); their rotations relative to that copy's pose are the
    #: scene's own alternatives for :func:`pointclm.refinement.resolve_flips`.
    duplicates: np.ndarray = field(default_factory=lambda: np.empty((0, 4, 4)))
    #: The mutual descriptor matches that survived matching: ``len(correspondences)``, or,
    #: when fewer than 3 (too few for a pose), how few; ``correspondences`` is then empty and
    #: ``result`` has no instance. None: not recorded (``len(correspondences)``).
    matches: int | None = None

    def __repr__(self) -> str:
        return (
            f"Pass(correspondences={len(self.correspondences)}, candidates={len(self.result)}, "
            f"voted={len(self.voted)}, scan_points={len(self.scan_points)}, added={self.added}, "
            f"duplicates={len(self.duplicates)})"
        )


@dataclass(frozen=True)
class PointCloudRegistration:
    """The result of :func:`register_point_clouds`; ``print`` shows a summary.

    ``instances`` are the refined and verified copies, surest first (``confidence``).
    ``result`` is the correspondence stage's :class:`pointclm.RegistrationResult` over
    ``correspondences`` (rows: downsampled model point | downsampled scene point), before
    refinement.
    ``passes`` holds every pass of the correspondence stage: pass 0 over the whole scan, then
    one per peeling round over what the accepted copies leave unexplained.
    ``timings`` holds seconds per stage (load, downsample, normals, fpfh, matching, embedding,
    pruning, clustering, poses, refinement: pass 0's; peeling: every later pass; flips: the
    half-turned alternatives; total).
    ``viewpoint`` is the sensor position verification judged by (given, or a PCD file's
    ``VIEWPOINT``; None: none known, poses judged by the share of the model explained), and
    ``orientation`` says how the scan's normals were oriented. ``viewpoint_disputed``: the
    scan does not look like one view from the viewpoint given (a
    :class:`pointclm.errors.ViewpointDisagreementWarning` said so; verification used it all
    the same). ``diagnosis`` explains an
    empty or doubtful result and what to try ("" when there is nothing to say).
    ``ambiguous`` holds poses that fit the scan as well as a copy but slide along a face (a
    box flush with its neighbours, a flat face lying on a larger plane): the scan does not
    say where along that face the copy lies. They are not in ``instances``; surest first,
    their ``confidence`` lowered by the slide (times ``(1 - slid_fitness) / (1 - 0.9)``), none
    sharing more than half its scan points with an instance or a surer one. Each carries its
    ``information`` matrix: its near-zero directions are the slide. Keep those the
    application can tell apart (a gripper that needs only the face, a known grid pitch).
    :meth:`to_open3d` gives the scan and each copy as Open3D clouds.
    """

    result: RegistrationResult
    correspondences: np.ndarray
    source_points: np.ndarray
    target_points: np.ndarray
    voxel_size: float
    config: Config
    instances: list[CloudInstance] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    passes: list[Pass] = field(default_factory=list)
    viewpoint: np.ndarray | None = None
    orientation: str = ""
    diagnosis: str = ""
    viewpoint_disputed: bool = False
    ambiguous: list[CloudInstance] = field(default_factory=list)
    #: The model's symmetries every pose was made canonical by (declared, or detected with
    #: ``symmetry="auto"``); None: none declared.
    symmetry: Symmetry | None = None
    #: The descriptor the clouds were matched by: "fpfh", "learned" or "fpfh+learned"
    #: (``descriptor="auto"`` decided for the model); "" when the clouds were not matched here.
    descriptor: str = ""

    def __post_init__(self) -> None:
        clouds = (self.source_points, self.target_points, self.voxel_size)
        for inst in [*self.instances, *self.ambiguous]:
            if isinstance(inst, CloudInstance):
                object.__setattr__(inst, "_clouds", clouds)

    @property
    def transformations(self) -> np.ndarray:
        """(M, 4, 4) T_target_source of every instance found."""
        if not self.instances:
            return np.zeros((0, 4, 4))
        return np.stack([inst.transformation for inst in self.instances])

    def to_open3d(self) -> list[Any]:
        """``[scan, copy 0, copy 1, ...]`` as ``open3d.geometry.PointCloud`` objects, ready
        for ``open3d.visualization.draw_geometries``: the scan (``target_points``) in grey,
        then for each of ``instances`` (same order, surest first) the model
        (``source_points``) placed by its ``transformation``, each in its own colour (those
        of :func:`pointclm.visualize.palette`, as the PNG and PLY draw them). Imports
        Open3D (``pip install open3d-cpu`` or ``open3d``)."""
        from ..interop.open3d import to_open3d
        from ..visualize import GREY, palette

        clouds = [to_open3d(self.target_points, colors=GREY)]
        for inst, colour in zip(self.instances, palette(len(self.instances)), strict=True):
            posed = self.source_points @ inst.rotation.T + inst.translation
            clouds.append(to_open3d(posed, colors=colour))
        return clouds

    def to_html(
        self,
        path: str | os.PathLike[str],
        *,
        ground_truth: ArrayLike | None = None,
        title: str = "",
    ) -> Path:
        """Write one self-contained page to turn the result around in a browser (plotly,
        ``pip install 'pointclm[viz]'``); see :func:`pointclm.html_page.write_html`."""
        from ..html_page import write_html

        return write_html(path, self, ground_truth=ground_truth, title=title)

    def __repr__(self) -> str:
        # A summary, not the arrays: what was found, how it was judged, where time went.
        lines = [
            f"PointCloudRegistration({len(self.instances)} instance(s) in "
            f"{len(self.target_points)} scan points at voxel {self.voxel_size:.4g}, "
            f"{len(self.passes)} pass(es), {self.timings.get('total', float('nan')):.2f} s)"
        ]
        lines += [f"  [{i}] {inst!r}" for i, inst in enumerate(self.instances)]
        if self.diagnosis:
            lines.append(f"  note: {self.diagnosis}")
        if self.orientation:
            lines.append(f"  scan normals: {self.orientation}")
        if self.descriptor:
            lines.append(f"  matched by: {self.descriptor}")
        judged = "none known" if self.viewpoint is None else _xyz(self.viewpoint)
        disputed = " (the scan disputes it)" if self.viewpoint_disputed else ""
        lines.append(f"  verification viewpoint: {judged}{disputed}")
        stages = ", ".join(f"{k} {v:.3f}" for k, v in self.timings.items() if k != "total")
        lines.append(f"  timings (s): {stages}")
        return "\n".join(lines)


def _xyz(p: ArrayLike) -> str:
    return "(" + ", ".join(f"{v:.4g}" for v in np.asarray(p, dtype=np.float64)) + ")"

"""The stage after poses when the clouds are at hand: ICP refinement and verification.

A pose fitted to a few descriptor matches is off by a few voxels and degrees, and realistic
scenes hold consistent groups of wrong matches that yield wrong poses. The clouds settle
both: ICP pulls each pose onto its copy, and the share of the model the scan then explains
(Open3D's ``fitness``) rejects poses over clutter and duplicates of one copy. With the
sensor's position, each pose is judged instead by what the sensor could see of the model at
that pose, so that copies hidden in part by others are kept (``benchmarks/clouds/verification.py``).

Acceptance rules of :func:`refine_poses`
----------------------------------------
With a viewpoint (the position of the sensor that took the scan, one view), each pose is
judged by what the sensor could see of the model at that pose: the posed model points not
hidden by the model itself or by the scan, nor past the scan's edge (on a ray without a return
where the scan has none on some side within the model's radius: its field of view, a crop). A
pose is kept when the scan explains at least `min_visible_fitness` of them, at most
`max_contradiction` of them lie where the sensor saw through to something behind, and they are
at least `min_seen` of the model. A partly hidden copy is thus
judged on its visible part. Without a viewpoint, or when more than 12 % of the
scan lies 5 voxels behind other scan points seen from it (a merged or wrongly placed scan),
the fallback is the share of the model explained: at least `min_fitness`, and at least
`min_relative_fitness` times the best pose's (``RefinedPoses.by_visibility`` says which rule
judged). A pose is a duplicate when more than `max_shared` of the scan points it explains are
explained by a surer pose. With or without a viewpoint, a pose is rejected when the model slid
along the surface it explains (by that surface's spread, both ways along its two main
directions) keeps more than `max_slid_fitness` of what it explains in place: a patch lying on a
larger surface of its shape (a face of a part on a table or a wall) fits anywhere on it, so
the fit does not say where the object is. And a pose is rejected when fewer than
`min_normal_agreement` (0.4) of the model points the scan explains have normals within 30
degrees of the scan's there: a right pose lies along the surface it explains, while a model sunk
into a floor or wall, whose noise band holds the cut, meets it across.

Across a scene's poses, once peeling is done: `register_point_clouds` drops, among three or more
poses judged by the sensor, those whose visible side lies on the scan more loosely than
`MAX_RELATIVE_VISIBLE_RMSE` times the median pose's (:func:`loose_poses` over
``RefinedPoses.visible_rmse``), and makes the rest less sure the looser they fit
(:func:`fit_tightness`) and the less firmly the scan pins them down (:func:`stability_factor`
of :func:`pose_stability`) than the median pose. `refine_poses` reports ``visible_rmse`` and
leaves this to the caller, since it may be given only some of the scene's copies.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from . import _core
from . import preprocessing as pp
from .interop.open3d import with_open3d_normals
from .registration import as_threads
from .scene_rules import SCENE_DEFAULTS
from .symmetry import canonical_for
from .symmetry import resolve as resolve_symmetry

#: The core's declaration of `RefineParams` (lengths in voxels): every rule's default, read
#: here so that it is stated once, in Rust (`pointclm::pointcloud::RefineParams`).
_RULE_DEFAULTS: dict[str, Any] = {f["name"]: f["default"] for f in _core.refine_params_schema()}

__all__ = [
    "MAX_CONTRADICTION",
    "MAX_RELATIVE_VISIBLE_RMSE",
    "MAX_SHARED",
    "MAX_SLID_FITNESS",
    "MIN_NORMAL_AGREEMENT",
    "MIN_FITNESS",
    "MIN_POSES_TO_COMPARE",
    "MIN_RELATIVE_FITNESS",
    "MIN_SEEN",
    "MIN_VISIBLE_FITNESS",
    "RefinedPoses",
    "RefinementContext",
    "fit_tightness",
    "loose_poses",
    "pose_stability",
    "refine_poses",
    "resolve_flips",
    "stability_factor",
]

# The acceptance rules' defaults, and the turned alternatives' and scene ranking's, as the
# Rust core declares them (`pointclm::pointcloud::RefineParams`, `pointclm::scene::SceneRules`,
# where each field's reason and the data it was chosen on are written; `help(SceneRules)`).
MIN_VISIBLE_FITNESS: float = _RULE_DEFAULTS["min_visible_fitness"]
MAX_CONTRADICTION: float = _RULE_DEFAULTS["max_contradiction"]
MIN_SEEN: float = _RULE_DEFAULTS["min_seen"]
MAX_SLID_FITNESS: float = _RULE_DEFAULTS["max_slid_fitness"]
MIN_NORMAL_AGREEMENT: float = _RULE_DEFAULTS["min_normal_agreement"]
MAX_SHARED: float = _RULE_DEFAULTS["max_shared"]
MIN_FITNESS: float = _RULE_DEFAULTS["min_fitness"]
MIN_RELATIVE_FITNESS: float = _RULE_DEFAULTS["min_relative_fitness"]
MIN_FLIP_CHANGE = SCENE_DEFAULTS.min_flip_change
MIN_FLIP_CHANGE_BY_FITNESS = SCENE_DEFAULTS.min_flip_change_by_fitness
MAX_QUARTER_TURN_CHANGE = SCENE_DEFAULTS.max_quarter_turn_change
FLIP_EVIDENCE_RATIO = SCENE_DEFAULTS.flip_evidence_ratio
FLIP_EVIDENCE_SIGMAS = SCENE_DEFAULTS.flip_evidence_sigmas
SCENE_TURN_DEG = SCENE_DEFAULTS.scene_turn_deg
MAX_SCENE_TURNS = SCENE_DEFAULTS.max_scene_turns
MAX_RELATIVE_VISIBLE_RMSE = SCENE_DEFAULTS.max_relative_visible_rmse
MIN_POSES_TO_COMPARE = SCENE_DEFAULTS.min_poses_to_compare

#: Scores only: `refine_poses` with these rejects nothing but duplicates (and keeps those
#: with ``max_shared=1``).
_KEEP_ALL: dict[str, Any] = {
    "min_fitness": 0.0,
    "min_relative_fitness": 0.0,
    "min_visible_fitness": 0.0,
    "max_contradiction": 1.0,
    "min_seen": 0.0,
    "max_slid_fitness": 1.0,
    "min_normal_agreement": 0.0,
}


class RefinedPoses(NamedTuple):
    """The accepted poses, surest first."""

    #: (M, 4, 4) T_target_source after ICP.
    transformations: np.ndarray
    #: (M,) share of the source points with a target point within 1.5 voxels.
    fitness: np.ndarray
    #: (M,) RMS distance of those source points to their nearest target points.
    inlier_rmse: np.ndarray
    #: (M,) index of the input pose each one came from.
    origin: np.ndarray
    #: (M,) how sure each pose is, in [0, 1], in decreasing order: with a viewpoint
    #: ``visible_fitness * (1 - contradiction)``, without one ``fitness``; from
    #: :func:`resolve_flips`, divided by one plus the number of turns it cannot rule out.
    confidence: np.ndarray
    #: (M,) share of what the sensor could see of the model at the pose that the scan
    #: explains (NaN when the viewpoint did not judge).
    visible_fitness: np.ndarray
    #: (M,) share of what the sensor could see of the model at the pose that lies where it
    #: saw free space (NaN when the viewpoint did not judge).
    contradiction: np.ndarray
    #: (M,) share of the model the sensor could see at the pose (NaN when the viewpoint did
    #: not judge).
    seen: np.ndarray
    #: (M,) RMS distance of the explained source points the sensor could see at the pose to
    #: their nearest target points: how tightly the side it saw lies on the scan (NaN when
    #: the viewpoint did not judge, or it sees none).
    visible_rmse: np.ndarray
    #: True when the poses were judged by what the sensor at the viewpoint could see; False
    #: when no viewpoint was given or the scan does not look like one view from it.
    by_visibility: bool
    #: (M,) what each model slid along the face it explains still explains, as a share of
    #: what it explains in place (NaN where not measured); None where not known.
    slid_fitness: np.ndarray | None = None
    #: The poses that pass every rule but slide along a face (``slid_fitness`` above
    #: `max_slid_fitness`): where along that face the copy lies, the scan does not say. Not
    #: kept, but returned apart, surest first, confidence times ``(1 - slid_fitness) / (1 -
    #: max_slid_fitness)``, none sharing more than `max_shared` of its scan points with a kept
    #: pose or a surer one. None where not known.
    sliding: RefinedPoses | None = None


def refine_poses(
    source_points: ArrayLike,
    target_points: ArrayLike,
    transformations: ArrayLike,
    voxel_size: float,
    *,
    viewpoint: ArrayLike | None = None,
    icp: bool = True,
    min_visible_fitness: float = MIN_VISIBLE_FITNESS,
    max_contradiction: float = MAX_CONTRADICTION,
    min_seen: float = MIN_SEEN,
    min_fitness: float = MIN_FITNESS,
    min_relative_fitness: float = MIN_RELATIVE_FITNESS,
    max_shared: float = MAX_SHARED,
    max_slid_fitness: float = MAX_SLID_FITNESS,
    min_normal_agreement: float = MIN_NORMAL_AGREEMENT,
    target_normals: ArrayLike | None = None,
    num_threads: int | None = None,
    symmetry: Any = None,
) -> RefinedPoses:
    """Refine poses of `source_points` in `target_points` by point-to-plane ICP and keep
    those the scan supports, surest first.

    Parameters
    ----------
    source_points, target_points : (N, 3), (M, 3) array_like, or Open3D clouds or meshes
        The model and the scan, downsampled at `voxel_size`; an Open3D target's normals
        serve as `target_normals` when those are omitted (:mod:`pointclm.interop.open3d`).
    transformations : (K, 4, 4) array_like
        Candidate poses ``T_target_source``; a rotation block off by rounding (``||R^T R -
        I||_F <= 1e-3``, positive determinant) is replaced by the nearest rotation.
    voxel_size : float
        Sets the lengths: ICP at 3, 2 and 1.5 voxels, a model point explained within 1.5,
        depth cells of 1.5 voxels and one surface within 3 voxels along a ray.
    viewpoint : (3,) array_like, optional
        The position of the sensor that took `target_points` (one view): poses are judged by
        what it could see of them (module documentation); ICP leaves out the far side.
    icp : bool
        False: verification only, the poses are kept as given.
    min_visible_fitness, max_contradiction, min_seen, min_fitness, min_relative_fitness : float
        The acceptance rules, in [0, 1] (module documentation).
    max_shared, max_slid_fitness, min_normal_agreement : float in [0, 1]
        The duplicate, slide and normals rules (module documentation); 1, 1 and 0 turn them off.
    target_normals : (M, 3) array_like, optional
        Unit normals of `target_points` (either sign); if omitted, estimated within 2 voxels,
        or 4 where depth steps make flat terraces at 2 (`pointclm.preprocessing.terraced_share`).
    symmetry : dict, pointclm.symmetry.Symmetry or "auto", optional
        The model's symmetries, as :func:`pointclm.register_point_clouds` takes them: poses
        (kept and sliding) come back canonical among their equivalents; scores do not change.
    """
    declared = resolve_symmetry(symmetry)  # a bad symmetry fails before the work
    clouds = (source_points, target_points, voxel_size)
    context = RefinementContext(
        *clouds, viewpoint=viewpoint, target_normals=target_normals, num_threads=num_threads
    )
    rules = (min_visible_fitness, max_contradiction, min_seen, min_fitness, min_relative_fitness)
    others = (max_shared, max_slid_fitness, min_normal_agreement)
    named = dict(zip(_RULES, (*rules, *others), strict=True))
    refined = context.refine(transformations, icp=icp, num_threads=num_threads, **named)
    return _canonical(refined, declared, source_points, num_threads)


def _canonical(
    refined: RefinedPoses, symmetry: Any, source_points: ArrayLike, num_threads: int | None
) -> RefinedPoses:
    """`refined` with its poses, kept and sliding, canonical under `symmetry` (checked; None:
    `refined` as it is)."""
    if symmetry is None:
        return refined

    def canonical(poses: np.ndarray) -> np.ndarray:
        if len(poses) == 0:
            return poses
        model = pp.as_points(source_points, "source_points")
        return canonical_for(symmetry, model, poses, num_threads)

    sliding = refined.sliding
    if sliding is not None:
        sliding = sliding._replace(transformations=canonical(sliding.transformations))
    return refined._replace(transformations=canonical(refined.transformations), sliding=sliding)


class RefinementContext:
    """:func:`refine_poses` in two stages, for many calls against one scan: what depends on
    the clouds alone (the scan's index and normals, the depth maps from `viewpoint`, the
    model's normals) is built here once, and :meth:`refine` takes the poses and the rules.
    Each :meth:`refine` returns what :func:`refine_poses` returns for the same arguments.

    Why: :func:`pointclm.register_point_clouds` refines against the same scan about six times
    per call (the first pass, each peeling round, the half-turned alternatives), and building
    that part cost about 6.5 ms of each call on one thread, against 3.3 ms per pose.
    """

    def __init__(
        self,
        source_points: ArrayLike,
        target_points: ArrayLike,
        voxel_size: float,
        *,
        viewpoint: ArrayLike | None = None,
        target_normals: ArrayLike | None = None,
        num_threads: int | None = None,
    ) -> None:
        src = pp.as_points(source_points, "source_points")
        target_points, target_normals = with_open3d_normals(target_points, target_normals)
        tgt = pp.as_points(target_points, "target_points")
        #: How many scan points the context indexes.
        self.target_size = len(tgt)
        self.voxel_size = pp.as_positive(voxel_size, "voxel_size")
        self.viewpoint = _as_viewpoint(viewpoint)
        normals = None if target_normals is None else pp.as_points(target_normals, "target_normals")
        self._core = _core.RefineContext(
            src,
            tgt,
            self.voxel_size,
            self.viewpoint,
            target_normals=normals,
            num_threads=as_threads(num_threads),
        )

    def rejections(
        self,
        transformations: ArrayLike,
        *,
        icp: bool = True,
        num_threads: int | None = None,
        **rules: float,
    ) -> list[Rejection]:
        """Why :meth:`refine` with the same arguments rejects each pose it does not keep, by
        input order (`rules` as :meth:`refine` takes them; the defaults otherwise)."""
        unknown = sorted(set(rules) - set(_RULES))
        if unknown:
            raise ValueError(f"unknown rule(s) {unknown}; the rules are {list(_RULES)}")
        rejected = self._judged(transformations, icp, rules, num_threads)[4]
        return [Rejection(*r) for r in rejected]

    def _judged(
        self,
        transformations: ArrayLike,
        icp: bool,
        rules: dict[str, float],
        num_threads: int | None,
    ) -> Any:
        """The core's refinement of `transformations` under `rules` (by name; the others at
        their defaults): its arrays, verdict and rejections, as it returns them."""
        return self._core.refine(
            _as_poses(transformations),
            pp.as_flag(icp, "icp"),
            {name: _number(v, name) for name, v in rules.items()},
            num_threads=as_threads(num_threads),
        )

    def near_shares(
        self,
        transformations: ArrayLike,
        points: ArrayLike,
        radius: float,
        *,
        num_threads: int | None = None,
    ) -> np.ndarray:
        """(K,) the share of `points` (N x 3, in the source's frame) that each of
        `transformations` (K x 4 x 4, T_target_source) puts strictly within `radius` of a
        target point: what a pose already holds before ICP."""
        return self._core.near_shares(
            _as_poses(transformations),
            pp.as_points(points, "points"),
            pp.as_positive(radius, "radius"),
            num_threads=as_threads(num_threads),
        )

    def refine(
        self,
        transformations: ArrayLike,
        *,
        icp: bool = True,
        min_visible_fitness: float = MIN_VISIBLE_FITNESS,
        max_contradiction: float = MAX_CONTRADICTION,
        min_seen: float = MIN_SEEN,
        min_fitness: float = MIN_FITNESS,
        min_relative_fitness: float = MIN_RELATIVE_FITNESS,
        max_shared: float = MAX_SHARED,
        max_slid_fitness: float = MAX_SLID_FITNESS,
        min_normal_agreement: float = MIN_NORMAL_AGREEMENT,
        num_threads: int | None = None,
    ) -> RefinedPoses:
        """:func:`refine_poses` of `transformations` against the context's clouds."""
        rules = (
            min_visible_fitness,
            max_contradiction,
            min_seen,
            min_fitness,
            min_relative_fitness,
            max_shared,
            max_slid_fitness,
            min_normal_agreement,
        )
        named = dict(zip(_RULES, rules, strict=True))
        mats, columns, origin, by_visibility, _, sliding = self._judged(
            transformations, icp, named, num_threads
        )
        kept = _refined_poses(mats, columns, origin, bool(by_visibility))
        s_mats, s_columns, s_origin = sliding
        return kept._replace(
            sliding=_refined_poses(s_mats, s_columns, s_origin, kept.by_visibility)
        )


def _refined_poses(
    mats: np.ndarray, columns: list[np.ndarray], origin: np.ndarray, by_visibility: bool
) -> RefinedPoses:
    """Poses from the core's arrays (its column order)."""
    confidence, fitness, visible, contradiction, seen, rmse, visible_rmse, slid = columns
    return RefinedPoses(
        mats,
        fitness,
        rmse,
        origin,
        confidence,
        visible,
        contradiction,
        seen,
        visible_rmse,
        by_visibility,
        slid_fitness=slid,
    )


class Rejection(NamedTuple):
    """Why verification did not keep a pose: the first rule it failed (a field of
    :func:`refine_poses`' rules, or ``"explains_nothing"``), its value and the threshold."""

    #: Index of the input pose.
    origin: int
    rule: str
    value: float
    threshold: float


#: The rules' names, in the order the core takes them.
_RULES = (
    "min_visible_fitness",
    "max_contradiction",
    "min_seen",
    "min_fitness",
    "min_relative_fitness",
    "max_shared",
    "max_slid_fitness",
    "min_normal_agreement",
)


def _as_poses(transformations: ArrayLike) -> np.ndarray:
    """(K, 4, 4) float64, C-contiguous; an empty input is no pose."""
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
    return np.ascontiguousarray(poses)


def _as_viewpoint(viewpoint: ArrayLike | None) -> tuple[float, float, float] | None:
    if viewpoint is None:
        return None
    v = np.asarray(viewpoint, dtype=np.float64)
    if v.shape != (3,) or not np.isfinite(v).all():
        raise ValueError(f"viewpoint must be 3 finite numbers, got {viewpoint!r}")
    return (float(v[0]), float(v[1]), float(v[2]))


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


def pose_stability(
    source_points: ArrayLike,
    source_normals: ArrayLike,
    target: Any,
    poses: ArrayLike,
    radius: float,
    *,
    num_threads: int | None = None,
    context: RefinementContext | None = None,
) -> np.ndarray:
    """How firmly the scan pins each pose (P x 4 x 4) down: the smallest over the largest
    eigenvalue of the point-to-plane ICP's 6 x 6 normal matrix (Gelfand et al. 2003,
    "Geometrically stable sampling for the ICP algorithm") over the posed model points within
    `radius` of a scan point, rotations taken about the posed model's centroid in units of the
    model's radius. 0 where fewer than six points are explained. Orientation of the normals
    does not matter. `target`: the scan's points (or a scipy k-d tree of them); `context`: a
    :class:`RefinementContext` of the same clouds to reuse its index of the scan.

    Why: a pose whose explained part is one flat face (a box on the bin's floor, or turned
    over on a copy's top face with the rest of it hidden) is free to slide and spin in that
    plane, and the scan cannot say where it is; a copy showing several faces or a curved side
    is pinned in every direction."""
    src = pp.as_points(source_points, "source_points")
    nrm = pp.as_points(source_normals, "source_normals")
    T = _as_poses(poses)
    if len(T) == 0:
        return np.zeros(0)
    if context is None:
        scan = pp.as_points(getattr(target, "data", target), "target")
        # The index's cells are the fitness radius (1.5 voxels): `radius` is that here.
        context = RefinementContext(src, scan, float(radius) / 1.5, num_threads=num_threads)
    return context._core.pose_stability(
        T, nrm, pp.as_positive(radius, "radius"), num_threads=as_threads(num_threads)
    )


# The turned alternatives of a pose and the scene-wide comparisons live in their own modules;
# these names stay reachable here.
from .flips import (  # noqa: E402, F401
    flip_turns,
    quarter_turns,
    resolve_flips,
)
from .scene_fit import fit_tightness, loose_poses, stability_factor  # noqa: E402, F401

"""The stage after poses when the clouds are at hand: ICP refinement and verification.

A pose fitted to a few descriptor matches is off by a few voxels and degrees, and realistic
scenes hold consistent groups of wrong matches that yield wrong poses. The clouds settle
both: ICP pulls each pose onto its copy, and the share of the model the scan then explains
(Open3D's ``fitness``) rejects poses over clutter and duplicates of one copy. With the
sensor's position, each pose is judged instead by what the sensor could see of the model at
that pose, so that copies hidden in part by others are kept (``benchmarks/verification.py``).

Acceptance rules of :func:`refine_poses`
----------------------------------------
With a viewpoint (the position of the sensor that took the scan, one view), each pose is
judged by what the sensor could see of the model at that pose: the posed model points not
hidden by the model itself or by the scan. A pose is kept when the scan explains at least
`min_visible_fitness` of them, at most `max_contradiction` of them lie where the sensor saw
through to something behind, and they are at least `min_seen` of the model. A partly hidden
copy is thus judged on its visible part. Without a viewpoint, or when more than 12 % of the
scan lies 5 voxels behind other scan points seen from it (a merged or wrongly placed scan),
the fallback is the share of the model explained: at least `min_fitness`, and at least
`min_relative_fitness` times the best pose's (``RefinedPoses.by_visibility`` says which rule
judged). A pose is a duplicate when more than `max_shared` of the scan points it explains are
explained by a surer pose. With or without a viewpoint, a pose is rejected when the model slid
along the surface it explains (by that surface's spread, both ways along its two main
directions) keeps more than `max_slid_fitness` of what it explains in place: a patch lying on a
larger surface of its shape (a face of a part on a table or a wall) fits anywhere on it, so
the fit does not say where the object is.

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
from .metrics import rotation_error_deg
from .registration import as_threads

__all__ = [
    "MAX_CONTRADICTION",
    "MAX_RELATIVE_VISIBLE_RMSE",
    "MAX_SHARED",
    "MAX_SLID_FITNESS",
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

#: With a viewpoint: a pose must explain at least this share of what the sensor could see of
#: the model at that pose.
MIN_VISIBLE_FITNESS = 0.85
#: With a viewpoint: at most this share of what the sensor could see of the model at a pose
#: may lie where the sensor saw free space (its first return clearly behind the surface).
#: Point-to-plane ICP settles a right pose on the surface, and model points the sensor would
#: see nearly edge-on (over 75 degrees) are not judged, so a right pose leaves almost none
#: (chosen on the validation models, see BENCHMARKS.md; 0.05 under point-to-point ICP).
MAX_CONTRADICTION = 0.01
#: With a viewpoint: the sensor must be able to see at least this share of the model at a
#: pose (below it there is too little to judge). On the validation bins the wrong poses that
#: passed were mostly buried ones, judged on a tenth to a quarter of the model: 0.05 -> 0.15
#: raised the ADD-S precision 0.976 -> 0.993 for 0.421 -> 0.414 recall; the realistic and
#: sparse-scan validation scenes were unchanged (stop 33, BENCHMARKS.md).
MIN_SEEN = 0.15
#: A pose whose model, slid along the surface it explains, keeps more than this share of it
#: is rejected (1: never). A patch of extent L slid by its spread (L / sqrt(12)) leaves its
#: own support with about 30 % of its points; a pose on a larger surface of its shape keeps
#: them all. On PCL's Kinect frame with its true viewpoint, the milk carton's wrong poses
#: (a face on the table) keep 0.96-0.99, its right pose 0.48-0.88; on the validation bins and
#: realistic scenes no right pose was lost (BENCHMARKS.md).
MAX_SLID_FITNESS = 0.9
#: With a viewpoint, a half turn of the model is tried by :func:`resolve_flips` only when at
#: least this share of the turned model lies farther than 1.5 voxels (the fitness radius) from
#: the model: below it the turn maps the model onto itself as far as verification can tell
#: (the elliptic cylinder and the capsule of the validation bins), so the scan cannot choose,
#: and switching would only follow noise. A bed turned end for end moves 1-4 % of it (the
#: headboard), and the sensor's free-space test tells which end it saw: 0.05 -> 0.01 found
#: 5 -> 8 of the 16 beds of the realistic validation scenes, the validation bins unchanged
#: (stop 33, BENCHMARKS.md).
MIN_FLIP_CHANGE = 0.01
#: :data:`MIN_FLIP_CHANGE` for poses judged without a viewpoint: the share of the model
#: explained cannot tell a change of a few percent from noise (at 0.01 the realistic
#: validation scenes without a viewpoint lost their 3 right beds of 16).
MIN_FLIP_CHANGE_BY_FITNESS = 0.05
#: A pose is a duplicate when more than this share of the scan points it explains are explained
#: by a surer pose (the default of ``max_shared``; also the rule by which peeling and
#: :func:`resolve_flips` tell a pose on another's copy).
MAX_SHARED = 0.5
#: A quarter turn of the model (either way about a principal axis) is tried by
#: :func:`resolve_flips` only when it leaves at least half of the model in place (moves at most
#: this share farther than 1.5 voxels from it): a near-symmetry, such as a bed or a box about
#: its vertical axis, where ICP settles the turned pose on the copy. A turn that moves more
#: poses the model visibly wrong, which ICP and verification handle without help.
MAX_QUARTER_TURN_CHANGE = 0.5
#: A turned alternative that is no surer by ``confidence`` still replaces a pose when it
#: explains more than this many times as many of the points that tell the two apart (each
#: one's model points that the other leaves where it has no surface), and more by
#: `FLIP_EVIDENCE_SIGMAS` standard deviations of a fair split. Why: a pose turned about a
#: near-symmetry turns the part that differs away from the sensor and explains all it still
#: shows, so its visible fitness matches the right pose's; only the part that differs can
#: choose. On the validation bins, the right turn explained 60-220 such points where the pose
#: explained 0-25, while a right pose's wrong turn gathered a few stray points of neighbouring
#: copies (stop 39, BENCHMARKS.md).
FLIP_EVIDENCE_RATIO = 4.0
#: See `FLIP_EVIDENCE_RATIO`: the alternative's count must exceed the pose's by this many
#: times the square root of their sum (a sign test at about three sigmas).
FLIP_EVIDENCE_SIGMAS = 3.0
#: :func:`resolve_flips` also tries the scene's own alternatives (``rotations``: in
#: ``register_point_clouds``, the rotations of the poses that peeling dropped as duplicates of
#: an accepted copy, relative to that copy's pose), grouped when within this many degrees of
#: each other: the registration benchmarks' rotation bound, within which two poses of a copy
#: count as the same. Why: the wrong poses left among the validation bins' first five were
#: turned about axes 8-41 degrees off every principal axis, which no principal-axis turn
#: reaches, while for 3 of those 5 poses a candidate of a peeling round had settled on the
#: same copy at the right rotation (BENCHMARKS.md, bins, stop 40).
SCENE_TURN_DEG = 15.0
#: At most this many of the scene's alternatives are tried, the most frequent first: as many
#: as the principal-axis half turns (each costs one ICP per pose).
MAX_SCENE_TURNS = 3
#: Without a viewpoint: poses explaining less of the model are rejected whatever the rest of
#: the scene holds.
MIN_FITNESS = 0.3
#: Without a viewpoint: poses explaining less than this share of the best pose's fitness are
#: rejected: copies of one object under one sensor are seen alike when none hides another.
#: Chosen on the realistic scenes of the training models (dragon, happy, bathtub; 0.7 / 0.8 /
#: 0.9 compared), checked on the validation models (armadillo, bed); never on the bunny.
MIN_RELATIVE_FITNESS = 0.8
#: With a viewpoint, across a scene's accepted poses (at least `MIN_POSES_TO_COMPARE`): a pose
#: whose visible side lies on the scan more loosely than this many times the median pose's
#: (``visible_rmse``) is dropped. Why: copies of one object in one scan are sampled by one
#: sensor, so right poses fit alike, while a model posed on clutter pairs its points with
#: surfaces of another shape and sits looser, though each pose alone passes the other rules.
#: Chosen on the validation sets only (stop 34, BENCHMARKS.md): right poses reached 1.12
#: times the median on the realistic validation scenes (with and without stray points) and
#: 1.33 in the validation bins (2 of 458 above 1.3), wrong poses far from any copy 1.15-1.76.
MAX_RELATIVE_VISIBLE_RMSE = 1.3
#: `MAX_RELATIVE_VISIBLE_RMSE` compares a pose with the scene's median only among this many
#: poses or more: with two, the median is their mean and says nothing about which is loose.
MIN_POSES_TO_COMPARE = 3

#: Scores only: `refine_poses` with these rejects nothing but duplicates (and keeps those
#: with ``max_shared=1``).
_KEEP_ALL: dict[str, Any] = {
    "min_fitness": 0.0,
    "min_relative_fitness": 0.0,
    "min_visible_fitness": 0.0,
    "max_contradiction": 1.0,
    "min_seen": 0.0,
    "max_slid_fitness": 1.0,
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
    target_normals: ArrayLike | None = None,
    num_threads: int | None = None,
) -> RefinedPoses:
    """Refine poses of `source_points` in `target_points` by point-to-plane ICP and keep
    those the scan supports, surest first.

    Parameters
    ----------
    source_points, target_points : (N, 3), (M, 3) array_like
        The model and the scan, downsampled at `voxel_size` (as
        :func:`pointclm.register_point_clouds` returns them).
    transformations : (K, 4, 4) array_like
        Candidate poses ``T_target_source``. A rotation block off by rounding
        (``||R^T R - I||_F <= 1e-3``, positive determinant) is replaced by the nearest
        rotation; anything farther from a rotation is a ValueError.
    voxel_size : float
        Sets the lengths: ICP at 3, 2 and 1.5 voxels, a model point explained within 1.5,
        depth cells of 1.5 voxels and one surface within 3 voxels along a ray.
    viewpoint : (3,) array_like, optional
        The position of the sensor that took `target_points` (one view): poses are then
        judged by what it could see of them (the module's acceptance rules), and ICP leaves
        out the model's far side from it (a scan does not hold it).
    icp : bool
        False: verification only, the poses are kept as given.
    min_visible_fitness, max_contradiction, min_seen, min_fitness, min_relative_fitness : float
        The acceptance rules, in [0, 1] (module documentation); all 0 (and `max_contradiction` 1):
        nothing is rejected but duplicates.
    max_shared : float in [0, 1]
        The share of a pose's explained scan points a surer pose may also explain before it
        is a duplicate; 1 keeps duplicates.
    max_slid_fitness : float in [0, 1]
        The share of what a pose explains that the model slid along that surface may keep
        (module documentation); 1 turns the test off.
    target_normals : (M, 3) array_like, optional
        Unit normals of `target_points` (either sign), e.g. those
        :func:`pointclm.register_point_clouds` computed; estimated within 2 voxels when
        omitted (pass them when refining against the same scan repeatedly).
    """
    clouds = (source_points, target_points, voxel_size)
    context = RefinementContext(
        *clouds, viewpoint=viewpoint, target_normals=target_normals, num_threads=num_threads
    )
    rules = (min_visible_fitness, max_contradiction, min_seen, min_fitness, min_relative_fitness)
    named = dict(zip(_RULES, (*rules, max_shared, max_slid_fitness), strict=True))
    return context.refine(transformations, icp=icp, num_threads=num_threads, **named)


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
        tgt = pp.as_points(target_points, "target_points")
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
        num_threads: int | None = None,
    ) -> RefinedPoses:
        """:func:`refine_poses` of `transformations` against the context's clouds."""
        rules = (
            min_visible_fitness,
            max_contradiction,
            min_seen,
            min_fitness,
            min_relative_fitness,
        )
        numbers: Any = [
            _number(v, name)
            for v, name in zip((*rules, max_shared, max_slid_fitness), _RULES, strict=True)
        ]
        core: Any = self._core  # the rules pass as one list, which the stub cannot count
        mats, columns, origin, by_visibility = core.refine(
            _as_poses(transformations),
            pp.as_flag(icp, "icp"),
            *numbers,
            num_threads=as_threads(num_threads),
        )
        confidence, fitness, visible, contradiction, seen, rmse, visible_rmse = columns
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
            bool(by_visibility),
        )


#: The rules' names, in the order the core takes them.
_RULES = (
    "min_visible_fitness",
    "max_contradiction",
    "min_seen",
    "min_fitness",
    "min_relative_fitness",
    "max_shared",
    "max_slid_fitness",
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


def flip_turns(
    source_points: ArrayLike, voxel_size: float, min_change: float = MIN_FLIP_CHANGE
) -> np.ndarray:
    """(F, 4, 4) half turns of the model about its principal axes through its centroid that
    verification can tell from the model itself (at least `min_change` of the turned model
    farther than 1.5 voxels from it, `MIN_FLIP_CHANGE`); F <= 3."""
    return _shape(source_points, voxel_size).half_turns(min_change)


def quarter_turns(
    source_points: ArrayLike,
    voxel_size: float,
    min_change: float = MIN_FLIP_CHANGE,
    max_change: float = MAX_QUARTER_TURN_CHANGE,
) -> np.ndarray:
    """(Q, 4, 4) quarter turns of the model, either way about its principal axes through its
    centroid, that move at least `min_change` and at most `max_change` of it farther than 1.5
    voxels from it (near-symmetries, `MAX_QUARTER_TURN_CHANGE`); Q <= 6."""
    return _shape(source_points, voxel_size).quarter_turns(min_change, max_change)


def _shape(source_points: ArrayLike, voxel_size: float) -> _Shape:
    src = pp.as_points(source_points, "source_points")
    return _Shape(src, pp.as_positive(voxel_size, "voxel_size"))


class _Shape:
    """A model's points, centroid, principal axes and k-d tree, to turn it and measure how
    much a turn moves."""

    def __init__(self, src: np.ndarray, voxel: float) -> None:
        from scipy.spatial import cKDTree

        self.src, self.radius = src, 1.5 * float(voxel)
        self.centre = src.mean(0)
        _, axes = np.linalg.eigh(np.cov((src - self.centre).T))
        self.axes = axes.T
        self.tree = cKDTree(src)

    def turns(self, by_visibility: bool, rotations: np.ndarray) -> tuple[np.ndarray, int]:
        """:func:`resolve_flips`' turns (half turns first, then quarter turns, then the
        scene's own from `rotations`) and how many are half turns."""
        # Judged by the share of the model alone, a small change is not told from noise.
        min_change = MIN_FLIP_CHANGE if by_visibility else MIN_FLIP_CHANGE_BY_FITNESS
        half = self.half_turns(min_change)
        turns = np.concatenate([half, self.quarter_turns(min_change, MAX_QUARTER_TURN_CHANGE)])
        scene = self.scene_turns(rotations, turns, min_change)
        return np.concatenate([turns, scene]), len(half)

    def half_turns(self, min_change: float) -> np.ndarray:
        """:func:`flip_turns`."""
        return self._kept([2.0 * np.outer(a, a) - np.eye(3) for a in self.axes], min_change)

    def quarter_turns(self, min_change: float, max_change: float) -> np.ndarray:
        """:func:`quarter_turns`."""
        rotations = []
        for a in self.axes:
            cross = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
            rotations += [np.eye(3) + way * cross + cross @ cross for way in (1.0, -1.0)]
        return self._kept(rotations, min_change, max_change)

    def scene_turns(
        self, rotations: np.ndarray, tried: np.ndarray, min_change: float
    ) -> np.ndarray:
        """:func:`resolve_flips`' turns from `rotations` (3 x 3 each): grouped within
        `SCENE_TURN_DEG` degrees (each joins the first group whose first rotation is that near),
        groups within it of the identity or of a turn already `tried` left out, the
        `MAX_SCENE_TURNS` largest kept (ties: the first found), each moving at least
        `min_change` of the model."""
        known = np.concatenate([np.eye(3)[None], tried[:, :3, :3]])
        groups: list[list[np.ndarray]] = []
        for rot in rotations:
            if (rotation_error_deg(known, rot) < SCENE_TURN_DEG).any():
                continue
            home = next((g for g in groups if rotation_error_deg(g[0], rot) < SCENE_TURN_DEG), None)
            if home is None:
                groups.append([rot])
            else:
                home.append(rot)
        groups.sort(key=len, reverse=True)  # stable: ties keep the order found
        return self._kept([g[0] for g in groups[:MAX_SCENE_TURNS]], min_change)

    def _kept(
        self, rotations: list[np.ndarray], min_change: float, max_change: float = 1.0
    ) -> np.ndarray:
        """The rigid motions rotating by `rotations` about the centroid that move from
        `min_change` to `max_change` of the model farther than 1.5 voxels from it."""
        kept = []
        for rot in rotations:
            turn = np.eye(4)
            turn[:3, :3], turn[:3, 3] = rot, self.centre - rot @ self.centre
            dist, _ = self.tree.query(self.src @ rot.T + turn[:3, 3])
            if min_change <= float(np.mean(dist > self.radius)) <= max_change:
                kept.append(turn)
        return np.array(kept).reshape(-1, 4, 4)


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
    """
    shape = _shape(source_points, voxel_size)
    turns, half = shape.turns(poses.by_visibility, _as_rotations(rotations))
    n = len(poses.transformations)
    if n == 0 or len(turns) == 0:
        return poses, np.arange(n)
    candidates = np.einsum("pij,fjk->pfik", poses.transformations, turns).reshape(-1, 4, 4)
    if context is None:
        context = RefinementContext(
            shape.src,
            target_points,
            voxel_size,
            viewpoint=viewpoint,
            target_normals=target_normals,
            num_threads=num_threads,
        )
    alt = _scored(context, candidates, num_threads)
    evidence = _TurnEvidence(shape, pp.as_points(target_points, "target_points"))
    fields, turned = _with_better_turns(poses, alt, len(turns), half, evidence)
    _undo_turns_onto_other_copies(poses, fields, turned, evidence)
    order = np.argsort(-fields["confidence"], kind="stable")
    return poses._replace(**{f: v[order] for f, v in fields.items()}), order


def _scored(
    context: RefinementContext, candidates: np.ndarray, num_threads: int | None
) -> RefinedPoses:
    """Every candidate refined by ICP and scored, none rejected."""
    return context.refine(candidates, **_KEEP_ALL, max_shared=1.0, num_threads=num_threads)


class _TurnEvidence:
    """Which of two poses of one copy the points that tell them apart support."""

    def __init__(self, shape: _Shape, target: np.ndarray) -> None:
        from scipy.spatial import cKDTree

        self.src, self.radius, self.model = shape.src, shape.radius, shape.tree
        self.scan = cKDTree(target)

    def explained(self, pose: np.ndarray) -> np.ndarray:
        return explained_scan_points(self.scan, self.src, pose, self.radius)

    def _near(self, tree: Any, points: np.ndarray) -> np.ndarray:
        dist, _ = tree.query(points, distance_upper_bound=self.radius)
        return np.isfinite(dist)

    def hits(self, first: np.ndarray, second: np.ndarray) -> tuple[int, int]:
        """How many of the points that tell two poses of the model apart (4 x 4,
        T_target_source) the scan explains for each: the model points `first` puts where
        `second` has no surface, and the other way round."""
        rel = np.linalg.solve(first, second)  # second = first @ rel, in the model's frame
        rot, shift = rel[:3, :3], rel[:3, 3]
        # The first pose's own points lie off the model as the second poses it (rel^-1 p off
        # the model); the second's, rel q off the model.
        only_first = ~self._near(self.model, (self.src - shift) @ rot)
        only_second = ~self._near(self.model, self.src @ rot.T + shift)
        own, other = (
            int(self._near(self.scan, self.src[only] @ pose[:3, :3].T + pose[:3, 3]).sum())
            for only, pose in ((only_first, first), (only_second, second))
        )
        return own, other


def explained_scan_points(
    scan_tree: Any, source: np.ndarray, pose: np.ndarray, radius: float
) -> np.ndarray:
    """The scan points (indices into `scan_tree`'s, distinct) within `radius` of `source` at
    `pose` (4 x 4, T_target_source): what a pose explains, as verification counts it at 1.5
    voxels."""
    dist, idx = scan_tree.query(source @ pose[:3, :3].T + pose[:3, 3], distance_upper_bound=radius)
    return np.unique(idx[np.isfinite(dist)])


def _decisive(more: int, fewer: int) -> bool:
    """Whether `more` explained points that tell two poses apart decide against `fewer`
    (`FLIP_EVIDENCE_RATIO`, `FLIP_EVIDENCE_SIGMAS`)."""
    return more > FLIP_EVIDENCE_RATIO * fewer and more - fewer > FLIP_EVIDENCE_SIGMAS * np.sqrt(
        more + fewer
    )


def _with_better_turns(
    poses: RefinedPoses, alt: RefinedPoses, turns: int, half: int, evidence: _TurnEvidence
) -> tuple[dict[str, Any], list[int]]:
    """The fields of `poses`, each pose's row taken from its best alternative of `alt`
    (`turns` per pose, pose-major, the first `half` of them half turns) by
    :func:`resolve_flips`'s rule: the surest half turn that is surer, else the turn the points
    that tell it from the pose favour most decisively, and the rows replaced. A pose no turn
    replaces has its confidence divided by one plus the number of its turns that could have
    (eligible) and that those points do not rule out. A candidate `alt` did not return cannot
    win."""
    n = len(poses.transformations)
    fields = {f: getattr(poses, f).copy() for f in RefinedPoses._fields if f != "by_visibility"}
    turned: list[int] = []
    if len(alt.origin) == 0:
        return fields, turned
    row_of = np.full(n * turns, -1, dtype=np.int64)
    row_of[np.asarray(alt.origin, dtype=np.int64)] = np.arange(len(alt.origin))
    found = row_of >= 0

    def pick(values: np.ndarray) -> np.ndarray:
        return np.where(found, values[row_of], np.nan).reshape(n, turns)

    conf, fit = pick(alt.confidence), pick(alt.fitness)
    as_much = fit >= poses.fitness[:, None]
    # The alternative must explain as much of the model and pass verification itself.
    eligible = as_much.copy()
    if poses.by_visibility:
        eligible &= (pick(alt.visible_fitness) >= MIN_VISIBLE_FITNESS) & (
            pick(alt.contradiction) <= MAX_CONTRADICTION
        )
    surer = (conf > poses.confidence[:, None]) & as_much
    surer[:, half:] = False
    for i in range(n):
        if surer[i].any():
            t = int(np.argmax(np.where(surer[i], conf[i], -np.inf)))
        else:
            hits = {
                int(t): evidence.hits(
                    poses.transformations[i], alt.transformations[row_of[i * turns + t]]
                )
                for t in np.flatnonzero(eligible[i])
            }
            margins = {t: other - own for t, (own, other) in hits.items() if _decisive(other, own)}
            if not margins:
                # The pose is one of as many hypotheses as the turns it cannot rule out.
                undecided = sum(not _decisive(own, other) for own, other in hits.values())
                fields["confidence"][i] /= 1 + undecided
                continue
            t = max(margins, key=lambda u: margins[u])
        _set_row(fields, i, alt, row_of[i * turns + t])
        turned.append(i)
    return fields, turned


def _undo_turns_onto_other_copies(
    poses: RefinedPoses, fields: dict[str, Any], turned: list[int], evidence: _TurnEvidence
) -> None:
    """Put back, in `fields`, each turned row whose turn carried it onto another pose's copy:
    its turned pose shares more than half of the scan points it explains with the other poses
    (the ``max_shared`` rule of verification), and more than the pose did. Such a turn is ICP
    settling on a neighbour, not an alternative for this copy."""
    if not turned:
        return
    explained = [evidence.explained(pose) for pose in fields["transformations"]]
    count = np.zeros(len(evidence.scan.data), dtype=np.int64)
    for points in explained:
        count[points] += 1
    for i in turned:
        count[explained[i]] -= 1  # the other poses' points alone
        before = evidence.explained(poses.transformations[i])
        shared = [(count[p] > 0).mean() if len(p) else 1.0 for p in (explained[i], before)]
        if shared[0] > MAX_SHARED and shared[0] > shared[1]:
            _set_row(fields, i, poses, i)
            explained[i] = before
        count[explained[i]] += 1


def _set_row(fields: dict[str, Any], i: int, source: RefinedPoses, j: int) -> None:
    """Row `i` of `fields` (all but ``origin``) taken from row `j` of `source`."""
    for f in fields:
        if f != "origin":
            fields[f][i] = getattr(source, f)[j]


def loose_poses(
    visible_rmse: ArrayLike, max_relative: float = MAX_RELATIVE_VISIBLE_RMSE
) -> np.ndarray:
    """Which of a scene's poses fit the scan loosely against the others: ``visible_rmse``
    (`RefinedPoses.visible_rmse`) above `max_relative` times its median over the poses where
    it is known. None among fewer than `MIN_POSES_TO_COMPARE` known values (see
    `MAX_RELATIVE_VISIBLE_RMSE` for why)."""
    return _relative_to_median(visible_rmse) > float(max_relative)  # NaN: False


def fit_tightness(visible_rmse: ArrayLike) -> np.ndarray:
    """Each pose's factor of sureness from how tightly its visible side lies on the scan
    against the scene's median pose: ``min(1, median / visible_rmse)``, 1 where unknown or
    among fewer than `MIN_POSES_TO_COMPARE` known values. `register_point_clouds` multiplies
    ``confidence`` by it, after :func:`loose_poses` dropped the loosest.

    Why: visible fitness saturates near 1 for every copy a heap shows well, so it cannot order
    them, while a pose turned a little about a near-symmetry (a Buddha 17 degrees about its
    axis, a bed end for end) still pairs its points with its copy's surface, a little looser
    than the right poses of the same scan do (`MAX_RELATIVE_VISIBLE_RMSE` says why they fit
    alike). On the 72 validation bins, wrong poses sat at a median 1.15 times the scene's
    median and right ones at 1.0; the first five were all right in 71 scenes with the factor
    at any power from 0.5 to 4 against 69 without it (BENCHMARKS.md, stop 44)."""
    with np.errstate(divide="ignore"):  # exactly 0 against a positive median: 1
        return _at_most_one(1.0 / _relative_to_median(visible_rmse))


def pose_stability(
    source_points: np.ndarray,
    source_normals: np.ndarray,
    scan_tree: Any,
    poses: np.ndarray,
    radius: float,
    workers: int = 1,
) -> np.ndarray:
    """How firmly the scan pins each pose (P x 4 x 4) down: the smallest over the largest
    eigenvalue of the point-to-plane ICP's 6 x 6 normal matrix (Gelfand et al. 2003,
    "Geometrically stable sampling for the ICP algorithm") over the posed model points within
    `radius` of a scan point, rotations taken about the posed model's centroid in units of the
    model's radius. 0 where fewer than six points are explained. Orientation of the normals
    does not matter. `workers`: scipy's, for the one query of every posed point.

    Why: a pose whose explained part is one flat face (a box on the bin's floor, or turned
    over on a copy's top face with the rest of it hidden) is free to slide and spin in that
    plane, and the scan cannot say where it is; a copy showing several faces or a curved side
    is pinned in every direction."""
    pts = np.asarray(source_points, dtype=np.float64)
    nrm = np.asarray(source_normals, dtype=np.float64)
    T = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    out = np.zeros(len(T))
    if len(T) == 0 or len(pts) == 0:
        return out
    centre = pts.mean(axis=0)
    scale = float(np.linalg.norm(pts - centre, axis=1).max()) or 1.0
    posed = np.einsum("pij,sj->psi", T[:, :3, :3], pts) + T[:, None, :3, 3]
    dist, _ = scan_tree.query(posed.reshape(-1, 3), distance_upper_bound=radius, workers=workers)
    hits = np.isfinite(dist).reshape(len(T), len(pts))
    for i in np.flatnonzero(hits.sum(axis=1) >= 6):
        n = nrm[hits[i]] @ T[i, :3, :3].T
        arm = (posed[i, hits[i]] - (T[i, :3, :3] @ centre + T[i, :3, 3])) / scale
        rows = np.hstack([np.cross(arm, n), n])
        eig = np.linalg.eigvalsh(rows.T @ rows)
        out[i] = eig[0] / eig[-1] if eig[-1] > 0 else 0.0
    return out


def stability_factor(stability: ArrayLike) -> np.ndarray:
    """Each pose's factor of sureness from :func:`pose_stability` against the scene's median
    pose: ``min(1, stability / median)``, 1 where unknown (NaN) or among fewer than
    `MIN_POSES_TO_COMPARE` known values. `register_point_clouds` multiplies ``confidence`` by
    it, with :func:`fit_tightness`.

    Why relative: copies of one part show the scan alike, so a right pose is pinned about as
    firmly as the scene's median copy, whatever the part's shape; a pose resting on one face of
    a copy or of the bin is pinned less. On the validation bins (seeds 12-23 of the six
    validation models, where it was chosen) the first five were all right in 71 of 72 scenes
    against 68 with :func:`fit_tightness` alone, at any power from 0.25 to 1; on seeds 0-11,
    71 as before (box 10's pose on a sixth of a copy mended, a turn of box 8 that ADD-S
    forgives broken); on 36 scenes of procedural parts, re-ranked offline, 36 against 35
    (BENCHMARKS.md, stop 44)."""
    return _at_most_one(_relative_to_median(stability))


def _at_most_one(ratio: np.ndarray) -> np.ndarray:
    """``min(1, ratio)``, and 1 where `ratio` is NaN (nothing to compare with)."""
    return np.where(np.isnan(ratio), 1.0, np.minimum(1.0, ratio))


def _relative_to_median(values: ArrayLike) -> np.ndarray:
    """`values` over their median among the finite ones; NaN where not finite, and everywhere
    among fewer than `MIN_POSES_TO_COMPARE` finite values."""
    x = np.asarray(values, dtype=np.float64).reshape(-1)
    known = np.isfinite(x)
    if known.sum() < MIN_POSES_TO_COMPARE:
        return np.full(len(x), np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):  # a median of 0: inf, or NaN for 0
        return np.where(known, x / float(np.median(x[known])), np.nan)

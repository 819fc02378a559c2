"""Turned alternatives of verified poses: a part close to a symmetry is often posed turned, and
the few discrete hypotheses (half turns about the model's principal axes, quarter turns about
those that leave most of it in place, and the scene's own alternatives) are refined and scored
like the pose, the one the scan supports best kept (:func:`resolve_flips`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from pointclm import _core
from pointclm import preprocessing as pp
from pointclm.metrics import rotation_error_deg
from pointclm.refinement import (
    _KEEP_ALL,
    MAX_CONTRADICTION,
    MAX_QUARTER_TURN_CHANGE,
    MAX_SHARED,
    MIN_FLIP_CHANGE,
    MIN_VISIBLE_FITNESS,
    RefinedPoses,
    RefinementContext,
)
from pointclm.scene_rules import SCENE_DEFAULTS, SceneRules

__all__ = ["flip_turns", "quarter_turns", "resolve_flips"]


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


def _shape(
    source_points: ArrayLike, voxel_size: float, scene: SceneRules = SCENE_DEFAULTS
) -> _Shape:
    src = pp.as_points(source_points, "source_points")
    return _Shape(src, pp.as_positive(voxel_size, "voxel_size"), scene)


class _Shape:
    """A model's points, centroid, principal axes and k-d tree, to turn it and measure how
    much a turn moves."""

    def __init__(self, src: np.ndarray, voxel: float, scene: SceneRules = SCENE_DEFAULTS) -> None:
        from scipy.spatial import cKDTree

        self.src, self.radius, self.scene = src, 1.5 * float(voxel), scene
        self.centre = src.mean(0)
        _, axes = np.linalg.eigh(np.cov((src - self.centre).T))
        axes = axes.T
        lead = np.argmax(np.abs(axes) > 1e-6, axis=1)
        self.axes = axes * np.sign(axes[np.arange(3), lead])[:, None]
        self.tree = cKDTree(src)

    def turns(self, by_visibility: bool, rotations: np.ndarray) -> tuple[np.ndarray, int]:
        """:func:`resolve_flips`' turns (half turns first, then quarter turns, then the
        scene's own from `rotations`) and how many are half turns."""
        # Judged by the share of the model alone, a small change is not told from noise.
        sc = self.scene
        min_change = sc.min_flip_change if by_visibility else sc.min_flip_change_by_fitness
        half = self.half_turns(min_change)
        turns = np.concatenate([half, self.quarter_turns(min_change, sc.max_quarter_turn_change)])
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
            if (rotation_error_deg(known, rot) < self.scene.scene_turn_deg).any():
                continue
            near = self.scene.scene_turn_deg
            home = next((g for g in groups if rotation_error_deg(g[0], rot) < near), None)
            if home is None:
                groups.append([rot])
            else:
                home.append(rot)
        groups.sort(key=len, reverse=True)  # stable: ties keep the order found
        return self._kept([g[0] for g in groups[: self.scene.max_scene_turns]], min_change)

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
    shape = _shape(source_points, voxel_size, SceneRules.resolve(scene))
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
    evidence = _TurnEvidence(shape, context)
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
    """Which of two poses of one copy the points that tell them apart support, counted on the
    scan's index of a :class:`RefinementContext` (given, or built on `scan` points)."""

    def __init__(self, shape: _Shape, scan: RefinementContext | ArrayLike) -> None:
        self.src, self.radius, self.model = shape.src, shape.radius, shape.tree
        self.scene = shape.scene
        if not isinstance(scan, RefinementContext):
            # The context's index is gridded at the fitness radius, this radius.
            scan = RefinementContext(shape.src, scan, shape.radius / 1.5)
        self.scan = scan._core
        self.scan_size = scan.target_size

    def explained(self, pose: np.ndarray) -> np.ndarray:
        return self.scan.explained_scan_points(pose[None], self.radius)

    def _near_model(self, points: np.ndarray) -> np.ndarray:
        dist, _ = self.model.query(points, distance_upper_bound=self.radius)
        return np.isfinite(dist)

    def _near_scan(self, points: np.ndarray) -> np.ndarray:
        if len(points) == 0:
            return np.zeros(0, dtype=bool)
        return self.scan.near_mask(np.ascontiguousarray(points), self.radius)

    def hits(self, first: np.ndarray, second: np.ndarray) -> tuple[int, int]:
        """How many of the points that tell two poses of the model apart (4 x 4,
        T_target_source) the scan explains for each: the model points `first` puts where
        `second` has no surface, and the other way round."""
        rel = np.linalg.solve(first, second)  # second = first @ rel, in the model's frame
        rot, shift = rel[:3, :3], rel[:3, 3]
        # The first pose's own points lie off the model as the second poses it (rel^-1 p off
        # the model); the second's, rel q off the model.
        only_first = ~self._near_model((self.src - shift) @ rot)
        only_second = ~self._near_model(self.src @ rot.T + shift)
        own, other = (
            int(self._near_scan(self.src[only] @ pose[:3, :3].T + pose[:3, 3]).sum())
            for only, pose in ((only_first, first), (only_second, second))
        )
        return own, other


def _decisive(more: int, fewer: int, scene: SceneRules = SCENE_DEFAULTS) -> bool:
    """Whether `more` explained points that tell two poses apart decide against `fewer`
    (`FLIP_EVIDENCE_RATIO`, `FLIP_EVIDENCE_SIGMAS`)."""
    ratio, sigmas = scene.flip_evidence_ratio, scene.flip_evidence_sigmas
    return more > ratio * fewer and more - fewer > sigmas * np.sqrt(more + fewer)


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
            sc = evidence.scene
            margins = {
                t: other - own for t, (own, other) in hits.items() if _decisive(other, own, sc)
            }
            if not margins:
                # The pose is one of as many hypotheses as the turns it cannot rule out.
                undecided = sum(not _decisive(own, other, sc) for own, other in hits.values())
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
    count = np.zeros(evidence.scan_size, dtype=np.int64)
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

"""Peeling: further passes over the scan points no accepted copy explains, each matched,
registered, voted on in a heap, refined and verified against the accepted copies, until a
round adds no copy."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from .. import _core
from .. import preprocessing as pp
from .._core import RegistrationResult
from ..config import Config
from ..refinement import (
    MAX_SHARED,
    RefinedPoses,
)
from ..registration import as_threads, register
from ..scene_rules import SCENE_DEFAULTS, SceneRules
from .results import Pass
from .run import _match, _Run
from .verification import _merge, _take


def unexplained_points(
    target_points: np.ndarray,
    source_points: np.ndarray,
    transformations: np.ndarray,
    radius: float,
    *,
    num_threads: int | None = None,
) -> np.ndarray:
    """Mask of the target points farther than `radius` from every posed source point, searched
    on `num_threads` threads (None: every core)."""
    poses = np.asarray(transformations, dtype=np.float64).reshape(-1, 4, 4)
    return _core.unexplained_points(
        pp.as_points(target_points, "target_points"),
        pp.as_points(source_points, "source_points"),
        np.ascontiguousarray(poses),
        radius,
        num_threads=as_threads(num_threads),
    )


def _unexplained(run: _Run, transformations: np.ndarray) -> np.ndarray:
    """Mask of the scan points no copy at `transformations` explains (within
    `PEEL_RADIUS_VOXELS`)."""
    radius = run.scene.peel_radius_voxels * run.voxel
    return unexplained_points(
        run.tgt_d.points, run.src_d.points, transformations, radius, num_threads=run.num_threads
    )


def _peel(
    run: _Run,
    refined: RefinedPoses,
    tags: list[tuple[int, int]],
    passes: list[Pass],
    cfg: Config,
) -> tuple[RefinedPoses, list[tuple[int, int]]]:
    """Peeling rounds: match the scan points no accepted copy explains, register them, refine
    the new poses and verify them together with the accepted ones; stop when a round adds no
    copy. Once the passes match as in a heap (:func:`_is_heap`: `_Run.heap_matching`), peeling
    stops only after `HEAP_EMPTY_ROUNDS` such rounds in a row.

    Why: in a heap of identical parts, the copies accepted first hold most of the mutual
    descriptor matches and of the sampled correspondences, so the others keep too few true
    matches to form a cluster. Once their points are set aside, the next copies' points become
    mutual best matches and fill the sample. Each round's poses are verified on the whole scan,
    so a pose that slides onto an accepted copy is a duplicate and is dropped.
    """
    unexplained = _unexplained(run, refined.transformations)
    empty = 0  # rounds in a row that added no copy
    for round_ in range(1, run.scene.max_peel_rounds + 1):
        # Judged before every round on the copies accepted so far.
        matching = run.heap_matching if _is_heap(run, tags) else run.matching
        free = np.flatnonzero(unexplained)
        if len(free) < 3:
            break
        step = _peel_round(run, refined, tags, cfg, round_, free, matching, unexplained)
        if step is None:
            break
        refined, tags, unexplained, done = step
        passes.append(done)
        empty = 0 if done.added else empty + 1
        if empty >= (run.scene.heap_empty_rounds if matching is run.heap_matching else 1):
            break
    return refined, tags


def _is_heap(run: _Run, tags: list[tuple[int, int]]) -> bool:
    """Whether a pass matches as in a heap: the user said the scan is one (``heap=True``:
    every pass), or the copies accepted before it show one (`HEAP_MIN_COPIES`)."""
    if run.heap_matching is None:
        return False
    return bool(run.heap) or len(tags) >= run.scene.heap_min_copies


def _peel_round(
    run: _Run,
    refined: RefinedPoses,
    tags: list[tuple[int, int]],
    cfg: Config,
    round_: int,
    free: np.ndarray,
    matching: dict[str, Any] | None,
    unexplained: np.ndarray,
) -> tuple[RefinedPoses, list[tuple[int, int]], np.ndarray, Pass] | None:
    """One peeling round over the scan points `free`, matched with `matching`: the accepted
    poses, tags and unexplained mask after it, and its pass; None when matching leaves fewer
    than 3 correspondences."""
    stage = _clustered_and_voted(run, cfg, round_, free, matching)
    if stage is None:
        return None
    corr, result, voted = stage
    reach = _within_reach(run, voted, refined)
    candidates = np.concatenate(
        [np.asarray(result.transformations).reshape(-1, 4, 4), voted[reach]]
    )
    new = run.refiner.refine(candidates, max_shared=1.0, num_threads=run.num_threads)
    # A voted pose's origin names its row of `voted` (past len(result)), screened or not.
    rows = np.concatenate([np.arange(len(result)), len(result) + reach])
    new = _without_weak_votes(
        new._replace(origin=rows[new.origin]), len(result), refined, run.scene
    )
    duplicates = np.empty((0, 4, 4))
    if len(new.origin) and new.by_visibility and refined.by_visibility:
        refined, tags, duplicates = _add_seen(run, refined, tags, new, round_, unexplained)
    elif len(new.origin):
        refined, tags = _reverify(run, refined, tags, new, round_)
        # Re-verification may also drop accepted poses: recompute what is explained.
        unexplained = _unexplained(run, refined.transformations)
    added = sum(t[0] == round_ for t in tags)  # the copies this round added
    return refined, tags, unexplained, Pass(corr, result, free, added, voted, duplicates)


def _clustered_and_voted(
    run: _Run, cfg: Config, round_: int, free: np.ndarray, matching: dict[str, Any] | None
) -> tuple[np.ndarray, RegistrationResult, np.ndarray] | None:
    """A peeling round's candidates over the scan points `free`: its correspondences and
    their registration, and the poses voted by point pairs when the round matches as in a
    heap (else none); None when matching leaves fewer than 3 correspondences.

    Why voting runs on a second Python thread: it does not depend on the round's clusters,
    and their spectral clustering (the eigenvectors, the k-means seedings) runs on one
    thread, so voting keeps the pool's other threads busy meanwhile. Both calls share the
    core's pool for `run.num_threads`, and each gives the same result however its work is
    scheduled."""
    seed = run.seed + round_
    heap_round = run.heap and matching is run.heap_matching
    with ThreadPoolExecutor(max_workers=1) as beside:
        votes = beside.submit(run.voted_poses, free, round_) if heap_round else None
        corr, pair_normals, sims = _match(run, free, seed, matching)
        if len(corr) < 3:
            return None
        features = run.features(corr, cfg, pair_normals, sims)
        result = register(
            corr, features, cfg, seed, num_threads=run.num_threads, normals=pair_normals
        )
        # Voted poses follow the clusters' (tags past len(result) name them).
        voted = np.empty((0, 4, 4)) if votes is None else votes.result()
    return corr, result, voted


def _within_reach(run: _Run, voted: np.ndarray, accepted: RefinedPoses) -> np.ndarray:
    """Rows of `voted` worth refining: those that, as voted, already bring
    `VOTED_MIN_RELATIVE_FITNESS` times the median accepted copy's share of the model within
    ICP's first radius (3 voxels) of the scan; every row while no copy is accepted.

    Why: ICP moves a pose by a few voxels and degrees, within radii of 3 down to 1.5 voxels,
    so a pose must hold loosely before it what :func:`_without_weak_votes` asks of its result
    at 1.5 voxels. Refining a pose costs about as much as voting for all of them. On the
    validation bins this left out 44 % of the voted poses (85 % on the dragon) and 8 % of the
    time, for the same accepted copies but a few (ADD-S recall 0.885 -> 0.884; BENCHMARKS.md,
    bins)."""
    rows = np.arange(len(voted))
    if len(voted) == 0 or len(accepted.fitness) == 0:
        return rows
    model = run.src_d.points[:: -(-len(run.src_d.points) // run.scene.screen_points)]
    near = run.refiner.near_shares(voted, model, 3.0 * run.voxel, num_threads=run.num_threads)
    return rows[near >= _vote_floor(accepted.fitness, run.scene)]


def _without_weak_votes(
    new: RefinedPoses, clustered: int, accepted: RefinedPoses, scene: SceneRules = SCENE_DEFAULTS
) -> RefinedPoses:
    """`new` without the voted poses (origin at or past `clustered`) that explain less of the
    model than `VOTED_MIN_RELATIVE_FITNESS` times the median accepted copy (the copies
    accepted before this round and this round's clustered ones; with none, the best voted)."""
    voted = new.origin >= clustered
    if not voted.any():
        return new
    peers = np.concatenate([accepted.fitness, new.fitness[~voted]])
    floor = _vote_floor(peers if len(peers) else new.fitness[voted].max(keepdims=True), scene)
    return _take(new, np.flatnonzero(~voted | (new.fitness >= floor)))


def _vote_floor(fitness: np.ndarray, scene: SceneRules = SCENE_DEFAULTS) -> float:
    """The share of the model a voted pose must explain: `VOTED_MIN_RELATIVE_FITNESS` (the
    scene's ``voted_min_relative_fitness``) times the median of the copies' `fitness`."""
    return scene.voted_min_relative_fitness * float(np.median(fitness))


def _add_seen(
    run: _Run,
    refined: RefinedPoses,
    tags: list[tuple[int, int]],
    new: RefinedPoses,
    round_: int,
    unexplained: np.ndarray,
) -> tuple[RefinedPoses, list[tuple[int, int]], np.ndarray]:
    """A round's poses judged by visibility joined to the accepted ones: such a verdict does
    not depend on the other poses, so only duplicates of accepted copies are dropped, then
    the lists are merged; and the dropped duplicates' poses. The new copies' points leave
    `unexplained` (in place)."""
    keep, _ = run.refiner._core.not_duplicates(
        new.transformations,
        1.5 * run.voxel,
        MAX_SHARED,
        ~unexplained,
        num_threads=as_threads(run.num_threads),
    )
    duplicates = np.delete(new.transformations, keep, axis=0)
    if not keep:
        return refined, tags, duplicates
    kept = _take(new, keep)
    refined, tags = _merge(refined, tags, kept, [(round_, int(new.origin[i])) for i in keep])
    # The accepted set only grew: the new copies' points join the explained ones.
    unexplained &= _unexplained(run, kept.transformations)
    return refined, tags, duplicates


def _reverify(
    run: _Run,
    refined: RefinedPoses,
    tags: list[tuple[int, int]],
    new: RefinedPoses,
    round_: int,
) -> tuple[RefinedPoses, list[tuple[int, int]]]:
    """Accepted and new poses verified together (without visibility a pose's verdict
    depends on the best fitness among them)."""
    pool = np.concatenate([refined.transformations, new.transformations])
    pool_tags = tags + [(round_, int(o)) for o in new.origin]
    both = run.refiner.refine(pool, icp=False, num_threads=run.num_threads)
    return both, [pool_tags[int(o)] for o in both.origin]

"""Verification of the first pass's poses (and of a guessed viewpoint), and the bookkeeping of
verified poses: taking rows, merging lists, the instances returned."""

from __future__ import annotations

from dataclasses import replace
from typing import Any, NamedTuple

import numpy as np

from .._core import Instance, RegistrationResult
from ..covariance import PoseCovariances, pose_covariances
from ..refinement import (
    _KEEP_ALL,
    RefinedPoses,
)
from .results import CloudInstance, Pass
from .run import _Run


class Verified(NamedTuple):
    """Pass 0's poses as verification left them, and the run that goes on."""

    #: The run, its viewpoint settled (a guess confirmed, or dropped).
    run: _Run
    #: The verified poses, surest first.
    poses: RefinedPoses
    #: Each pose's (pass, instance of that pass's result).
    tags: list[tuple[int, int]]


def _verify(run: _Run, result: RegistrationResult, refine: bool) -> Verified:
    """Pass 0's poses refined and verified (or, without `refine`, only scored, in the
    correspondence stage's order), each with its (pass, instance of that pass's result), and
    the run that goes on (:func:`_confirm_viewpoint` settles a guessed viewpoint)."""
    if run.guessed_viewpoint and refine:
        return _confirm_viewpoint(run, result)
    refined = run.refiner.refine(
        np.asarray(result.transformations).reshape(-1, 4, 4),
        icp=refine,
        **({} if refine else {**_KEEP_ALL, "max_shared": 1.0}),
        num_threads=run.num_threads,
    )
    tags = [(0, int(o)) for o in refined.origin]
    if not refine:
        # Unverified poses keep the correspondence stage's order (most inliers first).
        keep = np.argsort(refined.origin)
        refined, tags = _take(refined, keep), [tags[i] for i in keep]
    return Verified(run, refined, tags)


def _confirm_viewpoint(run: _Run, result: RegistrationResult) -> Verified:
    """Pass 0 of a run whose viewpoint is a guess (the origin of a scan in its sensor's
    frame, or the sensor position estimated from the scan): the run with it, when verification
    from there keeps the pose that the model share ranks first, else the run without a
    viewpoint; pass 0's poses verified accordingly.

    Why: a scan looks like one view from many points near its sensor (at most 12 % of it
    hidden from there), which is enough to orient normals but not to judge poses, where 1 %
    of a model in free space rejects them. A Stanford range scan 0.06-0.19 m from the origin
    looks like one view from it, and every pose fails there; a depth camera's frame keeps
    its surest copy. An estimate 10 degrees off costs about a twentieth of the realistic F1,
    20 degrees a fifth (BENCHMARKS.md). ICP does not depend on the viewpoint, so the
    poses are refined once and judged both ways."""
    blind_run = replace(run, viewpoint=None, guessed_viewpoint=False, unconfirmed=run.viewpoint)
    fitted = blind_run.refiner.refine(
        np.asarray(result.transformations).reshape(-1, 4, 4),
        **_KEEP_ALL,
        max_shared=1.0,
        num_threads=run.num_threads,
    )
    # Back in the input order, so that both verdicts break ties as one refinement would.
    order = np.argsort(fitted.origin, kind="stable")
    poses, source = fitted.transformations[order], fitted.origin[order]
    seen, seen_tags = _judge(run, poses, source)
    blind, blind_tags = _judge(blind_run, poses, source)
    kept = set(seen.origin.tolist())
    if kept and (len(blind.origin) == 0 or int(blind.origin[0]) in kept):
        return Verified(run, seen, seen_tags)
    # Nothing either way confirms nothing: the run goes on (and explains) without a viewpoint.
    return Verified(blind_run, blind, blind_tags)


def _judge(
    run: _Run, poses: np.ndarray, source: np.ndarray
) -> tuple[RefinedPoses, list[tuple[int, int]]]:
    """Pass 0's poses, refined already (`source`: the correspondence stage's instance of each),
    verified by the run's rules without ICP."""
    judged = run.refiner.refine(poses, icp=False, num_threads=run.num_threads)
    judged = judged._replace(origin=source[judged.origin])
    return judged, [(0, int(o)) for o in judged.origin]


def _instances(
    refined: RefinedPoses,
    tags: list[tuple[int, int]],
    passes: list[Pass],
    covariances: PoseCovariances | None = None,
) -> list[CloudInstance]:
    def matches(tag: tuple[int, int]) -> Instance | None:
        found = passes[tag[0]].result
        return found.instances[tag[1]] if tag[1] < len(found) else None

    return [
        CloudInstance(
            refined.transformations[i],
            float(refined.fitness[i]),
            float(refined.inlier_rmse[i]),
            matches(tags[i]),
            float(refined.confidence[i]),
            float(refined.visible_fitness[i]),
            float(refined.contradiction[i]),
            tags[i][0],
            float(refined.visible_rmse[i]),
            *_covariance_of(covariances, i),
        )
        for i in range(len(tags))
    ]


def _covariances(run: _Run, refined: RefinedPoses) -> PoseCovariances:
    """Each final pose's information and covariance, once, against the run's scan."""
    return pose_covariances(
        run.src_d.points,
        run.tgt_d.points,
        refined.transformations,
        run.voxel,
        num_threads=run.num_threads,
        context=run.refiner,
    )


def _covariance_of(
    covariances: PoseCovariances | None, i: int
) -> tuple[np.ndarray | None, np.ndarray | None, int]:
    if covariances is None:
        return None, None, 0
    return (
        covariances.information[i],
        covariances.covariance[i],
        int(covariances.unobservable[i]),
    )


#: The per-pose columns of `RefinedPoses`.
_COLUMNS = [f for f in RefinedPoses._fields if f not in ("by_visibility", "sliding")]


def _column(poses: RefinedPoses, name: str) -> np.ndarray:
    """A column of `poses` (NaN where not known)."""
    value = getattr(poses, name)
    return np.full(len(poses.origin), np.nan) if value is None else value


def _take(poses: RefinedPoses, rows: list[int] | np.ndarray) -> RefinedPoses:
    idx = np.asarray(rows, dtype=np.int64)
    return poses._replace(**{f: _column(poses, f)[idx] for f in _COLUMNS}, sliding=None)


def _merge(
    a: RefinedPoses, a_tags: list[tuple[int, int]], b: RefinedPoses, b_tags: list[tuple[int, int]]
) -> tuple[RefinedPoses, list[tuple[int, int]]]:
    """Two lists of verified poses as one, surest first (`a` first among equals)."""
    joined: dict[str, Any] = {f: np.concatenate([_column(a, f), _column(b, f)]) for f in _COLUMNS}
    both = a._replace(**joined)
    order = np.argsort(-both.confidence, kind="stable")
    tags = a_tags + b_tags
    return _take(both, order), [tags[i] for i in order]

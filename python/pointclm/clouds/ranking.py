"""The scene's accepted poses, final: turned alternatives resolved, copies that fit loosely
against the others dropped, the rest ranked by how sure each is."""

from __future__ import annotations

import numpy as np

from ..refinement import (
    RefinedPoses,
    fit_tightness,
    loose_poses,
    pose_stability,
    resolve_flips,
    stability_factor,
)
from .results import Pass
from .run import _Run
from .verification import _take


def _settle(
    run: _Run,
    refined: RefinedPoses,
    tags: list[tuple[int, int]],
    flips: bool,
    passes: list[Pass],
) -> tuple[RefinedPoses, list[tuple[int, int]]]:
    """The scene's accepted poses, final: half turns resolved (if asked), then, when the
    sensor judged them, those that fit loosely against the others dropped
    (:func:`pointclm.refinement.loose_poses`) and the rest made less sure the looser they fit
    (:func:`pointclm.refinement.fit_tightness`) and the less firmly the scan pins them down
    (:func:`pointclm.refinement.stability_factor`) than the median, surest first. Why only at
    the end: the comparison needs every copy the scan shows, and peeling needs the dropped poses'
    scan points explained."""
    if flips and len(tags):
        refined, tags = _resolve_flips(run, refined, tags, _duplicate_turns(run, refined, passes))
    if not refined.by_visibility:
        return refined, tags
    sc = run.scene
    compare = sc.min_poses_to_compare
    loose = loose_poses(refined.visible_rmse, sc.max_relative_visible_rmse, compare)
    keep = np.flatnonzero(~loose)
    refined, tags = _take(refined, keep), [tags[int(i)] for i in keep]
    stability = pose_stability(
        run.src_d.points,
        run.src_d.normals,
        run.tgt_d.points,
        refined.transformations,
        1.5 * run.voxel,
        num_threads=run.num_threads,
        context=run.refiner,
    )
    tight = fit_tightness(refined.visible_rmse, compare)
    sureness = tight * stability_factor(stability, compare)
    refined = refined._replace(confidence=refined.confidence * sureness)
    order = np.argsort(-refined.confidence, kind="stable")
    return _take(refined, order), [tags[int(i)] for i in order]


def _duplicate_turns(run: _Run, refined: RefinedPoses, passes: list[Pass]) -> np.ndarray:
    """(D, 3, 3) each duplicate the passes dropped (``Pass.duplicates``), as a rotation of the
    model relative to the accepted pose whose copy it lies on (the nearest by the posed
    model's centroid)."""
    duplicates = np.concatenate([p.duplicates for p in passes]).reshape(-1, 4, 4)
    accepted = refined.transformations
    if len(duplicates) == 0 or len(accepted) == 0:
        return np.empty((0, 3, 3))
    centre = run.src_d.points.mean(0)
    homes = accepted[:, :3, :3] @ centre + accepted[:, :3, 3]
    posed = duplicates[:, :3, :3] @ centre + duplicates[:, :3, 3]
    home = np.argmin(np.linalg.norm(posed[:, None] - homes[None], axis=2), axis=1)
    # R_home^T R_duplicate: the duplicate's rotation in the home pose's model frame.
    return accepted[home, :3, :3].transpose(0, 2, 1) @ duplicates[:, :3, :3]


def _resolve_flips(
    run: _Run, refined: RefinedPoses, tags: list[tuple[int, int]], rotations: np.ndarray
) -> tuple[RefinedPoses, list[tuple[int, int]]]:
    """The accepted poses with half-turned alternatives the scan supports better
    (:func:`pointclm.refinement.resolve_flips`), surest first."""
    flipped, order = resolve_flips(
        run.src_d.points,
        run.tgt_d.points,
        refined,
        run.voxel,
        viewpoint=run.viewpoint,
        target_normals=run.tgt_d.normals,
        num_threads=run.num_threads,
        context=run.refiner,
        rotations=rotations,
        scene=run.scene,
    )
    return flipped, [tags[int(i)] for i in order]

"""Why a result is empty or doubtful, and what to try."""

from __future__ import annotations

import numpy as np

from ..refinement import (
    _KEEP_ALL,
    MAX_CONTRADICTION,
    MIN_FITNESS,
    MIN_SEEN,
    MIN_VISIBLE_FITNESS,
    RefinedPoses,
)
from .results import Pass, _xyz
from .run import _Run


def _diagnose(run: _Run, refined: RefinedPoses, passes: list[Pass], refine: bool) -> str:
    """Why the result is empty or doubtful, and what to try; "" when there is nothing to say."""
    first = passes[0]
    no_view = "" if run.viewpoint is not None else _no_viewpoint(run.unconfirmed)
    if len(refined.origin) and run.viewpoint is not None and refine and not refined.by_visibility:
        return (
            f"the scan does not look like one view from the viewpoint {_xyz(run.viewpoint)} "
            "(too much of it lies behind other scan points seen from there), so poses were "
            "judged by the share of the model they explain; if that is not where the sensor "
            "stood, pass its position, or viewpoint=None to orient the normals without one."
        )
    if len(refined.origin):
        return ""
    if len(first.result) == 0:
        return (
            f"nothing found: no consistent group among the {len(first.correspondences)} "
            "descriptor correspondences, so no candidate pose. The scan may not hold the "
            f"model, or its local shapes differ at voxel {run.voxel:.3g}: try a smaller "
            "voxel_size, mutual=False or n_samples=None." + no_view
        )
    return _rejected(run, first) + no_view


def _rejected(run: _Run, first: Pass) -> str:
    """Why verification rejected every candidate pose: the best one's scores against the
    rules (one more ICP of the candidates, only when nothing was found)."""
    scores = run.refiner.refine(
        np.asarray(first.result.transformations).reshape(-1, 4, 4),
        **_KEEP_ALL,
        max_shared=1.0,
        num_threads=run.num_threads,
    )
    n = len(first.result)
    head = f"nothing found: verification rejected all {n} candidate pose(s)"
    if not scores.by_visibility:
        best = float(scores.fitness.max()) if len(scores.fitness) else 0.0
        return (
            f"{head}: the best explains {best:.0%} of the model (needs {MIN_FITNESS:.0%}). "
            "A partial or occluded view explains little of a model."
        )
    i = int(np.argmax(scores.confidence))
    return (
        f"{head} as seen from the viewpoint {_xyz(run.viewpoint or (0, 0, 0))}: the best "
        f"explains {scores.visible_fitness[i]:.0%} of what the sensor could see of it (needs "
        f"{MIN_VISIBLE_FITNESS:.0%}), {scores.contradiction[i]:.0%} of it lies where the "
        f"sensor saw free space (at most {MAX_CONTRADICTION:.0%}), and the sensor could see "
        f"{scores.seen[i]:.0%} of the model (needs {MIN_SEEN:.0%}). If that is not where the "
        "sensor stood, pass its position, or viewpoint=None to orient the normals without one."
    )


def _no_viewpoint(unconfirmed: tuple[float, float, float] | None) -> str:
    """What to say of a run judged without a viewpoint: how the normals were oriented, and how
    to know the sensor's position."""
    how = (
        " The scan's normals were oriented without a sensor position"
        if unconfirmed is None
        else f" The scan's normals face {_xyz(unconfirmed)}, a guess of the sensor's position "
        "that verification from there did not confirm, so poses were judged without one"
    )
    return (
        how + ": if you know where the sensor stood, pass viewpoint= (its position in the "
        "scan's coordinates: the origin for a scan still in its sensor's frame, else the "
        "position from the calibration or pose log)."
    )

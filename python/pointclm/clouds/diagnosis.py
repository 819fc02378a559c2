"""Why a result is empty or doubtful, and what to try."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from ..refinement import RefinementContext
from .results import Pass, _xyz


class _Judged(Protocol):
    """What a diagnosis needs of a run: where the poses were judged from, at what voxel, and
    the refinement context to ask again why each candidate was rejected."""

    @property
    def viewpoint(self) -> tuple[float, float, float] | None: ...
    @property
    def unconfirmed(self) -> tuple[float, float, float] | None: ...
    @property
    def voxel(self) -> float: ...
    @property
    def num_threads(self) -> int | None: ...
    @property
    def refiner(self) -> RefinementContext: ...


def _diagnose(run: _Judged, found: int, by_visibility: bool, passes: list[Pass]) -> str:
    """Why the result is empty or doubtful, and what to try; "" when there is nothing to say.
    `found` copies were accepted, judged by the sensor when `by_visibility`."""
    first = passes[0]
    no_view = "" if run.viewpoint is not None else _no_viewpoint(run.unconfirmed)
    if found:
        return ""
    if len(first.result) == 0:
        return (
            f"nothing found: no consistent group among the {len(first.correspondences)} "
            "descriptor correspondences, so no candidate pose. The scan may not hold the "
            f"model, or its local shapes differ at voxel {run.voxel:.3g}: try a smaller "
            "voxel_size, mutual=False or n_samples=None." + no_view
        )
    return _rejected(run, first) + no_view


#: How each rule reads in a diagnosis: what its value measures, and how it compares.
_RULE_WORDS = {
    "min_seen": ("the share of the model the sensor could see", "needs at least"),
    "min_visible_fitness": ("the share of what the sensor could see that the scan explains",
                            "needs at least"),
    "max_contradiction": ("the share of it lying where the sensor saw free space", "at most"),
    "min_fitness": ("the share of the model explained", "needs at least"),
    "min_relative_fitness": ("the share of the model explained, against the best pose's",
                             "needs at least"),
    "max_slid_fitness": ("the share still explained with the model slid along its surface "
                         "(it fits anywhere on a larger surface)", "at most"),
    "max_shared": ("the share of its scan points a surer pose explains", "at most"),
    "explains_nothing": ("the scan points it explains", "needs at least"),
}  # fmt: skip


def _rejected(run: _Judged, first: Pass) -> str:
    """Why verification rejected every candidate pose: for each rule that rejected some, how
    many and the nearest miss, its value against the threshold (one more ICP of the
    candidates, only when nothing was found)."""
    poses = np.asarray(first.result.transformations).reshape(-1, 4, 4)
    rejected = run.refiner.rejections(poses, num_threads=run.num_threads)
    n = len(first.result)
    by_rule: dict[str, list[tuple[float, float]]] = {}
    for r in rejected:
        by_rule.setdefault(r.rule, []).append((r.value, r.threshold))
    parts = []
    for rule, values in sorted(by_rule.items(), key=lambda kv: -len(kv[1])):
        what, compare = _RULE_WORDS.get(rule, (rule, "against"))
        ceiling = compare == "at most"
        value, threshold = (min if ceiling else max)(values, key=lambda vt: vt[0])
        parts.append(
            f"{len(values)} by {rule} ({what}: nearest {value:.0%}, {compare} {threshold:.0%})"
        )
    judged = (
        f" as seen from the viewpoint {_xyz(run.viewpoint or (0, 0, 0))}"
        if run.viewpoint is not None
        else ""
    )
    tail = (
        " If that is not where the sensor stood, pass its position, or viewpoint=None to "
        "orient the normals without one."
        if run.viewpoint is not None
        else " A partial or occluded view explains little of a model."
    )
    return f"nothing found: verification rejected all {n} candidate pose(s){judged}: " + (
        "; ".join(parts) + "." + tail
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

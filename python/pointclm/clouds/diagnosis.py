"""Why a result is empty or doubtful, and what to try."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Protocol

import numpy as np

from ..refinement import _RULE_DEFAULTS, RefinementContext, Rejection
from ..registration import MIN_CORRESPONDENCES
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
    @property
    def face_proposals(self) -> bool: ...


def _diagnose(run: _Judged, found: int, by_visibility: bool, passes: list[Pass]) -> str:
    """Why the result is empty or doubtful, and what to try; "" when there is nothing to say.
    `found` copies were accepted, judged by the sensor when `by_visibility`."""
    first = passes[0]
    no_view = "" if run.viewpoint is not None else _no_viewpoint(run.unconfirmed)
    if found:
        return ""
    matches = len(first.correspondences) if first.matches is None else first.matches
    if matches < MIN_CORRESPONDENCES:
        return _too_few_matches(run, matches, len(first.faces)) + no_view
    if len(first.result) == 0:
        return (
            f"nothing found: no consistent group among the {len(first.correspondences)} "
            "descriptor correspondences, so no candidate pose. The scan may not hold the "
            f"model, or its local shapes differ at voxel {run.voxel:.3g}: try a smaller "
            "voxel_size, mutual=False or n_samples=None." + no_view
        )
    return _rejected(run, first) + no_view


def _too_few_matches(run: _Judged, matches: int, faces: int) -> str:
    """Why nothing was found when matching left too few pairs for a pose: the descriptors
    proposed nothing, and what became of the face proposals (which need no matches)."""
    if not run.face_proposals:
        tried = ""
        boxes = ", or proposals='faces' for a part made of large flat faces (a box)"
    elif faces:
        tried = f"; verification rejected all {faces} pose(s) laying a model face on the scan"
        boxes = ""
    else:
        tried = "; no planar patch of the scan took a model face"
        boxes = ""
    return (
        f"nothing found: only {matches} descriptor match(es) survived matching "
        f"({MIN_CORRESPONDENCES} needed for a pose), so the descriptors proposed no pose"
        f"{tried}. The scan may not hold the model, or its local shapes differ at voxel "
        f"{run.voxel:.3g} (a flat or featureless scan looks the same everywhere): try a "
        f"smaller voxel_size or mutual=False{boxes}."
    )


#: How each rule reads in a diagnosis: what its value measures (short, then in words), and
#: whether its threshold is a ceiling (the value must stay at or below it) or a floor.
_RULE_WORDS = {
    "min_seen": ("seen", "the share of the model the sensor could see", False),
    "min_visible_fitness": ("visible fitness", "the share of what the sensor could see that "
                            "the scan explains", False),
    "max_contradiction": ("contradiction", "the share of what the sensor could see lying "
                          "where it saw free space", True),
    "min_fitness": ("fitness", "the share of the model explained", False),
    "min_relative_fitness": ("fitness", "the share of the model explained, against the best "
                             "candidate's", False),
    "max_slid_fitness": ("slid fitness", "the share still explained with the model slid along "
                         "its surface: it fits anywhere on a larger surface; these come back "
                         "under ambiguous", True),
    "min_normal_agreement": ("normal agreement", "the share of the explained model points whose "
                             "surface is turned like the scan's: a model cut by a surface "
                             "meets it across", False),
    "max_shared": ("shared", "the share of its scan points a surer candidate explains", True),
    "explains_nothing": ("scan points explained", "a pose explaining no scan point", False),
}  # fmt: skip

#: Candidates a diagnosis names one by one (at least the nearest miss of every rule).
LISTED_MISSES = 3


def _fails(rule: str, value: float, threshold: float) -> bool:
    """Whether `value` misses `threshold` as `rule` compares them (NaN misses every rule)."""
    ceiling = _RULE_WORDS.get(rule, ("", "", False))[2]
    return not (value <= threshold if ceiling else value >= threshold)


def _pair(value: float, threshold: float, ceiling: bool) -> tuple[str, str]:
    """`value` and `threshold` with the fewest decimals (2 to 6) at which the printed value
    still misses the printed threshold: a rounding never reads as a pass."""
    for digits in (2, 3, 4, 6):
        v, t = f"{value:.{digits}f}", f"{threshold:.{digits}f}"
        if (float(v) > float(t)) if ceiling else (float(v) < float(t)):
            return v, t
    return repr(float(value)), repr(float(threshold))


def miss_text(rule: str, value: float, threshold: float, rules: Mapping[str, float]) -> str:
    """One rejection as a diagnosis names it: the measured value against the threshold and the
    rule, e.g. ``visible fitness 0.21 < 0.30 (min_visible_fitness)``."""
    short, _, ceiling = _RULE_WORDS.get(rule, (rule, rule, False))
    if rule == "explains_nothing":
        return "explains no scan point (explains_nothing: a pose must explain at least one)"
    if math.isnan(value):
        bound = "<=" if ceiling else ">="
        return f"{short} not measurable ({rule} needs {bound} {threshold:.2f})"
    v, t = _pair(value, threshold, ceiling)
    text = f"{short} {v} {'>' if ceiling else '<'} {t} ({rule}"
    share = rules.get(rule)
    if rule == "min_relative_fitness" and share:
        text += f": {share:g} x the best candidate's fitness {threshold / share:.3f}"
    return text + ")"


def explain_rejections(
    rejections: Sequence[Rejection], candidates: int, rules: Mapping[str, float] | None = None
) -> str:
    """Why verification rejected `candidates` candidate poses (`rejections`: the core's
    verdicts, :meth:`pointclm.RefinementContext.rejections`, under `rules`, by name; the
    defaults otherwise): how many each rule rejected, then the nearest misses one by one
    (candidate ``k`` is the correspondence stage's instance ``k``), each with its measured
    value, the threshold and the rule. A verdict whose value does not miss its threshold is
    never quoted as a reason."""
    rules = {**_RULE_DEFAULTS, **(rules or {})}
    missed = [r for r in rejections if _fails(r.rule, r.value, r.threshold)]
    by_rule: dict[str, list[Rejection]] = {}
    for r in missed:
        by_rule.setdefault(r.rule, []).append(r)
    ranked = sorted(by_rule.items(), key=lambda kv: -len(kv[1]))
    counts = ", ".join(
        f"{len(rs)} by {rule} ({_RULE_WORDS.get(rule, (rule, rule, False))[1]})"
        for rule, rs in ranked
    )
    listed = [min(rs, key=_gap) for _, rs in ranked]
    rest = sorted((r for r in missed if r not in listed), key=_gap)
    listed += rest[: max(0, LISTED_MISSES - len(listed))]
    misses = "; ".join(
        f"candidate {r.origin}, {miss_text(r.rule, r.value, r.threshold, rules)}" for r in listed
    )
    nearest = "the nearest miss" if len(listed) == 1 else "the nearest misses"
    return f"{counts}. {nearest.capitalize()}: {misses}." if listed else ""


def _gap(r: Rejection) -> float:
    """How far a rejection's value is from its threshold (NaN: farthest)."""
    gap = abs(r.value - r.threshold)
    return math.inf if math.isnan(gap) or r.rule == "explains_nothing" else gap


def _rejected(run: _Judged, first: Pass) -> str:
    """Why verification rejected every candidate pose (one more ICP of the candidates, only
    when nothing was found): `explain_rejections` of the core's verdicts."""
    poses = np.asarray(first.result.transformations).reshape(-1, 4, 4)
    rejected = run.refiner.rejections(poses, num_threads=run.num_threads)
    n = len(first.result)
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
    why = explain_rejections(rejected, n)
    return (
        f"nothing found: verification rejected all {n} candidate pose(s){judged}"
        + (f": {why}" if why else ".")
        + tail
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

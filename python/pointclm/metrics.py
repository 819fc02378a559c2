"""Multi-instance registration metrics: the paper's any-match scores and a strict F1.

Why two scores: the PointCLM authors count a prediction as correct if it matches *any* ground
truth instance, so duplicate predictions of one instance all count as correct (SPEC section 3).
Their MR / MP / MF are reproduced here for comparison with the paper, next to a strict score
where each ground-truth instance can be claimed by one prediction only (maximum bipartite
matching), which duplicates cannot inflate.

A prediction matches a ground-truth pose if the rotation error
``RE = arccos((tr(R^T R*) - 1) / 2) < 15 deg`` and the translation error ``TE = ||t - t*|| < 0.1``
(synthetic units). For a part with proper symmetries ``S`` (4 x 4 transforms with
``model = S model``, the BOP ``symmetries_discrete``, and rotations about its
``symmetries_continuous`` axes), every ``T* @ S`` is the same pose: pass ``symmetries=``
((S, 4, 4) transforms, a :class:`pointclm.symmetry.Symmetry` or a ``models_info`` entry) and
the errors are the smallest over them, so every equivalent pose scores the same
(:func:`symmetric_errors`, :func:`add_s`).

Conventions for empty scenes (both scores):

- no predictions and no ground truth: P = R = 1 (nothing to find, nothing claimed);
- no predictions, some ground truth: P = 0, R = 0 (as the authors' evaluation);
- no ground truth, some predictions: P = 0, R = 1 (every prediction is false; nothing missed);
- F1 = 2 P R / (P + R), and 0 when P + R = 0.

Only numpy is needed (the matching is Kuhn's augmenting-path algorithm, not scipy's).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .pose_errors import (
    _as_poses,
    _equivalent_errors,
    add_s,
    rotation_error_deg,
    symmetric_errors,
    translation_error,
)

__all__ = [
    "SceneScore",
    "add_s",
    "Summary",
    "max_bipartite_matching",
    "pose_match_matrix",
    "rotation_error_deg",
    "score_scene",
    "summarize",
    "symmetric_errors",
    "translation_error",
]


def pose_match_matrix(
    pred: ArrayLike,
    gt: ArrayLike,
    max_rotation_deg: float = 15.0,
    max_translation: float = 0.1,
    *,
    symmetries: Any = None,
) -> np.ndarray:
    """Which predictions register which ground-truth instances.

    Parameters
    ----------
    pred : array_like
        (P, 4, 4) predicted ``T_target_source`` (a list of 4x4 arrays is fine).
    gt : array_like
        (G, 4, 4) ground-truth poses.
    max_rotation_deg, max_translation : float
        Strict thresholds: a match needs ``RE < max_rotation_deg`` and ``TE < max_translation``.
    symmetries : optional
        The source's proper symmetries (as :func:`symmetric_errors` takes them): a
        prediction matches when it matches any truth made equivalent by one.

    Returns
    -------
    numpy.ndarray
        (P, G) bool.
    """
    re, te = _equivalent_errors(_as_poses(pred), _as_poses(gt), symmetries)
    return np.asarray(((re < max_rotation_deg) & (te < max_translation)).any(axis=-1))


def max_bipartite_matching(adjacency: ArrayLike) -> np.ndarray:
    """Maximum-cardinality matching of rows to columns (Kuhn's augmenting paths).

    Parameters
    ----------
    adjacency : numpy.ndarray
        (P, G) bool; ``adjacency[i, j]`` if row i may be matched to column j.

    Returns
    -------
    numpy.ndarray
        (P,) int64: the column matched to each row, or -1.

    Notes
    -----
    O(P * E), ample for the few instances of a scene.
    """
    adj = np.asarray(adjacency, dtype=bool)
    n_rows, n_cols = adj.shape
    neighbours = [np.flatnonzero(row) for row in adj]
    col_owner = np.full(n_cols, -1, dtype=np.int64)

    def augment(i: int, seen: np.ndarray) -> bool:
        for j in neighbours[i]:
            if not seen[j]:
                seen[j] = True
                if col_owner[j] < 0 or augment(int(col_owner[j]), seen):
                    col_owner[j] = i
                    return True
        return False

    for i in range(n_rows):
        augment(i, np.zeros(n_cols, dtype=bool))
    match = np.full(n_rows, -1, dtype=np.int64)
    owned = np.flatnonzero(col_owner >= 0)
    match[col_owner[owned]] = owned
    return match


def _f1(p: float, r: float) -> float:
    return 0.0 if p + r == 0 else 2.0 * p * r / (p + r)


def _pr(n_correct_pred: int, n_recalled: int, n_pred: int, n_gt: int) -> tuple[float, float]:
    """Precision and recall with the module's empty-scene conventions."""
    if n_pred == 0:
        return (1.0, 1.0) if n_gt == 0 else (0.0, 0.0)
    precision = n_correct_pred / n_pred
    recall = 1.0 if n_gt == 0 else n_recalled / n_gt
    return precision, recall


@dataclass(frozen=True)
class SceneScore:
    """Scores of one scene.

    Attributes
    ----------
    n_pred, n_gt : int
        Numbers of predicted and ground-truth instances.
    precision, recall : float
        Paper ("any-match"): predictions matching any GT / predictions, and GT matched by any
        prediction / GT.
    strict_precision, strict_recall, strict_f1 : float
        One-to-one: matched pairs of a maximum bipartite matching / predictions, / GT, and F1.
    n_matched : int
        Size of that matching.
    """

    n_pred: int
    n_gt: int
    precision: float
    recall: float
    strict_precision: float
    strict_recall: float
    strict_f1: float
    n_matched: int

    @property
    def f1(self) -> float:
        """Per-scene F1 of the any-match precision and recall."""
        return _f1(self.precision, self.recall)


def score_scene(
    pred: ArrayLike,
    gt: ArrayLike,
    max_rotation_deg: float = 15.0,
    max_translation: float = 0.1,
    *,
    symmetries: ArrayLike | None = None,
) -> SceneScore:
    """Score the predicted poses of one scene against its ground truth.

    Parameters
    ----------
    pred : array_like
        (P, 4, 4) predicted poses (a list of 4x4 arrays, possibly empty, is fine).
    gt : array_like
        (G, 4, 4) ground-truth poses.
    max_rotation_deg, max_translation : float
        Match thresholds (15 degrees, 0.1 in synthetic units).
    symmetries : array_like, optional
        (S, 4, 4) proper symmetries of the source (:func:`pose_match_matrix`).

    Returns
    -------
    SceneScore
        Any-match and strict scores, with the module's empty-scene conventions.
    """
    match = pose_match_matrix(pred, gt, max_rotation_deg, max_translation, symmetries=symmetries)
    n_pred, n_gt = match.shape
    precision, recall = _pr(
        int(match.any(axis=1).sum()), int(match.any(axis=0).sum()), n_pred, n_gt
    )
    n_matched = int((max_bipartite_matching(match) >= 0).sum())
    s_precision, s_recall = _pr(n_matched, n_matched, n_pred, n_gt)
    return SceneScore(
        n_pred=n_pred,
        n_gt=n_gt,
        precision=precision,
        recall=recall,
        strict_precision=s_precision,
        strict_recall=s_recall,
        strict_f1=_f1(s_precision, s_recall),
        n_matched=n_matched,
    )


@dataclass(frozen=True)
class Summary:
    """Scores over a set of scenes.

    Attributes
    ----------
    mean_recall, mean_precision : float
        MR and MP: means of the per-scene any-match recall and precision (paper).
    mean_f1 : float
        MF = 2 MP MR / (MP + MR), from the means, as the paper computes it.
    strict_f1 : float
        Mean of the per-scene strict F1.
    strict_precision, strict_recall : float
        Means of the per-scene strict precision and recall.
    n_scenes : int
        Number of scenes.
    """

    mean_recall: float
    mean_precision: float
    mean_f1: float
    strict_f1: float
    strict_precision: float
    strict_recall: float
    n_scenes: int

    def as_dict(self) -> dict[str, float | int]:
        """Fields as a plain dict (e.g. for JSON)."""
        return asdict(self)

    @staticmethod
    def table_header() -> str:
        """Header line matching :meth:`as_row`."""
        cells = " ".join(f"{c:>6}" for c in ("MR", "MP", "MF", "sF1", "sP", "sR"))
        return f"{'method':<24} {cells} {'n':>5}"

    def as_row(self, name: str = "") -> str:
        """One table line, scores in percent like the paper's tables."""
        vals = (
            self.mean_recall,
            self.mean_precision,
            self.mean_f1,
            self.strict_f1,
            self.strict_precision,
            self.strict_recall,
        )
        cells = " ".join(f"{100 * v:6.2f}" for v in vals)
        return f"{name:<24} {cells} {self.n_scenes:5d}"

    def __str__(self) -> str:
        return (
            f"MR {100 * self.mean_recall:.2f}  MP {100 * self.mean_precision:.2f}  "
            f"MF {100 * self.mean_f1:.2f}  strict F1 {100 * self.strict_f1:.2f} "
            f"(P {100 * self.strict_precision:.2f}, R {100 * self.strict_recall:.2f}) "
            f"over {self.n_scenes} scenes"
        )


def summarize(scores: Iterable[SceneScore]) -> Summary:
    """Aggregate per-scene scores into the paper's MR / MP / MF and the strict F1.

    Parameters
    ----------
    scores : iterable of SceneScore
        At least one scene.

    Returns
    -------
    Summary

    Raises
    ------
    ValueError
        If there is no scene.
    """
    items = list(scores)
    if not items:
        raise ValueError("summarize needs at least one scene")

    def mean(attr: str) -> float:
        return float(np.mean([getattr(s, attr) for s in items]))

    mp, mr = mean("precision"), mean("recall")
    return Summary(
        mean_recall=mr,
        mean_precision=mp,
        mean_f1=_f1(mp, mr),
        strict_f1=mean("strict_f1"),
        strict_precision=mean("strict_precision"),
        strict_recall=mean("strict_recall"),
        n_scenes=len(items),
    )

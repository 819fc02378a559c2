"""Tests of the registration metrics (paper any-match scores and strict one-to-one F1)."""

from __future__ import annotations

import numpy as np
import pytest
from pointclm.metrics import (
    SceneScore,
    Summary,
    max_bipartite_matching,
    pose_match_matrix,
    rotation_error_deg,
    score_scene,
    summarize,
    translation_error,
)


def rot_z(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def pose(deg: float = 0.0, t: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = rot_z(deg)
    out[:3, 3] = t
    return out


def test_rotation_and_translation_errors() -> None:
    assert rotation_error_deg(rot_z(30), rot_z(0)) == pytest.approx(30.0)
    assert rotation_error_deg(rot_z(10), rot_z(-20)) == pytest.approx(30.0)
    assert rotation_error_deg(rot_z(180), np.eye(3)) == pytest.approx(180.0)
    assert rotation_error_deg(np.eye(3), np.eye(3)) == 0.0  # clipped, no NaN
    assert np.isfinite(rotation_error_deg(np.eye(3) * (1 + 1e-12), np.eye(3)))
    batch = rotation_error_deg(np.stack([rot_z(5), rot_z(90)]), np.eye(3))
    np.testing.assert_allclose(batch, [5, 90])
    assert translation_error([1, 2, 3], [1, 2, 3]) == 0.0
    assert translation_error([3, 4, 0], [0, 0, 0]) == pytest.approx(5.0)


def test_match_matrix_thresholds() -> None:
    gt = [pose(0, (0, 0, 0)), pose(90, (1, 0, 0))]
    pred = [pose(14, (0.05, 0, 0)), pose(16, (0, 0, 0)), pose(90, (1, 0.11, 0))]
    m = pose_match_matrix(pred, gt)
    np.testing.assert_array_equal(m, [[True, False], [False, False], [False, False]])
    assert pose_match_matrix([], gt).shape == (0, 2)
    assert pose_match_matrix(pred, np.empty((0, 4, 4))).shape == (3, 0)


def test_duplicates_count_in_any_match_but_not_strict() -> None:
    gt = [pose(0, (0, 0, 0)), pose(90, (2, 0, 0)), pose(45, (0, 3, 0))]
    pred = [
        pose(1, (0.01, 0, 0)),
        pose(-1, (0, 0.02, 0)),
        pose(90, (2, 0, 0.01)),
        pose(0, (9, 9, 9)),
    ]
    s = score_scene(pred, gt)
    assert (s.n_pred, s.n_gt) == (4, 3)
    assert s.precision == pytest.approx(3 / 4)  # both duplicates count
    assert s.recall == pytest.approx(2 / 3)
    assert s.n_matched == 2
    assert s.strict_precision == pytest.approx(2 / 4)
    assert s.strict_recall == pytest.approx(2 / 3)
    assert s.strict_f1 == pytest.approx(2 * 0.5 * (2 / 3) / (0.5 + 2 / 3))


def test_strict_uses_maximum_matching() -> None:
    # pred 0 matches both GT, pred 1 only GT 0: a greedy pass could match 1, the max is 2.
    gt = [pose(0, (0, 0, 0)), pose(0, (0.06, 0, 0))]
    pred = [pose(0, (0.03, 0, 0)), pose(0, (-0.05, 0, 0))]
    m = pose_match_matrix(pred, gt)
    np.testing.assert_array_equal(m, [[True, True], [True, False]])
    s = score_scene(pred, gt)
    assert s.n_matched == 2 and s.strict_f1 == 1.0


def test_kuhn_equals_linear_sum_assignment() -> None:
    linear_sum_assignment = pytest.importorskip("scipy.optimize").linear_sum_assignment
    rng = np.random.default_rng(0)
    for _ in range(200):
        p, g = rng.integers(0, 12, size=2)
        adj = rng.random((p, g)) < rng.uniform(0.05, 0.6)
        match = max_bipartite_matching(adj)
        rows = np.flatnonzero(match >= 0)
        assert np.all(adj[rows, match[rows]])  # only allowed edges
        assert len(set(match[rows].tolist())) == len(rows)  # one-to-one
        if p and g:
            r, c = linear_sum_assignment(-adj.astype(float))
            expected = int(adj[r, c].sum())
        else:
            expected = 0
        assert len(rows) == expected


@pytest.mark.parametrize(
    ("n_pred", "n_gt", "expected"),
    [(0, 0, (1.0, 1.0, 1.0)), (0, 3, (0.0, 0.0, 0.0)), (2, 0, (0.0, 1.0, 0.0))],
)
def test_empty_conventions(n_pred: int, n_gt: int, expected: tuple[float, float, float]) -> None:
    pred = [pose(0, (5 * i, 0, 0)) for i in range(n_pred)]
    gt = [pose(0, (5 * i + 100, 0, 0)) for i in range(n_gt)]
    s = score_scene(pred, gt)
    p, r, f1 = expected
    assert (s.precision, s.recall, s.f1) == (p, r, f1)
    assert (s.strict_precision, s.strict_recall, s.strict_f1) == (p, r, f1)


def test_no_match_gives_zero_f1() -> None:
    s = score_scene([pose(0, (9, 9, 9))], [pose()])
    assert s.precision == 0 and s.recall == 0 and s.f1 == 0 and s.strict_f1 == 0


def test_summarize_uses_means_for_mf() -> None:
    a = SceneScore(2, 2, 1.0, 0.5, 1.0, 0.5, 2 / 3, 1)
    b = SceneScore(1, 1, 0.5, 1.0, 0.0, 0.0, 0.0, 0)
    s = summarize([a, b])
    assert isinstance(s, Summary)
    assert s.mean_precision == pytest.approx(0.75) and s.mean_recall == pytest.approx(0.75)
    assert s.mean_f1 == pytest.approx(0.75)  # from the means, not the mean of per-scene F1
    assert s.strict_f1 == pytest.approx(1 / 3)
    assert s.strict_precision == pytest.approx(0.5) and s.strict_recall == pytest.approx(0.25)
    assert s.n_scenes == 2
    assert "75.00" in s.as_row("x") and "MF" in Summary.table_header() and "MR" in str(s)
    assert s.as_dict()["n_scenes"] == 2
    with pytest.raises(ValueError):
        summarize([])

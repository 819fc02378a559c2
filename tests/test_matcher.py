"""DescriptorMatcher: matching parts of one scan without searching its descriptors again."""

from __future__ import annotations

import numpy as np
import pointclm.preprocessing as pp
import pytest


def _descriptors(n: int, salt: int) -> np.ndarray:
    rng = np.random.default_rng(salt)
    return rng.random((n, 33)) * 100.0


SRC, TGT = _descriptors(150, 1), _descriptors(400, 2)


@pytest.mark.parametrize("mutual", [False, True])
@pytest.mark.parametrize("k", [1, 3])
def test_matching_a_subset_equals_matching_its_descriptors(mutual: bool, k: int) -> None:
    matcher = pp.DescriptorMatcher(SRC, TGT, k=k)
    rows = np.flatnonzero(np.arange(len(TGT)) % 3 != 0)
    for seed in (0, 5):
        got = matcher.match(rows, top_k=200, mutual=mutual, n_samples=80, seed=seed)
        want = pp.match_features(
            SRC, TGT[rows], top_k=200, mutual=mutual, n_samples=80, seed=seed, k=k
        )
        np.testing.assert_array_equal(got.source, want.source)
        np.testing.assert_array_equal(got.target, rows[want.target])  # whole-target indices
        np.testing.assert_array_equal(got.distance, want.distance)
    whole = matcher.match(top_k=200, mutual=mutual, n_samples=None)
    mask = np.ones(len(TGT), dtype=bool)
    by_mask = matcher.match(mask, top_k=200, mutual=mutual, n_samples=None)
    np.testing.assert_array_equal(whole.target, by_mask.target)
    np.testing.assert_array_equal(whole.source, by_mask.source)


@pytest.mark.parametrize(
    "rows, match",
    [
        (np.array([], dtype=int), "rows is empty"),
        (np.array([0, 400]), "index the 400 target rows"),
        (np.array([-1]), "index the 400 target rows"),
        (np.array([0.5]), "1-D array of target row indices"),
        (np.ones(3, dtype=bool), "one entry per target row"),
    ],
)
def test_bad_rows_are_value_errors(rows: np.ndarray, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        pp.DescriptorMatcher(SRC, TGT).match(rows)


def test_the_core_checks_given_nearest_sources() -> None:
    from pointclm import _core

    near, d2 = _core.nearest_descriptors(SRC, TGT, k=2)
    assert near.shape == d2.shape == (len(TGT), 2)
    with pytest.raises(ValueError, match="neighbours per row"):
        _core.match_features(SRC, TGT, k=1, nearest=(near, d2))
    with pytest.raises(ValueError, match="nearest must be None or"):
        _core.match_features(SRC, TGT, k=2, nearest=(near.astype(np.float64), d2))
    bad = near.copy()
    bad[0, 0] = len(SRC)
    with pytest.raises(ValueError, match="does not exist"):
        _core.match_features(SRC, TGT, k=2, nearest=(bad, d2))

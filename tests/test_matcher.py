"""DescriptorMatcher: matching parts of one scan without searching its descriptors again."""

from __future__ import annotations

import numpy as np
import pointclm
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


def _two_copies() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A model of 150 points in the unit cube, and a scan of two copies of it 10 apart whose
    descriptors are the model's with a little noise of their own."""
    rng = np.random.default_rng(7)
    model = rng.random((150, 3))
    scan = np.vstack([model, model + [10.0, 0.0, 0.0]])
    desc = np.vstack([SRC + rng.normal(0, 0.01, SRC.shape) for _ in range(2)])
    return model, scan, desc


def test_a_windowed_mutual_check_keeps_every_copys_matches() -> None:
    model, scan, desc = _two_copies()
    diagonal = float(np.linalg.norm(model.max(0) - model.min(0)))
    matcher = pp.DescriptorMatcher(SRC, desc, target_points=scan)
    scene_wide = matcher.match(mutual=True, n_samples=None)
    assert len(scene_wide) <= len(SRC)  # one scan point per model point: one copy's worth
    local = matcher.match(mutual=True, n_samples=None, window=2 * diagonal)
    assert np.array_equal(local.target % len(SRC), local.source)  # every pair a true match
    per_copy = np.bincount(local.target // len(SRC), minlength=2)
    assert per_copy.min() >= 0.9 * len(SRC), per_copy
    # A subset of the rows: only its points are matched, each copy still by itself.
    rows = np.flatnonzero(np.arange(len(scan)) % 2 == 0)
    part = matcher.match(rows, mutual=True, n_samples=None, window=2 * diagonal)
    assert np.isin(part.target, rows).all() and len(part) >= 0.9 * len(rows)


def test_a_window_needs_the_mutual_check_one_neighbour_and_the_points() -> None:
    model, scan, desc = _two_copies()
    with pytest.raises(ValueError, match="mutual=True and k=1"):
        pp.DescriptorMatcher(SRC, desc, target_points=scan).match(mutual=False, window=1.0)
    with pytest.raises(ValueError, match="mutual=True and k=1"):
        pp.DescriptorMatcher(SRC, desc, k=2, target_points=scan).match(mutual=True, window=1.0)
    with pytest.raises(ValueError, match="target_points"):
        pp.DescriptorMatcher(SRC, desc).match(mutual=True, window=1.0)
    with pytest.raises(ValueError, match="one target point per target descriptor"):
        pp.DescriptorMatcher(SRC, desc, target_points=scan[:-1])
    with pytest.raises(ValueError, match="mutual_window needs"):
        pointclm.register_point_clouds(model, scan, mutual=False, mutual_window=2.0)


def _ranked_by_brute_force(src: np.ndarray, tgt: np.ndarray, rows: np.ndarray, rank: int):
    """(source, target) pairs of `mutual_rank`: the target row's nearest source row (over all
    sources) counts it among its `rank` nearest of `rows` (ties to the lower row)."""
    d2 = ((tgt[:, None, :] - src[None, :, :]) ** 2).sum(-1)  # target x source
    kept = set()
    for t in rows:
        s = int(np.argmin(d2[t]))
        order = sorted(rows, key=lambda q: (d2[q, s], q))
        if t in order[:rank]:
            kept.add((s, int(t)))
    return kept


@pytest.mark.parametrize("rank", [1, 2, 5])
def test_a_ranked_mutual_check_equals_brute_force(rank: int) -> None:
    # A target of at most WINDOW_CANDIDATES rows: every row is a candidate, so the check is
    # exact and brute force can say what it keeps.
    src, tgt = _descriptors(20, 3), _descriptors(pp.WINDOW_CANDIDATES, 4)
    matcher = pp.DescriptorMatcher(src, tgt)
    for rows in (np.arange(len(tgt)), np.flatnonzero(np.arange(len(tgt)) % 3 != 1)):
        got = matcher.match(rows, mutual=True, n_samples=None, mutual_rank=rank)
        pairs = set(zip(got.source.tolist(), got.target.tolist(), strict=True))
        assert pairs == _ranked_by_brute_force(src, tgt, rows, rank)
    if rank == 1:  # the mutual nearest check itself
        plain = matcher.match(mutual=True, n_samples=None)
        ranked = matcher.match(mutual=True, n_samples=None, mutual_rank=1)
        np.testing.assert_array_equal(plain.target, ranked.target)


def test_a_ranked_mutual_check_keeps_a_match_on_each_copy() -> None:
    model, scan, desc = _two_copies()
    matcher = pp.DescriptorMatcher(SRC, desc)
    scene_wide = matcher.match(mutual=True, n_samples=None)
    assert len(scene_wide) <= len(SRC)
    ranked = matcher.match(mutual=True, n_samples=None, mutual_rank=2)
    assert np.array_equal(ranked.target % len(SRC), ranked.source)  # every pair a true match
    per_copy = np.bincount(ranked.target // len(SRC), minlength=2)
    assert per_copy.min() >= 0.9 * len(SRC), per_copy
    # Ranks beyond the candidates looked at search further, once.
    wide = matcher.match(mutual=True, n_samples=None, mutual_rank=pp.WINDOW_CANDIDATES + 6)
    assert len(wide) >= len(ranked)


def test_a_rank_needs_the_mutual_check_and_one_neighbour() -> None:
    model, scan, desc = _two_copies()
    with pytest.raises(ValueError, match="mutual=True and k=1"):
        pp.DescriptorMatcher(SRC, desc).match(mutual=False, mutual_rank=2)
    with pytest.raises(ValueError, match="mutual=True and k=1"):
        pp.DescriptorMatcher(SRC, desc, k=2).match(mutual=True, mutual_rank=2)
    with pytest.raises(ValueError, match="not both"):
        pp.DescriptorMatcher(SRC, desc, target_points=scan).match(
            mutual=True, window=1.0, mutual_rank=2
        )
    for bad in (0, True, 2.5, -1):
        with pytest.raises(ValueError, match="mutual_rank must be an int"):
            pp.DescriptorMatcher(SRC, desc).match(mutual=True, mutual_rank=bad)

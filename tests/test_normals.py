"""Normals at both ends of each correspondence (the normal term of spatial consistency) and
top-k descriptor matching."""

from __future__ import annotations

import numpy as np
import pointclm
import pointclm.preprocessing as pp
import pytest
from pointclm import _core
from pointclm.datasets.scenes import SceneParams, make_realistic_scene


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _planted(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two rigid copies (60 rows each) and 180 outliers, with normals that the copies carry
    by their poses (every third flipped) and random ones for the outliers."""
    rng = np.random.default_rng(seed)
    rows, nrm, labels = [], [], []
    for k in range(2):
        r, t = _rotation(rng), rng.uniform(0, 3, size=3)
        x = rng.uniform(-0.5, 0.5, size=(60, 3))
        n = rng.normal(size=(60, 3))
        nt = n @ r.T
        nt[::3] *= -1
        rows.append(np.hstack([x, x @ r.T + t]))
        nrm.append(np.hstack([n, nt]))
        labels += [k] * 60
    rows.append(np.hstack([rng.uniform(-0.5, 0.5, (180, 3)), rng.uniform(0, 3.5, (180, 3))]))
    nrm.append(rng.normal(size=(180, 6)))
    labels += [-1] * 180
    return np.vstack(rows), np.vstack(nrm), np.array(labels)


def test_normal_term_keeps_rigid_pairs_and_cuts_the_rest() -> None:
    corr, nrm, labels = _planted()
    plain = _core.spatial_consistency(corr, 0.05)
    with_n = _core.spatial_consistency(np.hstack([corr, nrm]), 0.05)
    assert np.all(with_n <= plain + 1e-12) and np.array_equal(with_n, with_n.T)
    same = (labels[:, None] == labels[None, :]) & (labels[:, None] >= 0)
    np.testing.assert_allclose(with_n[same], plain[same], atol=1e-9)
    other = ~same & (plain > 0.5)
    assert (with_n[other] < 0.5 * plain[other]).mean() > 0.5


def test_register_with_normals_finds_the_copies_and_checks_them() -> None:
    corr, nrm, labels = _planted(1)
    cfg = {"sigma_d": 0.05, "tau_n": 10}
    r = pointclm.register(corr, config=cfg, normals=nrm)
    assert len(r.instances) == 2
    # Sharper consistency: pruning keeps no more outliers than without normals.
    plain = pointclm.register(corr, config=cfg)
    kept_out = lambda res: int((labels[np.asarray(res.kept)] < 0).sum())  # noqa: E731
    assert kept_out(r) <= kept_out(plain)
    # Bit-identical without normals, whatever the thread count.
    again = pointclm.register(corr, config=cfg, normals=nrm, num_threads=1)
    np.testing.assert_array_equal(again.transformations, r.transformations)
    with pytest.raises(ValueError, match="one row"):
        pointclm.register(corr, normals=nrm[:-1])
    with pytest.raises(ValueError, match=r"\(N, 6\)"):
        pointclm.register(corr, normals=nrm[:, :3])
    zero = nrm.copy()
    zero[5, 3:] = 0
    with pytest.raises(ValueError, match="target normal of row 5"):
        pointclm.register(corr, normals=zero)
    with pytest.raises(ValueError, match="non-finite"):
        pointclm.register(corr, normals=np.where(zero == 0, np.nan, nrm))
    with pytest.raises(ValueError, match="N, 12"):
        _core.register(np.hstack([corr, nrm[:, :3]]))
    before = nrm.copy()
    pointclm.register(corr, config=cfg, normals=nrm)
    np.testing.assert_array_equal(nrm, before)  # inputs are never modified


def test_top_k_matching() -> None:
    rng = np.random.default_rng(3)
    src, tgt = rng.random((80, 33)), rng.random((120, 33))
    one = pp.match_features(src, tgt, top_k=10**6, n_samples=None)
    three = pp.match_features(src, tgt, top_k=10**6, n_samples=None, k=3)
    assert len(one) == 120 and len(three) == 360
    assert np.all(np.diff(three.distance) >= 0)
    pairs = set(zip(three.source.tolist(), three.target.tolist(), strict=True))
    assert set(zip(one.source.tolist(), one.target.tolist(), strict=True)) <= pairs
    mutual = pp.match_features(src, tgt, top_k=10**6, n_samples=None, k=3, mutual=True)
    assert 0 < len(mutual) < 360
    with pytest.raises(ValueError, match="k must be"):
        pp.match_features(src, tgt, k=0)


def test_register_point_clouds_with_normals_and_top_k() -> None:
    scene = make_realistic_scene(3, SceneParams(model="bunny", data_dir=None))
    r = pointclm.register_point_clouds(
        scene.source_points,
        scene.target_points,
        scene.voxel_size,
        normals=True,
        k=3,
        viewpoint=scene.target_points.mean(0) + [0, 0, 10 * scene.diameter],
    )
    assert 0 < len(r.correspondences) <= 1000 and len(r.instances) >= 1

"""Turned alternatives (pointclm.flips, the core's scene::flips): which turns are tried, in
which order, and what a symmetric model leaves alone. The outcomes on near-symmetric parts
(a half or quarter turn put back) are in test_refinement.py."""

from __future__ import annotations

import numpy as np
import pointclm
import pytest
from pointclm.refinement import flip_turns, quarter_turns, resolve_flips


def _box(lo: list[float], hi: list[float], step: float = 0.04) -> np.ndarray:
    """Points every `step` on the faces of the box `lo`..`hi`, each once."""
    lo_, hi_ = np.asarray(lo), np.asarray(hi)
    faces = []
    for axis in range(3):
        u, v = (axis + 1) % 3, (axis + 2) % 3
        a = np.linspace(lo_[u], hi_[u], round((hi_[u] - lo_[u]) / step) + 1)
        b = np.linspace(lo_[v], hi_[v], round((hi_[v] - lo_[v]) / step) + 1)
        ga, gb = (g.ravel() for g in np.meshgrid(a, b))
        for side in (lo_[axis], hi_[axis]):
            face = np.empty((ga.size, 3))
            face[:, axis], face[:, u], face[:, v] = side, ga, gb
            faces.append(face)
    return np.unique(np.round(np.concatenate(faces), 9), axis=0)


def _box_with_a_block() -> np.ndarray:
    """A flat cuboid with a block on one corner of its top: no turn maps it onto itself."""
    both = np.concatenate([_box([0, 0, 0], [1, 0.6, 0.2]), _box([0, 0, 0.2], [0.28, 0.28, 0.4])])
    return np.unique(np.round(both, 9), axis=0)


def _axes(src: np.ndarray) -> np.ndarray:
    """Principal axes by ascending variance, each with its first component off zero positive."""
    _, vec = np.linalg.eigh(np.cov((src - src.mean(0)).T))
    axes = vec.T
    lead = np.argmax(np.abs(axes) > 1e-6, axis=1)
    return axes * np.sign(axes[np.arange(3), lead])[:, None]


def test_the_turns_are_about_the_canonical_principal_axes_in_order() -> None:
    src = _box_with_a_block()
    centre, axes = src.mean(0), _axes(src)
    half = flip_turns(src, 0.04)
    assert half.shape == (3, 4, 4)
    for turn, a in zip(half, axes, strict=True):
        np.testing.assert_allclose(turn[:3, :3], 2 * np.outer(a, a) - np.eye(3), atol=1e-9)
        np.testing.assert_allclose(turn[:3, :3] @ centre + turn[:3, 3], centre, atol=1e-12)
        np.testing.assert_array_equal(turn[3], [0, 0, 0, 1])
    # Quarter turns: +90 degrees about each axis (so signed) before -90.
    quarter = quarter_turns(src, 0.04, max_change=1.0)
    assert len(quarter) == 6
    for k, a in enumerate(axes):
        cross = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
        for way, turn in zip((1.0, -1.0), quarter[2 * k : 2 * k + 2], strict=True):
            want = np.eye(3) + way * cross + cross @ cross
            np.testing.assert_allclose(turn[:3, :3], want, atol=1e-9)
    # A share out of [0, 1] or a bad voxel is refused.
    with pytest.raises(ValueError, match="min_change"):
        flip_turns(src, 0.04, min_change=1.5)
    with pytest.raises(ValueError, match="max_change"):
        quarter_turns(src, 0.04, max_change=-0.1)
    with pytest.raises(ValueError, match="voxel_size"):
        flip_turns(src, 0.0)


def test_a_symmetric_models_turns_are_not_tried_and_its_poses_stay() -> None:
    # A plain cuboid is its own half turn about each axis, and every quarter turn moves most of
    # it: nothing to try, the poses come back as they were.
    src = _box([0, 0, 0], [1, 0.4, 0.2])
    assert flip_turns(src, 0.04).shape == (0, 4, 4)
    assert quarter_turns(src, 0.04).shape == (0, 4, 4)
    truth = np.eye(4)
    truth[:3, 3] = [0.3, -0.2, 0.1]
    scan = src + truth[:3, 3]
    refined = pointclm.refine_poses(src, scan, truth[None], 0.04)
    kept, order = resolve_flips(src, scan, refined, 0.04)
    assert order.tolist() == [0]
    np.testing.assert_array_equal(kept.transformations, refined.transformations)
    np.testing.assert_array_equal(kept.confidence, refined.confidence)


def test_the_box_with_a_block_half_turned_comes_back_from_every_turn() -> None:
    src = _box_with_a_block()
    theta = np.radians(35.0)
    truth = np.eye(4)
    truth[:3, :3] = [
        [np.cos(theta), -np.sin(theta), 0],
        [np.sin(theta), np.cos(theta), 0],
        [0, 0, 1],
    ]
    truth[:3, 3] = [0.5, -0.2, 0.1]
    scan = src @ truth[:3, :3].T + truth[:3, 3]
    wrong = truth @ flip_turns(src, 0.04)
    keep = {"max_shared": 1.0, "min_fitness": 0.0, "min_relative_fitness": 0.0}
    refined = pointclm.refine_poses(src, scan, wrong, 0.04, **keep)
    assert len(refined.origin) == 3 and (refined.fitness < 0.95).all()
    before = (refined.transformations.copy(), refined.confidence.copy())
    fixed, order = resolve_flips(src, scan, refined, 0.04)
    assert sorted(order.tolist()) == [0, 1, 2]
    np.testing.assert_allclose(fixed.transformations, np.broadcast_to(truth, (3, 4, 4)), atol=1e-6)
    assert (fixed.fitness == 1.0).all()
    np.testing.assert_array_equal(fixed.origin, refined.origin[order])
    # The input is not modified.
    np.testing.assert_array_equal(refined.transformations, before[0])
    np.testing.assert_array_equal(refined.confidence, before[1])

"""Bin-picking scenes: determinism, no interpenetration, visibility, rigid ground truth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from pointclm.datasets.bins import (
    FLOOR,
    WALL,
    BinParams,
    bin_scene_cached,
    load_bin_scene,
    make_bin_scene,
    save_bin_scene,
)
from scipy.spatial import cKDTree

#: A small bin (procedural part, no data folder): seconds per scene.
SMALL = BinParams(
    model="box",
    copies=(18, 22),
    bin_size=(0.2, 0.15, 0.1),
    sensor_height=0.5,
    resolution=(200, 150),
)


#: Fewer copies, for the tests that build several scenes.
TINY = replace(SMALL, copies=(3, 3))


@pytest.fixture(scope="module")
def scene():
    return make_bin_scene(0, SMALL)


def test_same_seed_same_scene_other_seed_other_scene() -> None:
    one = make_bin_scene(1, TINY)
    again = make_bin_scene(1, TINY)
    for name in ("scan", "scan_ids", "poses", "visible_fraction", "rank"):
        np.testing.assert_array_equal(getattr(one, name), getattr(again, name))
    other = make_bin_scene(2, TINY)
    assert not np.allclose(other.poses, one.poses)


def test_ground_truth_poses_are_rigid_and_explain_the_scan(scene) -> None:
    assert SMALL.copies[0] <= scene.n_copies <= SMALL.copies[1]
    rot = scene.poses[:, :3, :3]
    np.testing.assert_allclose(
        rot @ rot.transpose(0, 2, 1), np.broadcast_to(np.eye(3), rot.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-12)
    np.testing.assert_array_equal(
        scene.poses[:, 3], np.broadcast_to([0, 0, 0, 1.0], (scene.n_copies, 4))
    )
    # Scan points of a copy lie on the posed model, within the sensor's noise.
    for k in np.flatnonzero(scene.visible_pixels > 50)[:4]:
        pose = scene.poses[k]
        posed = scene.model_points @ pose[:3, :3].T + pose[:3, 3]
        dist, _ = cKDTree(posed).query(scene.scan[scene.scan_ids == k])
        assert np.median(dist) < 0.05 * scene.diameter


def test_copies_do_not_interpenetrate_and_stay_in_the_bin(scene) -> None:
    length, width, _ = SMALL.bin_size
    # Columns of a grid finer than, and offset from, the generator's: in each column the
    # copies' height intervals must not overlap.
    cell = scene.diameter / 97
    spans: dict[int, list[tuple[float, float]]] = {}
    for pose in scene.poses:
        p = scene.model_points @ pose[:3, :3].T + pose[:3, 3]
        assert np.all(np.abs(p[:, 0]) <= length / 2 + 1e-9)
        assert np.all(np.abs(p[:, 1]) <= width / 2 + 1e-9)
        assert p[:, 2].min() >= -1e-9
        ij = np.floor((p[:, :2] + 0.37 * cell) / cell).astype(np.int64)
        key = ij[:, 0] * 100_003 + ij[:, 1]
        order = np.argsort(key, kind="stable")
        keys, start = np.unique(key[order], return_index=True)
        lo = np.minimum.reduceat(p[order, 2], start)
        hi = np.maximum.reduceat(p[order, 2], start)
        for c, a, b in zip(keys.tolist(), lo, hi, strict=True):
            spans.setdefault(c, []).append((a, b))
    shared = 0
    for intervals in spans.values():
        intervals.sort()
        for (_, b1), (a2, _) in zip(intervals, intervals[1:], strict=False):
            assert a2 >= b1 - 1e-9, "two copies share a column's height interval"
            shared += 1
    assert shared > 0, "no copy rests on another: the heap test proves nothing"


def test_visible_fractions_and_ranks(scene) -> None:
    vf = scene.visible_fraction
    assert np.all((vf >= 0) & (vf <= 1))
    assert np.all(scene.visible_pixels <= scene.alone_pixels)
    assert vf.min() < 0.5 < vf.max(), "a heap hides some copies and leaves others in view"
    assert sorted(scene.rank.tolist()) == list(range(scene.n_copies))
    top = scene.least_hidden(scene.n_copies)
    assert np.all(np.diff(vf[top]) <= 0)
    ids = scene.scan_ids
    assert np.all((ids >= 0) & (ids < scene.n_copies) | (ids == FLOOR) | (ids == WALL))
    # Pixels are counted before noise, dropouts and the crop: never fewer than scan points.
    counts = np.bincount(ids[ids >= 0], minlength=scene.n_copies)
    assert np.all(counts <= scene.visible_pixels)


def test_npz_round_trip_and_cache(scene, tmp_path) -> None:
    path = tmp_path / "scene.npz"
    save_bin_scene(scene, path)
    back = load_bin_scene(path)
    np.testing.assert_array_equal(back.scan, scene.scan)
    np.testing.assert_array_equal(back.poses, scene.poses)
    assert back.params == scene.params and back.voxel_size == scene.voxel_size
    with np.load(path, allow_pickle=False) as z:
        assert "header" in z.files
    first = bin_scene_cached(tmp_path / "cache", 1, TINY)
    files = list((tmp_path / "cache").iterdir())
    assert len(files) == 1
    np.testing.assert_array_equal(bin_scene_cached(tmp_path / "cache", 1, TINY).scan, first.scan)


@pytest.mark.parametrize(
    "kwargs",
    [{"copies": (0, 3)}, {"copies": (5, 2)}, {"part_fraction": 1.5}, {"sensor_height": 0.1}],
)
def test_bad_parameters_are_rejected(kwargs) -> None:
    with pytest.raises(ValueError):
        BinParams(**kwargs)


def test_unknown_model_and_bad_seed_are_rejected() -> None:
    with pytest.raises(ValueError, match="unknown model"):
        make_bin_scene(0, BinParams(model="no-such-part"))
    with pytest.raises(ValueError, match="seed"):
        make_bin_scene(-1, SMALL)

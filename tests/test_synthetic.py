"""Tests of the shapes and of the seeded synthetic protocol (SPEC section 3)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers import DATA, needs_data
from pointclm.datasets import (
    PROCEDURAL_SHAPES,
    SyntheticScene,
    available_shapes,
    label_correspondences,
    load_mesh,
    load_shape,
    make_planted_scene,
    make_scene,
    make_scenes,
    modelnet40_shapes,
    normalize_unit_sphere,
)


def _assert_unit_sphere(cloud: np.ndarray) -> None:
    assert cloud.dtype == np.float64
    np.testing.assert_allclose(cloud.mean(axis=0), 0.0, atol=1e-12)
    assert np.linalg.norm(cloud, axis=1).max() == pytest.approx(1.0)


# --- shapes -------------------------------------------------------------------------------


def test_bunny_is_packaged_and_numpy_only() -> None:
    cloud = load_shape("bunny")
    assert cloud.shape == (2048, 3)
    _assert_unit_sphere(cloud)
    np.testing.assert_array_equal(cloud, load_shape("bunny", rng=0))
    assert not np.array_equal(cloud, load_shape("bunny", rng=1))
    npz = Path(__file__).resolve().parents[1] / "python/pointclm/datasets/data/bunny_res4.npz"
    with np.load(npz) as d:
        assert d["vertices"].shape == (453, 3) and d["vertices"].dtype == np.float64
        assert d["faces"].shape == (948, 3) and d["faces"].dtype == np.int32


@pytest.mark.parametrize("name", PROCEDURAL_SHAPES)
def test_procedural_shapes(name: str) -> None:
    cloud = load_shape(name, n_points=500, rng=np.random.default_rng(3))
    assert cloud.shape == (500, 3)
    _assert_unit_sphere(cloud)
    assert name in available_shapes()


def test_area_sampling_is_uniform() -> None:
    # Two unit squares, one 4x larger in area: it must get about 4/5 of the samples.
    from pointclm.datasets import sample_surface

    v = np.array(
        [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [5, 0, 0], [7, 0, 0], [7, 2, 0], [5, 2, 0]],
        float,
    )
    f = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    pts = sample_surface(v, f, 20000, 0)
    assert np.mean(pts[:, 0] > 3) == pytest.approx(0.8, abs=0.02)
    big = pts[pts[:, 0] > 3]
    assert big[:, 0].min() >= 5 and big[:, 0].max() <= 7 and big[:, 1].max() <= 2
    assert np.mean(big[:, 1] < 1) == pytest.approx(0.5, abs=0.03)


def test_unknown_shape_and_bad_files(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="neither a known shape"):
        load_shape("no-such-shape")
    bad = tmp_path / "broken.ply"
    bad.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\nzz\n")
    with pytest.raises(ValueError, match="broken.ply"):
        load_shape(bad)
    empty = tmp_path / "empty.off"
    empty.write_text("")
    with pytest.raises(ValueError, match="empty.off"):
        load_shape(empty)
    other = tmp_path / "cloud.xyz"
    other.write_text("0 0 0\n")
    with pytest.raises(ValueError, match="unsupported"):
        load_mesh(other)
    flat = tmp_path / "point.npy"
    np.save(flat, np.zeros((10, 3)))
    with pytest.raises(ValueError, match="point.npy"):
        load_shape(flat)


def test_numpy_files(tmp_path: Path) -> None:
    pts = np.random.default_rng(0).normal(size=(300, 3))
    np.save(tmp_path / "c.npy", pts)
    cloud = load_shape(tmp_path / "c.npy", n_points=100)
    _assert_unit_sphere(cloud)
    np.testing.assert_allclose(normalize_unit_sphere(pts[:2] * [1, 1, 1]).shape, (2, 3))


@needs_data
def test_data_folder_shapes() -> None:
    pytest.importorskip("trimesh")
    names = available_shapes(DATA)
    for name in (
        "stanford/dragon",
        "stanford/armadillo",
        "stanford/bunny-res3",
        "modelnet/bathtub",
        "modelnet/bed",
    ):
        assert name in names
        cloud = load_shape(name, n_points=256, data_dir=DATA)
        assert cloud.shape == (256, 3)
        _assert_unit_sphere(cloud)
    # point-only PLY (no faces): sampled from its points
    verts, faces = load_mesh(DATA / "stanford/armadillo/Armadillo_38294v.ply")
    assert faces is None and verts.shape == (38294, 3)
    # a path works without data_dir
    res4 = load_shape(DATA / "stanford/bunny/reconstruction/bun_zipper_res4.ply", rng=5)
    _assert_unit_sphere(res4)


def test_modelnet40_needs_a_folder(tmp_path: Path) -> None:
    pytest.importorskip("h5py")
    with pytest.raises(ValueError, match="ply_data_test"):
        modelnet40_shapes(tmp_path)


def test_modelnet40_reads_h5(tmp_path: Path) -> None:
    h5py = pytest.importorskip("h5py")
    rng = np.random.default_rng(0)
    for i in (1, 0):
        with h5py.File(tmp_path / f"ply_data_test{i}.h5", "w") as f:
            f["data"] = rng.random((2, 2048, 3)).astype(np.float32) + i
            f["label"] = np.full((2, 1), i, np.uint8)
    clouds, labels = modelnet40_shapes(tmp_path, with_labels=True)
    assert clouds.shape == (4, 2048, 3) and clouds.dtype == np.float64
    np.testing.assert_array_equal(labels, [0, 0, 1, 1])
    # the release's listing file, when present, gives the order
    listing = [f"data/modelnet40_ply_hdf5_2048/ply_data_test{i}.h5" for i in (1, 0)]
    (tmp_path / "test_files.txt").write_text("\n".join(listing) + "\n")
    _, listed = modelnet40_shapes(tmp_path, with_labels=True)
    np.testing.assert_array_equal(listed, [1, 1, 0, 0])
    scene = make_scene(0, clouds[2])
    assert scene.shape == "array"
    np.testing.assert_allclose(scene.source, normalize_unit_sphere(clouds[2])[:256])
    raw = make_scene(0, clouds[2], normalize=False, shape_name="modelnet40/test/2")
    np.testing.assert_array_equal(raw.source, clouds[2, :256])
    assert raw.shape == "modelnet40/test/2"


# --- synthetic protocol -------------------------------------------------------------------


def test_scene_shapes_and_dtypes() -> None:
    s = make_scene(0)
    assert isinstance(s, SyntheticScene)
    assert s.correspondences.shape == (1000, 6) and s.correspondences.dtype == np.float64
    assert s.labels.shape == (1000,) and s.labels.dtype == np.int64
    assert s.poses.dtype == np.float64 and s.poses.shape[1:] == (4, 4)
    assert s.source.shape == (256, 3)
    assert s.shape == "bunny" and s.seed == 0
    assert not s.correspondences.flags.writeable
    for pose in s.poses:
        r = pose[:3, :3]
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)
        np.testing.assert_array_equal(pose[3], [0, 0, 0, 1])
        assert np.all((pose[:3, 3] >= 0) & (pose[:3, 3] < 5))
    assert make_scene(0, n_keep=None).correspondences.shape == (256 * 50, 6)


def test_reproducible_and_seed_dependent() -> None:
    a, b, c = make_scene(7), make_scene(7), make_scene(8)
    for field in ("correspondences", "labels", "poses", "source"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert not np.array_equal(a.correspondences, c.correspondences)
    first = [s.correspondences for s in make_scenes(3, seed=1)]
    again = [s.correspondences for s in make_scenes(5, seed=1)][:3]
    for x, y in zip(first, again, strict=True):
        np.testing.assert_array_equal(x, y)
    seeds = [s.seed for s in make_scenes(4, seed=1)]
    assert len(set(seeds)) == 4
    np.testing.assert_array_equal(make_scene(seeds[2]).correspondences, first[2])


def test_instance_counts_and_labels_agree_with_poses() -> None:
    counts = []
    for s in make_scenes(40, seed=2):
        counts.append(s.n_instances)
        assert 5 <= s.n_instances <= 10
        x, y = s.correspondences[:, :3], s.correspondences[:, 3:]
        for k, pose in enumerate(s.poses):
            res = np.linalg.norm(x @ pose[:3, :3].T + pose[:3, 3] - y, axis=1)
            assert np.all(res[s.labels == k] < 0.05)
            assert np.all(res[s.labels == -1] >= 0.05)
        np.testing.assert_array_equal(label_correspondences(s.correspondences, s.poses), s.labels)
        # every instance has inliers: about 20 each
        assert np.all(np.bincount(s.labels[s.labels >= 0], minlength=s.n_instances) > 5)
    assert min(counts) == 5 and max(counts) == 10


def test_inlier_ratio_per_instance() -> None:
    test = [s.inlier_ratio / s.n_instances for s in make_scenes(30, seed=3)]
    train = [s.inlier_ratio / s.n_instances for s in make_scenes(30, seed=3, n_outlier_blocks=10)]
    assert np.mean(test) == pytest.approx(1 / 50, rel=0.1)  # 256 of 12,800 rows
    assert np.mean(train) == pytest.approx(1 / 20, rel=0.1)  # 256 of 5,120 rows


def test_source_is_first_256_of_normalised_shape() -> None:
    cloud = np.random.default_rng(0).normal(size=(2048, 3)) * [3, 2, 1] + 4
    s = make_scene(5, cloud)
    norm = normalize_unit_sphere(cloud)
    np.testing.assert_allclose(s.source, norm[:256])
    # every source side of a row is one of the 256 source points
    d = np.abs(s.correspondences[:, None, :3] - s.source[None]).sum(axis=2).min(axis=1)
    assert d.max() == 0.0
    # the same seed gives the same poses whatever the shape
    np.testing.assert_array_equal(s.poses, make_scene(5, "torus").poses)
    # a named shape: the source is the first 256 points of its 2048-point cloud
    bunny = make_scene(5)
    assert bunny.source.shape == (256, 3)
    assert np.linalg.norm(bunny.source, axis=1).max() <= 1.0 + 1e-12


def test_outlier_targets_in_box() -> None:
    s = make_scene(11, n_keep=None)
    out = s.correspondences[s.labels < 0, 3:]
    assert out.min() >= 0.0 and out.max() < 6.0


def test_shapes_cycle() -> None:
    names = [s.shape for s in make_scenes(4, shapes=["bunny", "torus"])]
    assert names == ["bunny", "torus", "bunny", "torus"]


def test_planted_scene_scales() -> None:
    s = make_planted_scene(10_000, seed=0)
    assert s.correspondences.shape == (10_000, 6)
    assert s.n_instances == 5
    counts = np.bincount(s.labels[s.labels >= 0], minlength=5)
    assert np.all(counts >= 200) and np.all(counts < 215)  # 2 % each, plus rare chance hits
    scale = 10 ** (1 / 3)
    assert s.correspondences[:, 3:].max() < 6 * scale + 1.5
    np.testing.assert_array_equal(
        s.correspondences, make_planted_scene(10_000, seed=0).correspondences
    )
    with pytest.raises(ValueError):
        make_planted_scene(100, seed=0, n_instances=5, inlier_fraction=0.3)

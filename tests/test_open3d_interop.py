"""Open3D clouds and meshes in, Open3D clouds out: the same poses as the numpy path, Open3D
never imported unless the caller holds one of its objects."""

from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pointclm
import pytest
from pointclm.errors import InputError
from pointclm.interop.open3d import from_open3d, is_open3d_geometry
from pointclm.io import NonFinitePointsWarning, read_point_cloud, sample_mesh
from posed_copies import posed_copies


@pytest.fixture(scope="module")
def clouds() -> tuple[np.ndarray, np.ndarray]:
    model, scan, _ = posed_copies(2)
    return model, scan


@pytest.fixture(scope="module")
def numpy_result(clouds):
    return pointclm.register_point_clouds(*clouds)


def _o3d():
    return pytest.importorskip("open3d")


# --- without Open3D: recognised by module name, never imported --------------------------


class _Vectors:
    """Open3D's Vector3dVector reads as an array."""

    def __init__(self, a: np.ndarray) -> None:
        self.a = a

    def __array__(self, dtype=None, copy=None):
        return self.a if dtype is None else self.a.astype(dtype)


class _FakeCloud:
    def __init__(self, points: np.ndarray, normals: np.ndarray | None = None) -> None:
        self.points = _Vectors(points)
        self.normals = _Vectors(np.zeros((0, 3)) if normals is None else normals)
        self.colors = _Vectors(np.zeros((0, 3)))

    def has_normals(self) -> bool:
        return len(self.normals.a) > 0

    def has_colors(self) -> bool:
        return False


# Named and placed as Open3D's pybind classes are.
_FakeCloud.__name__ = "PointCloud"
_FakeCloud.__module__ = "open3d.cpu.pybind.geometry"


class _FakeLineSet:
    pass


_FakeLineSet.__name__ = "LineSet"
_FakeLineSet.__module__ = "open3d.cpu.pybind.geometry"


def test_an_open3d_like_cloud_is_read_by_its_module_name(clouds, numpy_result) -> None:
    model, scan = clouds
    assert is_open3d_geometry(_FakeCloud(scan)) and not is_open3d_geometry(scan)
    r = pointclm.register_point_clouds(_FakeCloud(model), _FakeCloud(scan))
    np.testing.assert_array_equal(r.transformations, numpy_result.transformations)


def test_other_open3d_geometries_are_refused_by_name() -> None:
    with pytest.raises(InputError, match=r"target.*LineSet.*PointCloud or TriangleMesh"):
        pointclm.register_point_clouds(np.zeros((10, 3)), _FakeLineSet())
    with pytest.raises(InputError, match="has no points"):
        from_open3d(_FakeCloud(np.zeros((0, 3))))


def test_registering_arrays_does_not_import_open3d() -> None:
    code = (
        "import sys, numpy as np, pointclm\n"
        "from pointclm.datasets import load_shape\n"
        "m = load_shape('bunny', 1000)\n"
        "r = pointclm.register_point_clouds(m, m + 1.0)\n"
        "pointclm.io.read_point_cloud\n"
        "assert len(r.instances) == 1, r\n"
        "print('open3d' in sys.modules)\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "False"


# --- with Open3D --------------------------------------------------------------------------


def test_open3d_clouds_give_the_numpy_poses_and_to_open3d_round_trips(clouds, numpy_result) -> None:
    o3d = _o3d()
    model, scan = clouds
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(model))
    tgt = o3d.t.geometry.PointCloud(o3d.core.Tensor(scan))
    before = np.asarray(src.points).copy()
    r = pointclm.register_point_clouds(src, tgt)
    np.testing.assert_array_equal(r.transformations, numpy_result.transformations)
    np.testing.assert_array_equal(np.asarray(src.points), before)  # the input is left alone
    out = r.to_open3d()
    assert len(out) == 1 + len(r.instances) >= 3
    assert all(isinstance(c, o3d.geometry.PointCloud) for c in out)
    np.testing.assert_array_equal(np.asarray(out[0].points), r.target_points)
    colours = [tuple(np.asarray(c.colors)[0]) for c in out]
    assert len(set(colours)) == len(out)  # the scan and each copy in its own colour
    for inst, cloud in zip(r.instances, out[1:], strict=True):
        T = inst.transformation
        np.testing.assert_allclose(
            np.asarray(cloud.points), r.source_points @ T[:3, :3].T + T[:3, 3], atol=1e-12
        )
    # A copy that Open3D's own evaluation scores as pointclm does: same fitness and pairs.
    inst = r.instances[0]
    ev = o3d.pipelines.registration.evaluate_registration(
        o3d.geometry.PointCloud(o3d.utility.Vector3dVector(r.source_points)),
        out[0],
        1.5 * r.voxel_size,
        inst.transformation,
    )
    assert ev.fitness == pytest.approx(inst.fitness, abs=1e-9)
    assert ev.inlier_rmse == pytest.approx(inst.inlier_rmse, rel=1e-6)
    np.testing.assert_array_equal(
        np.asarray(ev.correspondence_set)[:, 0], inst.correspondence_set[:, 0]
    )


def test_normals_and_colours_come_with_the_points() -> None:
    o3d = _o3d()
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 3))
    nrm = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    cloud.normals = o3d.utility.Vector3dVector(nrm)
    cloud.colors = o3d.utility.Vector3dVector(np.full((50, 3), 0.25))
    read = read_point_cloud(cloud)
    np.testing.assert_array_equal(read.points, pts)
    np.testing.assert_array_equal(read.normals, nrm)
    np.testing.assert_array_equal(read.colors, np.full((50, 3), 0.25))
    t = o3d.t.geometry.PointCloud(o3d.core.Tensor(pts.astype(np.float32)))
    t.point.normals = o3d.core.Tensor(nrm.astype(np.float32))
    t.point.colors = o3d.core.Tensor(np.full((50, 3), 255, dtype=np.uint8))
    read = read_point_cloud(t)
    assert read.points.dtype == np.float64
    np.testing.assert_allclose(read.normals, nrm, atol=1e-6)
    np.testing.assert_array_equal(read.colors, np.ones((50, 3)))
    back = pointclm.io.to_open3d(read)
    np.testing.assert_array_equal(np.asarray(back.normals), read.normals)
    # A tensor of points is an array, checked as one.
    np.testing.assert_array_equal(
        pointclm.preprocessing.as_points(t.point.positions, "p"), read.points
    )
    with pytest.raises(InputError, match="p must"):
        pointclm.preprocessing.as_points(o3d.core.Tensor(np.ones((4, 2))), "p")


def test_a_mesh_is_sampled_as_a_mesh_file_is() -> None:
    o3d = _o3d()
    mesh = o3d.geometry.TriangleMesh.create_box(1.0, 2.0, 3.0)
    verts, tris = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    want = sample_mesh(verts, tris, 500, seed=4)
    got = read_point_cloud(mesh, n_samples=500, seed=4)
    np.testing.assert_array_equal(got.points, want.points)
    np.testing.assert_array_equal(got.normals, want.normals)
    tmesh = o3d.t.geometry.TriangleMesh.from_legacy(mesh)
    np.testing.assert_array_equal(
        read_point_cloud(tmesh, n_samples=500, seed=4).points, want.points
    )
    # As a model: the default sample count of a mesh file, max(10_000, vertices).
    assert len(pointclm.preprocessing.as_points(mesh, "source")) == 10_000


def test_nan_points_of_an_open3d_cloud_are_dropped_with_a_count() -> None:
    o3d = _o3d()
    pts = np.random.default_rng(1).normal(size=(20, 3))
    pts[[3, 7]] = np.nan
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        read = read_point_cloud(cloud)
    assert len(read) == 18 and read.dropped == 2
    assert any(
        issubclass(w.category, NonFinitePointsWarning) and "dropped 2 points" in str(w.message)
        for w in caught
    )


def test_refine_poses_takes_an_open3d_scan_and_its_normals(numpy_result) -> None:
    o3d = _o3d()
    r = numpy_result
    scan = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(r.target_points))
    scan.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(2 * r.voxel_size, 30))
    normals = np.asarray(scan.normals).copy()
    start = r.transformations.copy()
    start[:, :3, 3] += 0.3 * r.voxel_size
    ours = pointclm.refine_poses(r.source_points, scan, start, r.voxel_size)
    plain = pointclm.refine_poses(
        r.source_points, r.target_points, start, r.voxel_size, target_normals=normals
    )
    np.testing.assert_array_equal(ours.transformations, plain.transformations)
    # Without them the normals are estimated here, and the poses differ in the last bits.
    estimated = pointclm.refine_poses(r.source_points, r.target_points, start, r.voxel_size)
    assert not np.array_equal(estimated.transformations, ours.transformations)

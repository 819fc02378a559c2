"""pointclm.io: readers on real files from ../shared/data, synthetic edge cases, write_ply.

Point counts are those listed in ../shared/data/SOURCES.md. Mesh samples are checked to lie
on the mesh as trimesh reads it, which also cross-checks our PLY/OFF parsing against an
independent reader.
"""

from __future__ import annotations

import struct
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from helpers import DATA, DATA_HINT
from pointclm.io import (
    SUPPORTED_SUFFIXES,
    NonFinitePointsWarning,
    PointCloud,
    load_points,
    read_open3d_feature,
    read_point_cloud,
    write_ply,
)
from pointclm.io.lzf import lzf_decompress


def data_file(rel: str) -> Path:
    path = DATA / rel
    if not path.exists():
        pytest.skip(f"{path} is missing; {DATA_HINT}")
    return path


def assert_valid(cloud: PointCloud, n: int | None = None) -> None:
    """The contract every reader keeps."""
    pts = cloud.points
    assert pts.dtype == np.float64 and pts.ndim == 2 and pts.shape[1] == 3
    assert pts.flags.c_contiguous
    assert np.isfinite(pts).all()
    if n is not None:
        assert len(cloud) == n == len(pts)
    for extra in (cloud.normals, cloud.colors):
        if extra is not None:
            assert extra.shape == pts.shape and extra.dtype == np.float64
            assert np.isfinite(extra).all()
    if cloud.colors is not None:
        assert cloud.colors.min() >= 0.0 and cloud.colors.max() <= 1.0


def assert_unit(normals: np.ndarray | None, atol: float = 1e-5) -> None:
    assert normals is not None
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=atol)


def on_surface(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """For each point, whether it lies inside some triangle (brute force, in chunks)."""
    v0 = vertices[faces[:, 0]]
    e1 = vertices[faces[:, 1]] - v0
    e2 = vertices[faces[:, 2]] - v0
    normal = np.cross(e1, e2)
    length = np.linalg.norm(normal, axis=1)
    ok_tri = length > 0
    v0, e1, e2 = v0[ok_tri], e1[ok_tri], e2[ok_tri]
    unit = normal[ok_tri] / length[ok_tri, None]
    d00 = (e1 * e1).sum(1)
    d01 = (e1 * e2).sum(1)
    d11 = (e2 * e2).sum(1)
    denom = d00 * d11 - d01 * d01
    scale = np.ptp(vertices, axis=0).max()
    found = np.zeros(len(points), dtype=bool)
    for start in range(0, len(points), 64):
        p = points[start : start + 64, None, :]
        w = p - v0[None]
        dist = np.abs((w * unit[None]).sum(2))
        d20 = (w * e1[None]).sum(2)
        d21 = (w * e2[None]).sum(2)
        b = (d11 * d20 - d01 * d21) / denom
        c = (d00 * d21 - d01 * d20) / denom
        a = 1.0 - b - c
        eps = 1e-6
        inside = (a >= -eps) & (b >= -eps) & (c >= -eps) & (dist <= 1e-9 * scale + 1e-12)
        found[start : start + 64] = inside.any(axis=1)
    return found


def trimesh_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    trimesh = pytest.importorskip("trimesh")
    mesh = trimesh.load(str(path), process=False)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


# --------------------------------------------------------------------------------------
# PCD
# --------------------------------------------------------------------------------------


def test_pcd_binary_compressed() -> None:
    cloud = read_point_cloud(data_file("pcl/milk.pcd"))
    assert_valid(cloud, 13_704)
    assert cloud.normals is None and cloud.colors is None


def test_pcd_binary_compressed_organised_with_nans() -> None:
    path = data_file("pcl/milk_cartoon_all_small_clorox.pcd")
    start = time.perf_counter()
    with pytest.warns(NonFinitePointsWarning, match="dropped 65793 rows"):
        cloud = read_point_cloud(path)
    elapsed = time.perf_counter() - start
    assert_valid(cloud, 241_407)  # of 640 x 480 = 307,200 pixels
    assert cloud.dropped == 307_200 - 241_407
    assert cloud.colors is not None and cloud.normals is None
    assert cloud.colors.std(axis=0).min() > 0.05  # real colours, not a constant
    # Kinect depth: everything in front of the camera, within a few metres.
    assert cloud.points[:, 2].min() > 0.3 and cloud.points[:, 2].max() < 5.0
    assert elapsed < 5.0, f"loading the 640x480 scene took {elapsed:.2f} s"


def test_pcd_ascii() -> None:
    cloud = read_point_cloud(data_file("pcl/bunny.pcd"))
    assert_valid(cloud, 397)
    np.testing.assert_allclose(cloud.points[0], [0.0054216, 0.11349, 0.040749], rtol=1e-6)


def test_pcd_binary_with_normals_and_rgb() -> None:
    for name, n in (("cloud_bin_0", 3_903), ("cloud_bin_1", 3_458)):
        cloud = read_point_cloud(data_file(f"3dmatch/open3d_feature/{name}.pcd"))
        assert_valid(cloud, n)
        assert_unit(cloud.normals, atol=1e-4)  # float32 normals, unit to ~5e-5 in the file
        assert cloud.colors is not None and cloud.colors.max() > 0


def _pcd_header(fields: str, sizes: str, types: str, n: int, data: str) -> bytes:
    counts = " ".join(["1"] * len(fields.split()))
    return (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {fields}\nSIZE {sizes}\nTYPE {types}\nCOUNT {counts}\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    ).encode()


def _literal_lzf(raw: bytes) -> bytes:
    """A valid LZF block made only of literal runs (no compression, but any decoder reads it)."""
    out = bytearray()
    for i in range(0, len(raw), 32):
        chunk = raw[i : i + 32]
        out.append(len(chunk) - 1)
        out += chunk
    return bytes(out)


def _synthetic_fields() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pts = np.array([[0, 0, 0], [np.nan, np.nan, np.nan], [1, 2, 3], [4, 5, np.inf]], np.float32)
    nrm = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0], [1, 0, 0]], np.float32)
    rgb = np.array([0xFF0000, 0x00FF00, 0x0000FF, 0x808080], np.uint32)
    return pts, nrm, rgb


@pytest.mark.parametrize("layout", ["ascii", "binary", "binary_compressed"])
def test_pcd_layouts_keep_attributes_aligned(tmp_path: Path, layout: str) -> None:
    pts, nrm, rgb = _synthetic_fields()
    header = _pcd_header(
        "x y z normal_x normal_y normal_z rgb", "4 4 4 4 4 4 4", "F F F F F F F", 4, layout
    )
    rgb_f = rgb.view(np.float32)  # PCL packs rgb into a float's bits
    columns = [*pts.T, *nrm.T, rgb_f]
    if layout == "ascii":
        rows = [" ".join(repr(float(c[i])) for c in columns) for i in range(4)]
        body = ("\n".join(rows) + "\n").encode()
    elif layout == "binary":
        body = np.stack(columns, axis=1).astype("<f4").tobytes()
    else:
        raw = b"".join(c.astype("<f4").tobytes() for c in columns)  # field by field
        body = struct.pack("<II", len(_literal_lzf(raw)), len(raw)) + _literal_lzf(raw)
    path = tmp_path / f"aligned_{layout}.pcd"
    path.write_bytes(header + body)
    with pytest.warns(NonFinitePointsWarning, match="dropped 2 rows"):
        cloud = read_point_cloud(path)
    assert_valid(cloud, 2)  # the NaN and the inf rows are dropped
    np.testing.assert_array_equal(cloud.points, [[0, 0, 0], [1, 2, 3]])
    np.testing.assert_array_equal(cloud.normals, [[0, 0, 1], [0, 1, 0]])
    np.testing.assert_array_equal(cloud.colors, [[1, 0, 0], [0, 0, 1]])


def test_pcd_rgba_as_uint32(tmp_path: Path) -> None:
    header = _pcd_header("x y z rgba", "4 4 4 4", "F F F U", 2, "binary")
    rec = np.zeros(2, dtype=[("xyz", "<f4", 3), ("rgba", "<u4")])
    rec["xyz"] = [[1, 2, 3], [4, 5, 6]]
    rec["rgba"] = [0xFF336699, 0x80FFFFFF]
    path = tmp_path / "rgba.pcd"
    path.write_bytes(header + rec.tobytes())
    cloud = read_point_cloud(path)
    assert cloud.colors is not None
    np.testing.assert_allclose(
        cloud.colors, [[0x33 / 255, 0x66 / 255, 0x99 / 255], [1.0, 1.0, 1.0]]
    )


def test_lzf_back_references() -> None:
    # Literal "abc", then a back-reference of length 6 at distance 3 (overlapping copy).
    block = bytes([2]) + b"abc" + bytes([(6 - 2) << 5, 3 - 1])
    assert lzf_decompress(block, 9) == b"abcabcabc"
    # Extended length (7 + next byte) at distance 1: a run of one repeated byte.
    block = bytes([0]) + b"z" + bytes([7 << 5, 20 - 2 - 7, 0])
    assert lzf_decompress(block, 21) == b"z" * 21
    with pytest.raises(ValueError, match="before the start"):
        lzf_decompress(bytes([0]) + b"z" + bytes([(3 - 2) << 5, 5]), 4)
    with pytest.raises(ValueError, match="truncated"):
        lzf_decompress(bytes([5]) + b"ab", 6)


# --------------------------------------------------------------------------------------
# PLY
# --------------------------------------------------------------------------------------


def test_ply_ascii_range_scan() -> None:
    path = data_file("stanford/bunny/data/bun000.ply")
    cloud = read_point_cloud(path)  # a range_grid element follows the vertices: not faces
    assert_valid(cloud, 40_256)
    assert cloud.normals is None and cloud.colors is None
    trimesh = pytest.importorskip("trimesh")
    reference = trimesh.load(str(path), process=False)
    np.testing.assert_array_equal(cloud.points, reference.vertices)


def test_ply_points_with_normals() -> None:
    cloud = read_point_cloud(data_file("stanford/armadillo/Armadillo_38294v.ply"), n_samples=5)
    assert_valid(cloud, 38_294)  # 'element face 0': a point cloud; n_samples is ignored
    assert_unit(cloud.normals, atol=1e-5)


@pytest.mark.parametrize(
    ("rel", "n_vertices"),
    [
        ("stanford/bunny/reconstruction/bun_zipper_res2.ply", 8_171),  # ASCII mesh
        ("stanford/dragon/dragon_spica_21790v.ply", 21_790),  # binary mesh
        ("modelnet/bathtub_0154.ply", 1_494),  # binary mesh
        ("modelnet/bed_fmr.off", 22_627),  # OFF mesh
    ],
)
def test_mesh_is_sampled_on_its_surface(rel: str, n_vertices: int) -> None:
    path = data_file(rel)
    cloud = read_point_cloud(path)
    assert_valid(cloud, max(10_000, n_vertices))
    assert_unit(cloud.normals, atol=1e-9)  # sampled points carry their triangle's normal

    small = read_point_cloud(path, n_samples=200, seed=3)
    assert_valid(small, 200)
    vertices, faces = trimesh_mesh(path)
    assert on_surface(small.points, vertices, faces).all()
    assert len(np.unique(small.points, axis=0)) == 200


def test_mesh_sampling_is_seeded() -> None:
    path = data_file("stanford/bunny/reconstruction/bun_zipper_res2.ply")
    a = load_points(path, n_samples=2_000, seed=7)
    b = load_points(path, n_samples=2_000, seed=7)
    c = load_points(path, n_samples=2_000, seed=8)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert a.shape == (2_000, 3) and a.dtype == np.float64


def test_mesh_sampling_is_uniform_by_area() -> None:
    path = data_file("modelnet/bathtub_0154.ply")
    vertices, faces = trimesh_mesh(path)
    points = load_points(path, n_samples=40_000, seed=0)
    # Split the bounding box in two along its longest axis; compare each half's share of
    # the samples with its share of the surface area (clipped triangles counted by centroid).
    axis = int(np.argmax(np.ptp(vertices, axis=0)))
    cut = np.median(vertices[:, axis])
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    area_share = area[tri.mean(axis=1)[:, axis] < cut].sum() / area.sum()
    sample_share = (points[:, axis] < cut).mean()
    assert abs(sample_share - area_share) < 0.03


def test_mesh_sampling_matches_datasets_sampler() -> None:
    """read_point_cloud and pointclm.datasets.shapes.sample_surface draw the same points."""
    path = data_file("stanford/dragon/dragon_spica_21790v.ply")
    shapes = pytest.importorskip("pointclm.datasets.shapes")
    vertices, faces = trimesh_mesh(path)
    expected = shapes.sample_surface(vertices, faces, 3_000, rng=11)
    np.testing.assert_array_equal(load_points(path, n_samples=3_000, seed=11), expected)


def _tiny_mesh_ply(fmt: str) -> bytes:
    """A unit square (one quad) and a triangle, with uchar colours: mixed polygon sizes."""
    verts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float32)
    colors = np.array(
        [[255, 0, 0], [255, 0, 0], [255, 0, 0], [255, 0, 0], [0, 0, 255]], dtype=np.uint8
    )
    faces = [[0, 1, 2, 3], [0, 1, 4]]
    header = (
        f"ply\nformat {fmt} 1.0\ncomment mixed polygons\nelement vertex 5\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode()
    if fmt == "ascii":
        rows = [
            " ".join(map(str, [*v.tolist(), *c.tolist()]))
            for v, c in zip(verts, colors, strict=True)
        ]
        rows += [" ".join(map(str, [len(f), *f])) for f in faces]
        return header + ("\n".join(rows) + "\n").encode()
    e = "<" if fmt == "binary_little_endian" else ">"
    rec = np.zeros(5, dtype=[("xyz", e + "f4", 3), ("rgb", "u1", 3)])
    rec["xyz"], rec["rgb"] = verts, colors
    body = rec.tobytes()
    for f in faces:
        body += struct.pack(f"{e}B{len(f)}i", len(f), *f)
    return header + body


def test_ply_ascii_and_binary_endians_agree(tmp_path: Path) -> None:
    clouds = []
    for fmt in ("ascii", "binary_little_endian", "binary_big_endian"):
        path = tmp_path / f"mixed_{fmt}.ply"
        path.write_bytes(_tiny_mesh_ply(fmt))
        clouds.append(read_point_cloud(path, n_samples=3_000, seed=5))
    for cloud in clouds:
        assert_valid(cloud, 3_000)
        np.testing.assert_array_equal(cloud.points, clouds[0].points)
        np.testing.assert_array_equal(cloud.colors, clouds[0].colors)
    pts = clouds[0].points
    on_quad = pts[:, 2] == 0
    # Areas 1 (quad) and 0.5 (triangle): two thirds of the samples on the quad, all red.
    assert abs(on_quad.mean() - 2 / 3) < 0.03
    assert clouds[0].colors is not None
    np.testing.assert_allclose(clouds[0].colors[on_quad], [[1, 0, 0]] * int(on_quad.sum()))
    assert (pts[on_quad, :2] >= 0).all() and (pts[on_quad, :2] <= 1).all()


# --------------------------------------------------------------------------------------
# Text, NumPy, Open3D features
# --------------------------------------------------------------------------------------


def test_npy_demo_fragment() -> None:
    path = data_file("3dmatch/geotransformer_demo/src.npy")
    cloud = read_point_cloud(path)
    assert_valid(cloud, 15_953)
    np.testing.assert_array_equal(cloud.points, np.load(path))


def test_text_formats(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 3))
    nrm = rng.normal(size=(50, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)

    xyz = tmp_path / "cloud.xyz"
    xyz.write_text("# x y z\n" + "\n".join(" ".join(f"{v:.17g}" for v in p) for p in pts))
    np.testing.assert_array_equal(load_points(xyz), pts)

    txt = tmp_path / "cloud.txt"
    rows = [", ".join(f"{v:.17g}" for v in [*p, *n]) for p, n in zip(pts, nrm, strict=True)]
    txt.write_text("\n".join(rows) + "\n\n")
    cloud = read_point_cloud(txt)
    assert_valid(cloud, 50)
    np.testing.assert_array_equal(cloud.normals, nrm)

    pts_file = tmp_path / "cloud.PTS"  # extension case does not matter
    pts_file.write_text("50\n" + "\n".join(" ".join(f"{v:.17g}" for v in p) for p in pts))
    np.testing.assert_array_equal(load_points(pts_file), pts)


def test_text_drops_nan_rows_keeping_normals_aligned(tmp_path: Path) -> None:
    path = tmp_path / "holes.xyz"
    path.write_text("0 0 0 0 0 1\nnan nan nan 1 0 0\n1 1 1 0 1 0\n2 inf 2 1 0 0\n3 3 3 nan 0 0\n")
    with pytest.warns(NonFinitePointsWarning, match=r"holes\.xyz: dropped 2 rows .*kept 3"):
        cloud = read_point_cloud(path)
    assert cloud.dropped == 2
    np.testing.assert_array_equal(cloud.points, [[0, 0, 0], [1, 1, 1], [3, 3, 3]])
    # A finite point with an unknown normal keeps its place; its normal is a zero row.
    np.testing.assert_array_equal(cloud.normals, [[0, 0, 1], [0, 1, 0], [0, 0, 0]])


def test_every_reader_drops_non_finite_rows_with_a_warning(tmp_path: Path) -> None:
    # One policy for files: rows with NaN/inf coordinates (a scanner's missing returns) are
    # dropped, and the reader says how many, whatever the format; a clean file says nothing.
    pts = np.arange(15, dtype=np.float64).reshape(5, 3)
    holes = pts.copy()
    holes[1, 0], holes[3, 2] = np.nan, -np.inf
    paths = {".npy": tmp_path / "a.npy", ".xyz": tmp_path / "a.xyz", ".pcd": tmp_path / "a.pcd"}
    np.save(paths[".npy"], holes)
    paths[".xyz"].write_text("\n".join(" ".join(str(v) for v in row) for row in holes))
    paths[".pcd"].write_bytes(
        _pcd_header("x y z", "8 8 8", "F F F", 5, "ascii")
        + "\n".join(" ".join(str(v) for v in row) for row in holes).encode()
    )
    for path in paths.values():
        with pytest.warns(NonFinitePointsWarning) as caught:
            cloud = read_point_cloud(path)
        assert len(caught) == 1 and str(caught[0].message).startswith(f"{path}: dropped 2 rows")
        assert cloud.dropped == 2
        np.testing.assert_array_equal(cloud.points, pts[[0, 2, 4]])
    # A mesh's NaN vertex: dropped too (no triangle touching it is sampled), and said.
    mesh = tmp_path / "m.ply"
    mesh.write_bytes(
        _tiny_mesh_ply("ascii").replace(b"\n0.0 0.0 1.0 0 0 255", b"\nnan 0.0 1.0 0 0 255")
    )
    with pytest.warns(NonFinitePointsWarning, match="m.ply: dropped 1 row "):
        cloud = read_point_cloud(mesh, n_samples=200)
    assert cloud.dropped == 1 and np.allclose(cloud.points[:, 2], 0.0)
    # Clean files: no warning at all; a file of NaN alone is still an error.
    clean = tmp_path / "clean.xyz"
    clean.write_text("0 0 0\n1 1 1\n2 2 3\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_point_cloud(clean).dropped == 0
    (tmp_path / "nan.xyz").write_text("nan nan nan\n")
    with pytest.raises(ValueError, match="no points with finite coordinates"):
        read_point_cloud(tmp_path / "nan.xyz")


def test_arrays_with_nan_raise_rather_than_being_cleaned() -> None:
    import pointclm
    from pointclm.errors import InputError

    model = np.random.default_rng(0).normal(size=(200, 3))
    scan = model.copy()
    scan[7, 1] = np.nan
    with pytest.raises(InputError, match="non-finite value"):
        pointclm.register_point_clouds(model, scan)


def test_npz_and_npy_variants(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(20, 3))
    nrm = np.tile([0.0, 0.0, 1.0], (20, 1))
    colors = rng.integers(0, 256, size=(20, 3), dtype=np.uint8)

    np.savez(tmp_path / "keyed.npz", points=pts, normals=nrm, colors=colors)
    cloud = read_point_cloud(tmp_path / "keyed.npz")
    np.testing.assert_array_equal(cloud.points, pts)
    np.testing.assert_array_equal(cloud.normals, nrm)
    assert cloud.colors is not None
    np.testing.assert_allclose(cloud.colors, colors / 255.0)

    np.savez(tmp_path / "single.npz", anything=pts.astype(np.float32))
    np.testing.assert_array_equal(load_points(tmp_path / "single.npz"), pts.astype(np.float32))

    np.save(tmp_path / "six.npy", np.hstack([pts, nrm]))
    cloud = read_point_cloud(tmp_path / "six.npy")
    np.testing.assert_array_equal(cloud.normals, nrm)

    np.savez(tmp_path / "ambiguous.npz", a=pts, b=pts)
    with pytest.raises(ValueError, match="'points'"):
        read_point_cloud(tmp_path / "ambiguous.npz")
    np.save(tmp_path / "flat.npy", pts.ravel())
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        read_point_cloud(tmp_path / "flat.npy")


def test_open3d_feature() -> None:
    feats = read_open3d_feature(data_file("3dmatch/open3d_feature/cloud_bin_0.fpfh.bin"))
    assert feats.shape == (3_903, 33) and feats.dtype == np.float64
    assert feats.flags.c_contiguous and feats.flags.writeable
    assert np.isfinite(feats).all() and feats.min() >= 0
    # FPFH is three 11-bin histograms, each normalised to 100: true only if rows are points.
    sums = feats.reshape(-1, 3, 11).sum(axis=2)
    np.testing.assert_allclose(sums, 100.0, atol=1e-3)
    other = read_open3d_feature(data_file("3dmatch/open3d_feature/cloud_bin_1.fpfh.bin"))
    assert other.shape == (3_458, 33)


def test_open3d_feature_errors(tmp_path: Path) -> None:
    path = tmp_path / "short.bin"
    path.write_bytes(struct.pack("<ii", 33, 10) + b"\0" * (33 * 9 * 8))
    with pytest.raises(ValueError, match="truncated") as info:
        read_open3d_feature(path)
    assert str(path) in str(info.value)
    with pytest.raises(FileNotFoundError):
        read_open3d_feature(tmp_path / "absent.bin")


# --------------------------------------------------------------------------------------
# write_ply
# --------------------------------------------------------------------------------------


def test_write_ply_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(300, 3)) * 1e5  # large coordinates survive (stored as double)
    nrm = rng.normal(size=(300, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    colors = rng.random((300, 3))
    path = tmp_path / "out.ply"
    write_ply(path, pts, colors=colors, normals=nrm)

    cloud = read_point_cloud(path)
    np.testing.assert_array_equal(cloud.points, pts)
    np.testing.assert_array_equal(cloud.normals, nrm)
    assert cloud.colors is not None
    np.testing.assert_allclose(cloud.colors, np.round(colors * 255) / 255)

    write_ply(tmp_path / "again.ply", cloud)  # a PointCloud carries its attributes
    again = read_point_cloud(tmp_path / "again.ply")
    np.testing.assert_array_equal(again.points, cloud.points)
    np.testing.assert_array_equal(again.colors, cloud.colors)

    write_ply(tmp_path / "plain.ply", pts[:, :3])
    plain = read_point_cloud(tmp_path / "plain.ply")
    assert plain.normals is None and plain.colors is None

    trimesh = pytest.importorskip("trimesh")
    loaded = trimesh.load(str(path))
    np.testing.assert_array_equal(np.asarray(loaded.vertices), pts)
    np.testing.assert_array_equal(
        np.asarray(loaded.colors)[:, :3], np.round(colors * 255).astype(np.uint8)
    )


def test_write_ply_rejects_bad_input(tmp_path: Path) -> None:
    path = tmp_path / "bad.ply"
    with pytest.raises(ValueError, match="finite"):
        write_ply(path, np.array([[0.0, np.nan, 0.0]]))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        write_ply(path, np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        write_ply(path, np.zeros((1, 3)), colors=np.full((1, 3), 2.0))
    with pytest.raises(ValueError, match="shape"):
        write_ply(path, np.zeros((2, 3)), normals=np.zeros((3, 3)))


# --------------------------------------------------------------------------------------
# Errors
# --------------------------------------------------------------------------------------


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nowhere.ply"
    with pytest.raises(FileNotFoundError) as info:
        read_point_cloud(path)
    assert str(path) in str(info.value)
    with pytest.raises(FileNotFoundError):
        load_points(tmp_path / "nowhere.obj")  # missing wins over an unsupported extension


@pytest.mark.parametrize("suffix", SUPPORTED_SUFFIXES)
def test_empty_file(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"empty{suffix}"
    path.write_bytes(b"")
    with pytest.raises(ValueError, match="empty") as info:
        read_point_cloud(path)
    assert str(path) in str(info.value)


def test_unknown_extension(tmp_path: Path) -> None:
    path = tmp_path / "cloud.obj"
    path.write_text("v 0 0 0\n")
    with pytest.raises(ValueError, match="unsupported file extension") as info:
        read_point_cloud(path)
    message = str(info.value)
    assert str(path) in message and ".ply" in message and ".pcd" in message


def test_truncated_binary_ply(tmp_path: Path) -> None:
    path = tmp_path / "cut.ply"
    write_ply(path, np.random.default_rng(3).normal(size=(100, 3)))
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) - 20])
    with pytest.raises(ValueError, match="truncated") as info:
        read_point_cloud(path)
    assert str(path) in str(info.value)


def test_truncated_binary_mesh_ply(tmp_path: Path) -> None:
    raw = data_file("stanford/dragon/dragon_spica_21790v.ply").read_bytes()
    path = tmp_path / "dragon_cut.ply"
    path.write_bytes(raw[: len(raw) - 1000])  # inside the face list
    with pytest.raises(ValueError, match="truncated"):
        read_point_cloud(path)


def test_truncated_ascii_ply(tmp_path: Path) -> None:
    raw = data_file("stanford/bunny/reconstruction/bun_zipper_res2.ply").read_bytes()
    path = tmp_path / "bunny_cut.ply"
    path.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ValueError, match="truncated") as info:
        read_point_cloud(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize("rel", ["pcl/milk.pcd", "3dmatch/open3d_feature/cloud_bin_0.pcd"])
def test_truncated_pcd(tmp_path: Path, rel: str) -> None:
    raw = data_file(rel).read_bytes()
    path = tmp_path / Path(rel).name
    path.write_bytes(raw[: len(raw) // 2])  # binary_compressed / binary
    with pytest.raises(ValueError, match="truncated") as info:
        read_point_cloud(path)
    assert str(path) in str(info.value)


def test_truncated_off(tmp_path: Path) -> None:
    raw = data_file("modelnet/bed_fmr.off").read_bytes()
    path = tmp_path / "bed_cut.off"
    path.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ValueError, match="truncated"):
        read_point_cloud(path)


def test_wrong_content_for_extension(tmp_path: Path) -> None:
    for name, content, expected in [
        ("noise.ply", bytes(range(256)) * 4, "not a PLY file"),
        ("noise.pcd", b"\x00\x01\x02 garbage\n" * 4, "not a PCD file"),
        ("noise.off", b"PLY 1 2\n", "not an OFF file"),
        ("noise.npy", b"not numpy at all", "not a readable .npy"),
        ("noise.npz", b"not a zip archive", "not a readable .npz"),
        ("four.xyz", b"1 2 3 4\n5 6 7 8\n", "3 .x y z. or 6"),
        ("words.txt", b"x y z\n1 2 3\n", "malformed"),
    ]:
        path = tmp_path / name
        path.write_bytes(content)
        with pytest.raises(ValueError, match=expected) as info:
            read_point_cloud(path)
        assert str(path) in str(info.value)


def test_all_nan_cloud(tmp_path: Path) -> None:
    text = tmp_path / "nan.xyz"
    text.write_text("nan nan nan\nnan 1 2\n")
    npy = tmp_path / "nan.npy"
    np.save(npy, np.full((5, 3), np.nan))
    ply = tmp_path / "nan.ply"
    ply.write_bytes(
        b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
        b"property float z\nend_header\nnan nan nan\ninf 0 0\n"
    )
    pcd = tmp_path / "nan.pcd"
    pcd.write_bytes(_pcd_header("x y z", "4 4 4", "F F F", 2, "ascii") + b"nan nan nan\n" * 2)
    for path in (text, npy, ply, pcd):
        with pytest.raises(ValueError, match="no points with finite coordinates") as info:
            read_point_cloud(path)
        assert str(path) in str(info.value)


def test_bad_n_samples() -> None:
    path = data_file("modelnet/bathtub_0154.ply")
    with pytest.raises(ValueError, match="n_samples"):
        read_point_cloud(path, n_samples=0)
    with pytest.raises(ValueError, match="n_samples"):
        read_point_cloud(path, n_samples=2.5)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="n_samples"):
        read_point_cloud(path, n_samples=10**12)


def test_point_cloud_validates() -> None:
    with pytest.raises(ValueError, match="finite"):
        PointCloud(np.array([[0.0, 0.0, np.nan]]))
    with pytest.raises(ValueError, match="shape"):
        PointCloud(np.zeros((3, 3)), normals=np.zeros((2, 3)))
    cloud = PointCloud(np.asfortranarray(np.ones((4, 3), dtype=np.float32)))
    assert cloud.points.dtype == np.float64 and cloud.points.flags.c_contiguous
    assert repr(cloud) == "PointCloud(4 points)"


def test_readers_need_only_numpy(monkeypatch: pytest.MonkeyPatch) -> None:
    """What `pip install pointclm` (no extras) gets: every format, no trimesh/scipy import."""
    for name in ("trimesh", "scipy", "open3d", "pypcd4", "lzf", "h5py"):
        monkeypatch.setitem(sys.modules, name, None)  # any import of it now fails
    for rel in (
        "stanford/dragon/dragon_spica_21790v.ply",
        "stanford/armadillo/Armadillo_38294v.ply",
        "modelnet/bed_fmr.off",
        "pcl/milk.pcd",
    ):
        assert_valid(read_point_cloud(data_file(rel), n_samples=100))


def test_datasets_read_meshes_through_io_without_trimesh(monkeypatch: pytest.MonkeyPatch) -> None:
    """One mesh path: load_shape/load_mesh read PLY and OFF with pointclm.io, not trimesh."""
    from pointclm.datasets import load_mesh, load_shape
    from pointclm.io import read_mesh

    monkeypatch.setitem(sys.modules, "trimesh", None)  # any import of it now fails
    for rel in ("stanford/bunny/reconstruction/bun_zipper_res4.ply", "modelnet/bed_fmr.off"):
        mesh = read_mesh(data_file(rel))
        verts, faces = load_mesh(data_file(rel))
        np.testing.assert_array_equal(verts, mesh.vertices)
        np.testing.assert_array_equal(faces, mesh.triangles)
        assert load_shape(data_file(rel), 100).shape == (100, 3)


def test_read_mesh_and_the_one_sampler(tmp_path: Path) -> None:
    """read_mesh returns triangles unsampled; read_point_cloud, sample_mesh and
    datasets.sample_surface draw the same points from a seed."""
    from pointclm.datasets import sample_surface
    from pointclm.io import read_mesh, sample_mesh

    path = tmp_path / "quad.off"
    path.write_text("OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n")
    mesh = read_mesh(path)
    np.testing.assert_array_equal(mesh.triangles, [[0, 1, 2], [0, 2, 3]])
    expected = sample_mesh(mesh.vertices, mesh.triangles, 500, seed=3).points
    np.testing.assert_array_equal(read_point_cloud(path, n_samples=500, seed=3).points, expected)
    np.testing.assert_array_equal(sample_surface(mesh.vertices, mesh.triangles, 500, 3), expected)
    with pytest.raises(FileNotFoundError, match="no such file"):
        read_mesh(tmp_path / "missing.ply")
    (tmp_path / "quad.xyz").write_text("0 0 0\n")
    with pytest.raises(ValueError, match="unsupported file type"):
        read_mesh(tmp_path / "quad.xyz")
    obj = tmp_path / "tri.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    pytest.importorskip("trimesh")  # the optional fallback for formats io does not parse
    np.testing.assert_array_equal(read_mesh(obj).triangles, [[0, 1, 2]])


def test_face_index_out_of_range(tmp_path: Path) -> None:
    path = tmp_path / "broken.off"
    path.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 99\n")
    with pytest.raises(ValueError, match="vertex index 99") as info:
        read_point_cloud(path)
    assert str(path) in str(info.value)

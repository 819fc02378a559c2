"""Scanner files through pointclm.io: LAS and LAZ written with laspy, E57 with pye57, read
back by extension; damaged files are ValueErrors naming the file, and a missing library
names the extra to install."""

from __future__ import annotations

import io
import struct
import sys
import warnings

import numpy as np
import pointclm
import pytest
from pointclm.io import SUPPORTED_SUFFIXES, NonFinitePointsWarning, read_point_cloud
from pointclm.io.scanner import LAZ_MAX_POINTS_PER_BYTE


def _points(n: int = 500, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-20.0, 20.0, (n, 3))


def _las_bytes(points: np.ndarray, *, compress: bool, rgb: np.ndarray | None = None) -> bytes:
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=3 if rgb is not None else 1, version="1.2")
    header.scales = [0.001] * 3
    header.offsets = [100.0, -50.0, 10.0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = (points + [100.0, -50.0, 10.0]).T
    if rgb is not None:
        las.red, las.green, las.blue = rgb.T
    out = io.BytesIO()
    las.write(out, do_compress=compress)
    return out.getvalue()


def _needs_laz() -> None:
    laspy = pytest.importorskip("laspy")
    if not laspy.LazBackend.detect_available():
        pytest.skip("no LAZ backend for laspy (pip install 'laspy[lazrs]')")


def test_scanner_extensions_are_supported():
    assert {".las", ".laz", ".e57"} <= set(SUPPORTED_SUFFIXES)


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_las_and_laz_read_back_with_scale_offset_and_colour(tmp_path, suffix):
    if suffix == ".laz":
        _needs_laz()
    pts = _points()
    rgb = (np.arange(len(pts))[:, None] * [1, 7, 13] % 65536).astype(np.uint16)
    path = tmp_path / f"scan{suffix}"
    path.write_bytes(_las_bytes(pts, compress=suffix == ".laz", rgb=rgb))
    cloud = read_point_cloud(path)
    # Stored as integers of 1 mm: read back to half a millimetre, offset added back.
    np.testing.assert_allclose(cloud.points, pts + [100.0, -50.0, 10.0], atol=5e-4 + 1e-9)
    assert cloud.colors is not None
    np.testing.assert_allclose(cloud.colors, rgb / 65535.0)
    assert cloud.normals is None and cloud.dropped == 0


def test_eight_bit_colours_in_las_are_scaled_by_255(tmp_path):
    pts = _points(50)
    rgb = np.tile(np.array([[255, 128, 0]], dtype=np.uint16), (50, 1))
    path = tmp_path / "rgb8.las"
    path.write_bytes(_las_bytes(pts, compress=False, rgb=rgb))
    np.testing.assert_allclose(
        read_point_cloud(path).colors, np.tile([1.0, 128 / 255, 0.0], (50, 1))
    )


def test_register_point_clouds_takes_a_las_path(tmp_path):
    pts = _points(400)
    path = tmp_path / "cloud.las"
    path.write_bytes(_las_bytes(pts, compress=False))
    loaded = pointclm.io.load_points(path)
    assert loaded.shape == (400, 3)


def test_truncated_las_names_the_file_and_both_sizes(tmp_path):
    raw = _las_bytes(_points(), compress=False)
    path = tmp_path / "cut.las"
    path.write_bytes(raw[: len(raw) - 100])
    with pytest.raises(ValueError, match=r"cut\.las: truncated: the header declares 500 points"):
        read_point_cloud(path)


def test_las_header_claiming_billions_of_points_is_refused_before_reading(tmp_path):
    raw = bytearray(_las_bytes(_points(10), compress=False))
    # LAS 1.2: the legacy point count is the uint32 at byte 107.
    struct.pack_into("<I", raw, 107, 4_000_000_000)
    path = tmp_path / "liar.las"
    path.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match=r"liar\.las: truncated: the header declares 4000000000"):
        read_point_cloud(path)


def test_laz_declaring_more_points_than_it_can_hold_is_refused(tmp_path):
    _needs_laz()
    raw = bytearray(_las_bytes(_points(10), compress=True))
    struct.pack_into("<I", raw, 107, LAZ_MAX_POINTS_PER_BYTE * len(raw) + 1)
    path = tmp_path / "liar.laz"
    path.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match=r"liar\.laz: the header declares .* more than"):
        read_point_cloud(path)


@pytest.mark.parametrize("suffix", [".las", ".laz", ".e57"])
@pytest.mark.parametrize("content", [b"", b"not a scanner file at all" * 4, b"LASF" + bytes(300)])
def test_empty_and_garbage_files_are_value_errors_naming_the_file(tmp_path, suffix, content):
    pytest.importorskip("pye57" if suffix == ".e57" else "laspy")
    path = tmp_path / f"bad{suffix}"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=rf"bad\{suffix}"):
        read_point_cloud(path)


def test_truncated_laz_is_a_value_error(tmp_path):
    _needs_laz()
    raw = _las_bytes(_points(2000), compress=True)
    path = tmp_path / "cut.laz"
    path.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ValueError, match=r"cut\.laz"):
        read_point_cloud(path)


def _write_e57(path, scans) -> None:
    pye57 = pytest.importorskip("pye57")
    e57 = pye57.E57(str(path), mode="w")
    for data, translation in scans:
        e57.write_scan_raw(data, rotation=np.array([1.0, 0, 0, 0]), translation=translation)
    e57.close()


def test_e57_scans_are_moved_into_the_file_frame_and_invalid_points_dropped(tmp_path):
    a, b = _points(300, 1), _points(200, 2)
    invalid = (np.arange(300) % 10 == 0).astype(np.int8)
    scan_a = {
        "cartesianX": a[:, 0],
        "cartesianY": a[:, 1],
        "cartesianZ": a[:, 2],
        "cartesianInvalidState": invalid,
    }
    scan_b = {"cartesianX": b[:, 0], "cartesianY": b[:, 1], "cartesianZ": b[:, 2]}
    path = tmp_path / "site.e57"
    _write_e57(path, [(scan_a, np.zeros(3)), (scan_b, np.array([5.0, 0.0, -1.0]))])
    with pytest.warns(NonFinitePointsWarning, match="dropped 30 rows"):
        cloud = read_point_cloud(path)
    expected = np.vstack([a[invalid == 0], b + [5.0, 0.0, -1.0]])
    # pye57 applies the pose in its own arithmetic: micrometres on coordinates of 20 m.
    np.testing.assert_allclose(cloud.points, expected, atol=1e-5)
    assert cloud.dropped == 30 and cloud.colors is None


def test_e57_colours_come_along(tmp_path):
    pts = _points(100)
    rgb = (np.arange(300).reshape(100, 3) % 256).astype(np.uint8)
    data = {
        "cartesianX": pts[:, 0],
        "cartesianY": pts[:, 1],
        "cartesianZ": pts[:, 2],
        "colorRed": rgb[:, 0],
        "colorGreen": rgb[:, 1],
        "colorBlue": rgb[:, 2],
    }
    path = tmp_path / "colour.e57"
    _write_e57(path, [(data, np.zeros(3))])
    with warnings.catch_warnings():
        warnings.simplefilter("error", NonFinitePointsWarning)
        cloud = read_point_cloud(path)
    np.testing.assert_allclose(cloud.points, pts, atol=1e-9)
    np.testing.assert_allclose(cloud.colors, rgb / 255.0)


@pytest.mark.parametrize("keep", [0.5, 0.1])
def test_truncated_e57_is_a_value_error(tmp_path, keep):
    path = tmp_path / "full.e57"
    pts = _points(2000)
    _write_e57(
        path, [({"cartesianX": pts[:, 0], "cartesianY": pts[:, 1], "cartesianZ": pts[:, 2]}, None)]
    )
    raw = path.read_bytes()
    cut = tmp_path / "cut.e57"
    cut.write_bytes(raw[: int(len(raw) * keep)])
    with pytest.raises(ValueError, match=r"cut\.e57: not a valid E57 file"):
        read_point_cloud(cut)


@pytest.mark.parametrize(("suffix", "module"), [(".las", "laspy"), (".e57", "pye57")])
def test_a_missing_library_names_the_extra(tmp_path, monkeypatch, suffix, module):
    path = tmp_path / f"scan{suffix}"
    path.write_bytes(b"anything")
    monkeypatch.setitem(sys.modules, module, None)  # import now fails as if not installed
    with pytest.raises(ImportError, match=r"pip install 'pointclm\[io\]'"):
        read_point_cloud(path)


def test_missing_scanner_file_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_point_cloud(tmp_path / "nothing.e57")

"""Organised frames: an (H, W, 3) scan array or an organised PCD file is a depth frame in its
sensor's coordinates, so its sensor, the origin, is the viewpoint unless the caller gives one;
pixels without a return (NaN, infinite, zero) are dropped and the caller's array is left as
it was."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pointclm
import pytest
from pointclm.clouds.scans import BY_FRAME, frame_points, read_scan
from pointclm.datasets.cameras import Camera
from pointclm.datasets.sensed import SensedSceneParams, make_sensed_scene
from pointclm.point_clouds import file_viewpoint


@pytest.fixture(scope="module")
def scene():
    camera = Camera(320, 240, 262.5, 262.5, 159.5, 119.5, 0.6)
    params = SensedSceneParams(parts=("bunny",), layout="pile", copies=(3, 4), camera=camera)
    return make_sensed_scene(0, params)


def test_a_frame_is_judged_from_its_sensor_and_left_as_it_was(scene) -> None:
    frame = scene.frame.copy()
    frame[0, :5] = 0.0  # a camera that writes zeros for a missing return
    frame[1, :5] = np.inf
    before = frame.copy()
    got = pointclm.register_point_clouds(scene.models[0], frame, seed=0)
    np.testing.assert_array_equal(frame, before)
    assert list(got.viewpoint) == [0.0, 0.0, 0.0]
    assert BY_FRAME in got.orientation
    points = frame_points(frame)
    assert len(points) == np.isfinite(scene.frame).all(axis=2).sum() - 10
    assert np.isfinite(points).all() and points.any(axis=1).all()
    # The same as the returns with the origin given: the frame only states the viewpoint.
    given = pointclm.register_point_clouds(scene.models[0], points, seed=0, viewpoint=(0, 0, 0))
    assert len(got.instances) == len(given.instances) >= 1
    for a, b in zip(got.instances, given.instances, strict=True):
        np.testing.assert_allclose(a.transformation, b.transformation, atol=1e-12)


def test_the_callers_viewpoint_wins_over_the_frames() -> None:
    frame = np.random.default_rng(0).normal(size=(4, 5, 3)) + [0, 0, 2]
    scan = read_scan(frame, (1.0, 2.0, 3.0))
    assert scan.viewpoint == (1.0, 2.0, 3.0) and scan.stated_by == ""
    assert scan.points.shape == (20, 3)
    assert read_scan(frame, None).viewpoint == (0.0, 0.0, 0.0)
    # An (N, 3) array states nothing.
    assert read_scan(frame.reshape(-1, 3), None).viewpoint is None


@pytest.mark.parametrize("fill", [np.nan, 0.0, -np.inf])
def test_a_frame_without_a_return_is_a_clear_error(fill: float) -> None:
    with pytest.raises(ValueError, match="organised frame .* holds no return"):
        pointclm.register_point_clouds(np.eye(3), np.full((4, 6, 3), fill))


def test_an_organised_pcd_file_states_the_origin(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    points = rng.normal(size=(12, 3)) + [0, 0, 1]
    flat, organised = tmp_path / "flat.pcd", tmp_path / "organised.pcd"
    body = "".join(f"{x} {y} {z}\n" for x, y, z in points)
    for path, (width, height) in ((flat, (12, 1)), (organised, (4, 3))):
        path.write_text(
            "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
            f"WIDTH {width}\nHEIGHT {height}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 12\n"
            f"DATA ascii\n{body}"
        )
    assert file_viewpoint(flat) is None
    np.testing.assert_array_equal(file_viewpoint(organised), np.zeros(3))
    scan = read_scan(organised, None)
    assert scan.viewpoint == (0.0, 0.0, 0.0) and scan.stated_by == BY_FRAME
    assert read_scan(flat, None).viewpoint is None


def test_several_models_take_a_frame(scene) -> None:
    got = pointclm.register_models([scene.models[0]], scene.frame, seed=0)
    assert list(got[0].viewpoint) == [0.0, 0.0, 0.0] and got[0].instances

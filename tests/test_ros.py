"""ROS 2 without ROS: PointCloud2 messages built here from bytes (and a real Kinect frame)
read as the numpy path reads them; Detection3DArray built as dicts, as rosbags messages
that serialise, and as rclpy-style objects."""

from __future__ import annotations

import importlib.machinery
import sys
import types
from types import SimpleNamespace

import numpy as np
import pytest
from helpers import DATA, needs_data
from pointclm.io import read_point_cloud
from pointclm.ros import (
    UNKNOWN_COVARIANCE,
    add_vision_msgs,
    detection3d_array,
    parse_pointcloud2,
    read_pointcloud2,
)

FLOAT32, FLOAT64, UINT32, UINT16 = 7, 8, 6, 4


def _field(name: str, offset: int, datatype: int, count: int = 1) -> dict:
    return {"name": name, "offset": offset, "datatype": datatype, "count": count}


def _message(
    table: np.ndarray, fields: list[dict], *, height: int = 1, row_pad: int = 0, big: bool = False
) -> dict:
    """A PointCloud2 dict whose data is `table` (a structured array, one record per point),
    laid out in `height` rows with `row_pad` bytes of padding after each."""
    width = len(table) // height
    step = table.dtype.itemsize
    rows = table.tobytes()
    data = b"".join(
        rows[r * width * step : (r + 1) * width * step] + b"\xee" * row_pad for r in range(height)
    )
    return {
        "height": height,
        "width": width,
        "fields": fields,
        "is_bigendian": big,
        "point_step": step,
        "row_step": width * step + row_pad,
        "data": data,
        "is_dense": False,
    }


def _xyz_table(
    points: np.ndarray,
    *,
    order: str = "<",
    kind: str = "f4",
    pad: int = 4,
    normals: np.ndarray | None = None,
) -> tuple[np.ndarray, list[dict]]:
    size = np.dtype(kind).itemsize
    datatype = FLOAT32 if kind == "f4" else FLOAT64
    names = ["x", "y", "z"] + (["normal_x", "normal_y", "normal_z"] if normals is not None else [])
    offsets = [i * size for i in range(3)] + [3 * size + pad + i * size for i in range(3)]
    spec = {
        "names": names + ["intensity"],
        "formats": [order + kind] * len(names) + [order + "u2"],
        "offsets": offsets[: len(names)] + [offsets[len(names) - 1] + size],
        "itemsize": offsets[len(names) - 1] + size + 2 + 6,  # trailing padding
    }
    table = np.zeros(len(points), np.dtype(spec))
    for i, n in enumerate("xyz"):
        table[n] = points[:, i]
    if normals is not None:
        for i, n in enumerate(names[3:]):
            table[n] = normals[:, i]
    table["intensity"] = np.arange(len(points)) % 65535
    fields = [_field(n, o, datatype) for n, o in zip(names, offsets, strict=False)]
    fields.append(_field("intensity", spec["offsets"][-1], UINT16))
    return table, fields


def test_unorganised_float32_cloud_reads_as_numpy_does():
    pts = np.random.default_rng(0).normal(size=(1000, 3))
    table, fields = _xyz_table(pts)
    cloud = read_pointcloud2(_message(table, fields))
    np.testing.assert_array_equal(cloud.points, pts.astype(np.float32).astype(np.float64))
    assert cloud.normals is None and cloud.colors is None and cloud.dropped == 0


@pytest.mark.parametrize("order", ["<", ">"])
def test_float64_with_normals_in_either_byte_order(order):
    rng = np.random.default_rng(1)
    pts, nrm = rng.normal(size=(300, 3)), rng.normal(size=(300, 3))
    table, fields = _xyz_table(pts, order=order, kind="f8", pad=8, normals=nrm)
    cloud = read_pointcloud2(_message(table, fields, big=order == ">"))
    np.testing.assert_array_equal(cloud.points, pts)
    np.testing.assert_array_equal(cloud.normals, nrm)


def test_the_byte_order_flag_is_obeyed():
    # The same bytes flagged the other way are other numbers (here tiny denormals).
    pts = np.tile([[1.5, -2.25, 3.0]], (10, 1))
    table, fields = _xyz_table(pts, kind="f8")
    msg = _message(table, fields)
    np.testing.assert_array_equal(read_pointcloud2(msg).points, pts)
    swapped = read_pointcloud2({**msg, "is_bigendian": True}).points
    assert np.all(np.abs(swapped) < 1e-300)


def test_organised_frame_with_row_padding_drops_nan_returns_with_a_count():
    # A 12 x 16 depth image back-projected through a pinhole; every 5th pixel has no return.
    h, w, f = 12, 16, 20.0
    v, u = np.mgrid[0:h, 0:w]
    depth = 1.0 + 0.01 * u + 0.02 * v
    pts = np.stack([(u - w / 2) / f * depth, (v - h / 2) / f * depth, depth], -1).reshape(-1, 3)
    missing = np.arange(h * w) % 5 == 0
    pts[missing] = np.nan
    table, fields = _xyz_table(pts)
    cloud = read_pointcloud2(_message(table, fields, height=h, row_pad=24))
    np.testing.assert_array_equal(cloud.points, pts[~missing].astype(np.float32))
    assert cloud.dropped == int(missing.sum())


def test_raw_bytes_and_layout_without_a_message():
    pts = np.random.default_rng(4).normal(size=(30, 3))
    table, fields = _xyz_table(pts)
    cloud = parse_pointcloud2(
        table.tobytes(), fields=fields, height=3, width=10, point_step=table.dtype.itemsize
    )
    np.testing.assert_array_equal(cloud.points, pts.astype(np.float32))


def test_message_objects_are_read_like_dicts():
    pts = np.random.default_rng(3).normal(size=(40, 3))
    table, fields = _xyz_table(pts)
    msg = _message(table, fields)
    as_object = SimpleNamespace(**{**msg, "fields": [SimpleNamespace(**f) for f in fields]})
    as_uint8 = {**msg, "data": np.frombuffer(msg["data"], np.uint8)}
    as_list = {**msg, "data": list(msg["data"])}
    expected = read_pointcloud2(msg).points
    for variant in (as_object, as_uint8, as_list):
        np.testing.assert_array_equal(read_pointcloud2(variant).points, expected)


def test_packed_rgb_is_read_as_pcl_packs_it():
    table = np.zeros(
        2,
        np.dtype(
            {
                "names": ["x", "y", "z", "rgb"],
                "formats": ["<f4"] * 3 + ["<u4"],
                "offsets": [0, 4, 8, 16],
                "itemsize": 32,
            }
        ),
    )
    table["x"] = [1, 2]
    table["rgb"] = [0x00FF8000, 0x000000FF]
    fields = [
        _field("x", 0, FLOAT32),
        _field("y", 4, FLOAT32),
        _field("z", 8, FLOAT32),
        _field("rgb", 16, FLOAT32),
    ]
    cloud = read_pointcloud2(_message(table, fields))
    np.testing.assert_allclose(cloud.colors, [[1, 128 / 255, 0], [0, 0, 1]])


def _good() -> dict:
    table, fields = _xyz_table(np.ones((4, 3)))
    return _message(table, fields)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda m: m.update(data=m["data"][:-1]), "data holds .* bytes"),
        (lambda m: m.update(data=m["data"] + b"\0" * 64), "does not describe this data"),
        (lambda m: m.update(row_step=4), "row_step 4 is shorter"),
        (lambda m: m.update(point_step=0), "point_step must be > 0"),
        (lambda m: m.update(height=-1), "height must be a non-negative int"),
        (lambda m: m.update(width=0, height=0, data=b""), "the cloud is empty"),
        (lambda m: m.update(fields=m["fields"][1:]), "no x field"),
        (lambda m: m["fields"][0].update(datatype=UINT16), "'x' has datatype 4"),
        (lambda m: m["fields"][0].update(offset=30), "does not fit in a point"),
        (lambda m: m["fields"][0].update(count=3), "'x' has count 3"),
        (lambda m: m["fields"].append(dict(m["fields"][0])), "appears twice"),
        (lambda m: m["fields"].append(_field("normal_x", 0, FLOAT32)), "normals need"),
        (lambda m: m.update(data=np.zeros(10, np.float32)), "bytes or uint8"),
        (lambda m: m.update(data=[300] * 8), r"\[0, 255\]"),
        (lambda m: m.pop("point_step"), "has no point_step"),
    ],
)
def test_bad_layouts_are_value_errors_saying_what_to_fix(change, match):
    msg = _good()
    change(msg)
    with pytest.raises(ValueError, match=match):
        read_pointcloud2(msg)


def test_all_nan_cloud_is_a_value_error():
    table, fields = _xyz_table(np.full((6, 3), np.nan))
    with pytest.raises(ValueError, match="all 6 points are NaN"):
        read_pointcloud2(_message(table, fields, height=2))


def _kinect_message() -> tuple[dict, object]:
    """PCL's organised 640 x 480 Kinect frame as PCL publishes a PointXYZRGBA cloud: x y z at
    0/4/8, rgba at 16, 32-byte points, NaN where the camera saw nothing."""
    from pointclm.io.pcd import _columns_compressed, _parse_header

    path = DATA / "pcl/milk_cartoon_all_small_clorox.pcd"
    raw = path.read_bytes()
    header = _parse_header(raw)
    columns = {
        f.name: c[:, 0]
        for f, c in zip(header.fields, _columns_compressed(raw, header), strict=True)
    }
    layout = np.dtype(
        {
            "names": ["x", "y", "z", "rgba"],
            "formats": ["<f4"] * 3 + ["<u4"],
            "offsets": [0, 4, 8, 16],
            "itemsize": 32,
        }
    )
    table = np.zeros(640 * 480, layout)
    for name in layout.names:
        table[name] = columns[name]
    fields = [
        _field("x", 0, FLOAT32),
        _field("y", 4, FLOAT32),
        _field("z", 8, FLOAT32),
        _field("rgba", 16, UINT32),
    ]
    return _message(table, fields, height=480), path


@needs_data
def test_a_real_kinect_frame_gives_the_points_of_the_numpy_path():
    msg, path = _kinect_message()
    with pytest.warns(UserWarning):
        expected = read_point_cloud(path)
    cloud = read_pointcloud2(msg)
    assert len(cloud) == 241_407 == len(expected)
    np.testing.assert_array_equal(cloud.points, expected.points)
    np.testing.assert_array_equal(cloud.colors, expected.colors)
    assert cloud.dropped == 640 * 480 - 241_407 == expected.dropped


@needs_data
def test_a_rosbags_deserialised_kinect_message_reads_the_same():
    typesys = pytest.importorskip("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS2_HUMBLE)
    msg, _ = _kinect_message()
    ros = _rosbags_cloud(store, msg)
    raw = store.serialize_cdr(ros, ros.__msgtype__)
    back = store.deserialize_cdr(raw, ros.__msgtype__)
    np.testing.assert_array_equal(read_pointcloud2(back).points, read_pointcloud2(msg).points)


def _rosbags_cloud(store, msg: dict, stamp: int = 0, frame: str = "camera"):
    t = store.types
    return t["sensor_msgs/msg/PointCloud2"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9),
            frame_id=frame,
        ),
        height=msg["height"],
        width=msg["width"],
        fields=[t["sensor_msgs/msg/PointField"](**f) for f in msg["fields"]],
        is_bigendian=msg["is_bigendian"],
        point_step=msg["point_step"],
        row_step=msg["row_step"],
        data=np.frombuffer(msg["data"], np.uint8),
        is_dense=False,
    )


# --- Detection3DArray ---------------------------------------------------------------------


def _rotation(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _result(covariance: np.ndarray | None = None) -> SimpleNamespace:
    poses = []
    for k, deg in enumerate((30.0, 200.0)):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = _rotation(deg), [k, 2.0 * k, 0.5]
        poses.append(T)
    extra = {} if covariance is None else {"covariance": covariance}
    instances = [
        SimpleNamespace(transformation=poses[0], confidence=0.9, fitness=0.8, **extra),
        SimpleNamespace(transformation=poses[1], confidence=float("nan"), fitness=0.7, **extra),
    ]
    model = np.array([[0.0, 0, 0], [2, 1, 0.5]])  # box centre (1, 0.5, 0.25), size (2, 1, 0.5)
    return SimpleNamespace(instances=instances, source_points=model)


def test_detections_as_dicts_carry_class_score_pose_box_and_unknown_covariance():
    out = detection3d_array(
        _result(), class_id="bunny", frame_id="camera", stamp=12.25, output="dict"
    )
    assert out["header"] == {"stamp": {"sec": 12, "nanosec": 250_000_000}, "frame_id": "camera"}
    assert [d["id"] for d in out["detections"]] == ["0", "1"]
    first, second = (d["results"][0] for d in out["detections"])
    assert first["hypothesis"] == {"class_id": "bunny", "score": 0.9}
    assert second["hypothesis"]["score"] == 0.7  # no confidence: the fitness
    pose = first["pose"]["pose"]
    q = pose["orientation"]  # 30 degrees about z
    np.testing.assert_allclose(
        [q["x"], q["y"], q["z"], q["w"]],
        [0, 0, np.sin(np.radians(15)), np.cos(np.radians(15))],
        atol=1e-12,
    )
    assert (pose["position"]["x"], pose["position"]["y"], pose["position"]["z"]) == (0, 0, 0.5)
    assert first["pose"]["covariance"] == list(UNKNOWN_COVARIANCE)
    cov = np.array(UNKNOWN_COVARIANCE).reshape(6, 6)
    np.testing.assert_array_equal(np.diag(cov), -1.0)
    box = out["detections"][1]["bbox"]
    assert box["size"] == {"x": 2.0, "y": 1.0, "z": 0.5}
    centre = _rotation(200.0) @ [1, 0.5, 0.25] + [1, 2, 0.5]
    np.testing.assert_allclose([box["center"]["position"][a] for a in "xyz"], centre)


def test_an_instance_covariance_is_reordered_translation_first_row_major():
    # pointclm's order is (rx, ry, rz, x, y, z); ROS's is (x, y, z, rx, ry, rz).
    cov = np.arange(36.0).reshape(6, 6)
    out = detection3d_array(_result(cov), output="dict")
    ros = np.array(out["detections"][0]["results"][0]["pose"]["covariance"]).reshape(6, 6)
    assert ros[0, 0] == cov[3, 3] and ros[3, 3] == cov[0, 0]  # var x, var rx
    assert ros[0, 5] == cov[3, 2]  # cov(x, rz)
    assert ros[5, 0] == cov[2, 3]
    np.testing.assert_array_equal(ros[:3, :3], cov[3:, 3:])
    np.testing.assert_array_equal(ros[3:, 3:], cov[:3, :3])
    np.testing.assert_array_equal(ros[:3, 3:], cov[3:, :3])
    with pytest.raises(ValueError, match="covariance must be 6 x 6"):
        detection3d_array(_result(np.eye(3)), output="dict")


def test_the_header_of_the_scan_is_copied():
    header = {"stamp": {"sec": 5, "nanosec": 7}, "frame_id": "lidar"}
    out = detection3d_array(_result(), header=header, output="dict")
    assert out["header"] == header
    assert all(d["header"] == header for d in out["detections"])
    out["detections"][0]["header"]["frame_id"] = "changed"  # no shared objects
    assert out["header"]["frame_id"] == "lidar"


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"stamp": -1}, "stamp must be"),
        ({"stamp": (1, 10**9)}, "stamp must be"),
        ({"stamp": "noon"}, "stamp must be"),
        ({"frame_id": 3}, "frame_id must be a str"),
        ({"class_id": None}, "class_id must be a str"),
        ({"output": "xml"}, "output must be one of"),
    ],
)
def test_bad_detection_arguments_are_value_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        detection3d_array(_result(), **{"output": "dict", **kwargs})


def test_an_empty_result_gives_an_empty_array():
    out = detection3d_array(
        SimpleNamespace(instances=[], source_points=np.zeros((0, 3))), output="dict"
    )
    assert out["detections"] == []


def test_rosbags_messages_serialise_with_the_vision_msgs_definitions():
    typesys = pytest.importorskip("rosbags.typesys")
    store = add_vision_msgs(typesys.get_typestore(typesys.Stores.ROS2_HUMBLE))
    msg = detection3d_array(
        _result(np.eye(6)), class_id="bunny", stamp=3 * 10**9 + 5, frame_id="cam", typestore=store
    )
    name = "vision_msgs/msg/Detection3DArray"
    back = store.deserialize_cdr(store.serialize_cdr(msg, name), name)
    as_dict = detection3d_array(
        _result(np.eye(6)), class_id="bunny", stamp=3 * 10**9 + 5, frame_id="cam", output="dict"
    )
    assert back.header.stamp.sec == 3 and back.header.stamp.nanosec == 5
    for d, ref in zip(back.detections, as_dict["detections"], strict=True):
        hyp = d.results[0]
        assert hyp.hypothesis.class_id == "bunny"
        assert hyp.hypothesis.score == ref["results"][0]["hypothesis"]["score"]
        np.testing.assert_array_equal(hyp.pose.covariance, np.eye(6).ravel())
        assert hyp.pose.pose.orientation.w == ref["results"][0]["pose"]["pose"]["orientation"]["w"]
        assert d.bbox.size.x == ref["bbox"]["size"]["x"]


def test_rclpy_messages_are_built_when_ros_is_importable(monkeypatch):
    # A stand-in for a sourced ROS 2 environment: rclpy and each message package import,
    # their classes take the fields as keywords, as rclpy's generated classes do.
    class Msg:
        def __init__(self, **fields):
            self.__dict__.update(fields)

    for pkg, names in {
        "rclpy": [],
        "vision_msgs": [
            "Detection3DArray",
            "Detection3D",
            "ObjectHypothesisWithPose",
            "ObjectHypothesis",
            "BoundingBox3D",
        ],
        "geometry_msgs": ["Pose", "PoseWithCovariance", "Point", "Quaternion", "Vector3"],
        "std_msgs": ["Header"],
        "builtin_interfaces": ["Time"],
    }.items():
        top = types.ModuleType(pkg)
        top.__spec__ = importlib.machinery.ModuleSpec(pkg, None)
        sub = types.ModuleType(f"{pkg}.msg")
        for n in names:
            setattr(sub, n, type(n, (Msg,), {}))
        monkeypatch.setitem(sys.modules, pkg, top)
        monkeypatch.setitem(sys.modules, f"{pkg}.msg", sub)
    out = detection3d_array(_result(), class_id="part")
    assert type(out).__name__ == "Detection3DArray"
    hyp = out.detections[1].results[0]
    assert type(hyp.pose).__name__ == "PoseWithCovariance"
    assert hyp.hypothesis.class_id == "part" and hyp.hypothesis.score == 0.7
    assert isinstance(hyp.pose.covariance, np.ndarray) and hyp.pose.covariance.shape == (36,)


def test_rclpy_output_without_ros_names_what_is_missing(monkeypatch):
    monkeypatch.setitem(sys.modules, "rclpy", None)
    with pytest.raises(ImportError, match="rclpy and vision_msgs"):
        detection3d_array(_result(), output="rclpy")
    assert isinstance(detection3d_array(_result()), dict)  # "auto" falls back to dicts

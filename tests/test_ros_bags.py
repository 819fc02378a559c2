"""ROS bags written here with rosbags (rosbag2 MCAP and SQLite, ROS 1) as the scans of a
batch: one scan per PointCloud2 message, registered by `pointclm batch` as the arrays are."""

from __future__ import annotations

import json

import numpy as np
import pointclm
import pytest
from pointclm.cli import main
from pointclm.datasets.scenes import SceneParams, make_realistic_scene
from pointclm.errors import InputError
from pointclm.io import load_points, write_ply
from pointclm.ros import bag_scans, is_bag, is_bag_message, read_bag_scan

rosbags = pytest.importorskip("rosbags")
from rosbags.typesys import Stores, get_typestore  # noqa: E402

ROS2 = get_typestore(Stores.ROS2_HUMBLE)


def _cloud(store, points: np.ndarray, stamp: int, frame: str = "camera"):
    """A PointCloud2 of float32 x y z (12-byte points, one row)."""
    t = store.types
    xyz = np.ascontiguousarray(points, dtype="<f4")
    time = t["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)
    ros1 = {} if store is ROS2 else {"seq": 0}  # ROS 1 headers have a sequence number
    return t["sensor_msgs/msg/PointCloud2"](
        header=t["std_msgs/msg/Header"](stamp=time, frame_id=frame, **ros1),
        height=1,
        width=len(xyz),
        fields=[
            t["sensor_msgs/msg/PointField"](name=n, offset=4 * i, datatype=7, count=1)
            for i, n in enumerate("xyz")
        ],
        is_bigendian=False,
        point_step=12,
        row_step=12 * len(xyz),
        data=np.frombuffer(xyz.tobytes(), np.uint8),
        is_dense=True,
    )


def _write_rosbag2(path, messages, storage: str = "mcap") -> None:
    """`messages`: (topic, stamp, message or a string for std_msgs/String)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conns = {}
        for topic, stamp, msg in messages:
            kind = "std_msgs/msg/String" if isinstance(msg, str) else msg.__msgtype__
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, kind, typestore=ROS2)
            if isinstance(msg, str):
                msg = ROS2.types[kind](data=msg)
            writer.write(conns[topic], stamp, ROS2.serialize_cdr(msg, kind))


def _points(seed: int, n: int = 50) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(n, 3)).astype(np.float32)


@pytest.fixture
def mixed_bag(tmp_path):
    path = tmp_path / "run"
    _write_rosbag2(
        path,
        [
            ("/points", 100, _cloud(ROS2, _points(0), 100)),
            ("/chatter", 150, "not a cloud"),
            ("/points", 200, _cloud(ROS2, _points(1), 200)),
            ("/points", 200, _cloud(ROS2, _points(2), 200)),  # same nanosecond
            ("/aux/points", 300, _cloud(ROS2, _points(3), 300)),
        ],
    )
    return path


def test_every_pointcloud2_message_is_a_scan_named_by_topic_and_stamp(mixed_bag):
    assert is_bag(mixed_bag)
    names = bag_scans(mixed_bag)
    assert names == [
        f"{mixed_bag}#/aux/points@300",
        f"{mixed_bag}#/points@100",
        f"{mixed_bag}#/points@200",
        f"{mixed_bag}#/points@200+1",
    ]
    assert all(is_bag_message(n) for n in names)
    for name, seed in zip(names, (3, 0, 1, 2), strict=True):
        np.testing.assert_array_equal(read_bag_scan(name).points, _points(seed))
    assert bag_scans(f"{mixed_bag}#/aux/points") == names[:1]
    assert bag_scans(names[2]) == names[2:3]


def test_missing_topics_and_messages_are_input_errors(mixed_bag):
    with pytest.raises(InputError, match=r"no sensor_msgs/PointCloud2 messages on /chatter"):
        bag_scans(f"{mixed_bag}#/chatter")
    with pytest.raises(InputError, match="no such message"):
        read_bag_scan(f"{mixed_bag}#/points@201")
    with pytest.raises(FileNotFoundError):
        read_bag_scan(f"{mixed_bag}.missing#/points@100")


def test_a_bag_without_clouds_lists_its_topics(tmp_path):
    path = tmp_path / "talk"
    _write_rosbag2(path, [("/chatter", 1, "hello")], storage="sqlite3")
    with pytest.raises(InputError, match=r"no sensor_msgs/PointCloud2 .*/chatter \(std_msgs"):
        bag_scans(path)


def test_a_damaged_bag_is_an_input_error(tmp_path):
    path = tmp_path / "broken.mcap"
    path.write_bytes(b"\x89MCAP0\r\n" + bytes(64))
    with pytest.raises(InputError, match=r"broken\.mcap: cannot read it as a ROS bag"):
        bag_scans(path)


def test_sqlite_bags_bare_mcap_files_and_ros1_bags(tmp_path):
    pts = _points(7)
    sqlite = tmp_path / "sq"
    _write_rosbag2(sqlite, [("/cloud", 5, _cloud(ROS2, pts, 5))], storage="sqlite3")
    mcap_dir = tmp_path / "mc"
    _write_rosbag2(mcap_dir, [("/cloud", 5, _cloud(ROS2, pts, 5))])
    bare = next(mcap_dir.glob("*.mcap"))
    from rosbags.rosbag1 import Writer

    ros1 = get_typestore(Stores.ROS1_NOETIC)
    bag = tmp_path / "old.bag"
    with Writer(bag) as writer:
        conn = writer.add_connection("/cloud", "sensor_msgs/msg/PointCloud2", typestore=ros1)
        writer.write(conn, 5, ros1.serialize_ros1(_cloud(ros1, pts, 5), conn.msgtype))
    for source in (sqlite, bare, bag):
        names = bag_scans(source)
        assert names == [f"{source}#/cloud@5"]
        np.testing.assert_array_equal(read_bag_scan(names[0]).points, pts)
    # A glob matching bag files expands each into its messages, as a folder of files would.
    from pointclm.batch import expand_scans

    assert expand_scans([str(mcap_dir / "*.mcap"), str(bag)]) == [
        f"{bare}#/cloud@5",
        f"{bag}#/cloud@5",
    ]


def test_pointclm_batch_registers_each_message_of_a_bag(tmp_path, capsys):
    scenes = [make_realistic_scene(seed, SceneParams(model="bunny")) for seed in (0, 1)]
    model = tmp_path / "bunny.ply"
    write_ply(model, scenes[0].source_points)
    bag = tmp_path / "scans"
    stamps = [1_700_000_000_000_000_000 + k * 10**8 for k in range(2)]
    _write_rosbag2(
        bag,
        [
            ("/camera/points", s, _cloud(ROS2, sc.target_points, s))
            for s, sc in zip(stamps, scenes, strict=True)
        ],
    )
    out = tmp_path / "r.jsonl"
    assert main(["batch", str(model), str(bag), "--out", str(out), "--quiet"]) == 0
    assert "2 registered, 0 failed" in capsys.readouterr().out
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r["scan"] for r in lines] == [f"{bag}#/camera/points@{s}" for s in stamps]
    for record, scene in zip(lines, scenes, strict=True):
        assert record["status"] == "ok", record
        # The same points through the numpy path (float32 in the message) give the same poses.
        scan = scene.target_points.astype(np.float32).astype(np.float64)
        direct = pointclm.register_point_clouds(load_points(model), scan)
        found = np.array([i["T_target_source"] for i in record["instances"]])
        np.testing.assert_allclose(found, direct.transformations, atol=1e-9)
        assert len(found) >= len(scene.poses) - 1
    # A resumed batch finds both messages already done.
    assert main(["batch", str(model), str(bag), "--out", str(out), "--quiet", "--resume"]) == 0
    assert "0 registered, 0 failed, 2 skipped" in capsys.readouterr().out

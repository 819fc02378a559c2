"""Each pose in the forms other tools take (quaternion, rotation, translation, Open3D's
correspondence set), and the BOP challenge's CSV out and back in."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pointclm
import pytest
from pointclm.cli import main
from pointclm.errors import InputError
from pointclm.io import BopEstimate, read_bop_csv, write_bop_csv, write_ply
from pointclm.poses import quaternion, rotation, translation
from posed_copies import posed_copies
from scipy.spatial.transform import Rotation


@pytest.fixture(scope="module")
def result():
    model, scan, _ = posed_copies(2, cut=True)
    return pointclm.register_point_clouds(model, scan)


def test_quaternion_orders_signs_and_known_values() -> None:
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # 90 degrees about z
    h = np.sqrt(0.5)
    np.testing.assert_allclose(quaternion(T), [0, 0, h, h], atol=1e-15)
    np.testing.assert_allclose(quaternion(T, order="wxyz"), [h, 0, 0, h], atol=1e-15)
    # 180 degrees about x: w = 0, the sign puts the first non-zero component positive.
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    np.testing.assert_allclose(quaternion(T), [1, 0, 0, 0], atol=1e-15)
    for R in Rotation.random(200, random_state=3):
        T[:3, :3] = R.as_matrix()
        q = quaternion(T)
        assert q[3] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
        np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), T[:3, :3], atol=1e-12)
        np.testing.assert_array_equal(quaternion(T, "wxyz"), np.roll(q, 1))
    with pytest.raises(InputError, match="order"):
        quaternion(T, order="wxzy")
    with pytest.raises(InputError, match="4 x 4"):
        quaternion(np.eye(3))


def test_each_instance_gives_its_pose_in_every_form(result) -> None:
    assert len(result.instances) == 2
    for inst in result.instances:
        T = inst.transformation
        np.testing.assert_array_equal(inst.rotation, T[:3, :3])
        np.testing.assert_array_equal(inst.translation, T[:3, 3])
        q = inst.quaternion()
        assert q[3] >= 0
        np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), T[:3, :3], atol=1e-9)
        np.testing.assert_array_equal(inst.quaternion(order="wxyz"), np.roll(q, 1))
        inst.rotation[0, 0] = 7.0  # a copy: the instance's pose is left alone
        assert inst.transformation[0, 0] != 7.0
    # The core's instances take the same functions.
    core = result.result.instances[0]
    np.testing.assert_array_equal(translation(core), core.transformation[:3, 3])
    np.testing.assert_array_equal(rotation(core), core.transformation[:3, :3])


def test_correspondence_set_is_what_fitness_and_inlier_rmse_count(result) -> None:
    fitnesses = []
    for inst in result.instances:
        pairs = inst.correspondence_set
        assert pairs.dtype == np.int64 and pairs.shape[1] == 2
        posed = result.source_points[pairs[:, 0]] @ inst.rotation.T + inst.translation
        d = np.linalg.norm(posed - result.target_points[pairs[:, 1]], axis=1)
        assert d.max() < 1.5 * result.voxel_size
        assert len(pairs) / len(result.source_points) == pytest.approx(inst.fitness, abs=1e-12)
        assert np.sqrt(np.mean(d**2)) == pytest.approx(inst.inlier_rmse, rel=1e-9)
        fitnesses.append(inst.fitness)
    assert min(fitnesses) < 0.95  # the cut copy: not every model point is explained


def _estimates_match(read: list[BopEstimate], reg, ids=(1, 2, 3), scale=1.0) -> None:
    assert len(read) == len(reg.instances)
    for est, inst in zip(read, reg.instances, strict=True):
        assert (est.scene_id, est.im_id, est.obj_id) == ids
        assert est.score == inst.confidence
        np.testing.assert_allclose(est.rotation, inst.rotation, atol=1e-6, rtol=0)
        np.testing.assert_allclose(est.translation * scale, inst.translation, atol=1e-6, rtol=0)
        np.testing.assert_allclose(est.transformation, inst.transformation, atol=1e-6, rtol=0)
        assert est.time == pytest.approx(reg.timings["total"])


def test_bop_csv_round_trip(result, tmp_path: Path) -> None:
    path = tmp_path / "poses.csv"
    assert write_bop_csv(result, path, 1, 2, 3) == 2
    lines = path.read_text().splitlines()
    assert lines[0] == "scene_id,im_id,obj_id,score,R,t,time"
    cells = lines[1].split(",")
    assert len(cells) == 7 and len(cells[4].split()) == 9 and len(cells[5].split()) == 3
    # t in millimetres: the clouds are taken to be in metres unless told otherwise.
    t_mm = np.array(cells[5].split(), dtype=float)
    np.testing.assert_allclose(t_mm, 1000 * result.instances[0].translation, rtol=1e-15)
    _estimates_match(read_bop_csv(path), result)
    raw = read_bop_csv(path, unit_to_mm=1)
    np.testing.assert_allclose(raw[0].translation, t_mm)
    # Clouds in millimetres: t as it is.
    write_bop_csv(result, path, 1, 2, 3, unit_to_mm=1)
    _estimates_match(read_bop_csv(path, unit_to_mm=1), result)


def test_bop_time_is_per_image(result, tmp_path: Path) -> None:
    # Two objects in one image and one in another: an image's lines share one time, the sum.
    path = tmp_path / "three.csv"
    write_bop_csv([result, result, result], path, 0, [5, 5, 6], [1, 2, 1])
    read = read_bop_csv(path)
    total = result.timings["total"]
    assert [e.time for e in read if e.im_id == 5] == pytest.approx([2 * total] * 4)
    assert [e.time for e in read if e.im_id == 6] == pytest.approx([total] * 2)
    assert [e.obj_id for e in read] == [1, 1, 2, 2, 1, 1]
    with pytest.raises(InputError, match="obj_id"):
        write_bop_csv([result, result], path, 0, 0, [1])
    with pytest.raises(InputError, match="unit_to_mm"):
        write_bop_csv(result, path, 0, 0, 1, unit_to_mm=0)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("a,b\n", "header"),
        ("scene_id,im_id,obj_id,score,R,t,time\n1,2,3,0.5,1 0 0 0 1 0 0 0 1,0 0 0\n", "line 2"),
        ("scene_id,im_id,obj_id,score,R,t,time\n1,x,3,0.5,1 0 0 0 1 0 0 0 1,0 0 0,1\n", "im_id"),
        ("scene_id,im_id,obj_id,score,R,t,time\n1,2,3,0.5,1 0 0 0 1 0 0 0,0 0 0,1\n", "R must"),
        ("scene_id,im_id,obj_id,score,R,t,time\n1,2,3,nan,1 0 0 0 1 0 0 0 1,0 0 0,1\n", "score"),
    ],
)
def test_a_bad_bop_csv_names_its_line(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=match) as err:
        read_bop_csv(path)
    assert str(path) in str(err.value)


def test_register_command_writes_the_bop_csv(tmp_path: Path, capsys) -> None:
    model, scan, poses = posed_copies(2)
    write_ply(tmp_path / "model.ply", model)
    write_ply(tmp_path / "scan.ply", scan)
    out, csv = tmp_path / "r.json", tmp_path / "r.csv"
    argv = ["register", str(tmp_path / "model.ply"), str(tmp_path / "scan.ply"), "--quiet"]
    flags = ["--out", str(out), "--bop-csv", str(csv), "--scene-id", "4", "--im-id", "9"]
    assert main([*argv, *flags, "--obj-id", "2", "--unit-to-mm", "1"]) == 0
    record = json.loads(out.read_text())
    read = read_bop_csv(csv, unit_to_mm=1)
    assert [(e.scene_id, e.im_id, e.obj_id) for e in read] == [(4, 9, 2)] * 2
    for est, inst in zip(read, record["instances"], strict=True):
        np.testing.assert_allclose(est.transformation, inst["T_target_source"], atol=1e-9)
        assert est.score == inst["confidence"]
    # The output path is checked before the work.
    assert main([*argv, "--bop-csv", str(tmp_path / "no" / "r.csv")]) != 0
    assert "--bop-csv" in capsys.readouterr().err

"""Poses that slide along a face (a box flush with its neighbours, a flat face lying on a larger
plane) are an ambiguity, not an error: verification returns them apart, less sure by the slide,
with their information matrix, and the copies returned stay pinned down."""

from __future__ import annotations

import json

import numpy as np
import pointclm
import pytest
from pointclm.batch.records import registration_record
from pointclm.refinement import MAX_SLID_FITNESS
from pointclm.schemas import result_schema


def _grid(x: tuple[float, float], y: tuple[float, float], step: float) -> np.ndarray:
    xs, ys = np.meshgrid(np.arange(x[0], x[1] + 1e-9, step), np.arange(y[0], y[1] + 1e-9, step))
    return np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])


def _plate_on_a_table(table_side: float) -> tuple[np.ndarray, np.ndarray]:
    """Two square plates at a right angle, the first lying on a table seen from above (the
    second reaches below the table, hidden from the sensor)."""
    first = _grid((0.0, 1.0), (0.0, 1.0), 0.05)
    second = first[:, [2, 1, 0]] * [1, 1, -1] - [0, 0, 0.05]
    table = _grid((-table_side, table_side), (-table_side, table_side), 0.05)
    table[:, 2] += 1e-4 * np.sin(7 * table[:, 0] + 3 * table[:, 1])  # not a perfect lattice
    return np.vstack([first, second]), table


EYE = np.array([0.3, 0.2, 30.0])


@pytest.mark.parametrize("viewpoint", [EYE, None])
def test_a_face_on_a_larger_plane_comes_back_apart_not_rejected(viewpoint) -> None:
    part, table = _plate_on_a_table(3.0)
    pose = np.eye(4)[None]
    out = pointclm.refine_poses(part, table, pose, 0.1, viewpoint=viewpoint, icp=False)
    assert len(out.transformations) == 0
    assert out.sliding is not None and len(out.sliding.transformations) == 1
    assert out.sliding.slid_fitness[0] > MAX_SLID_FITNESS
    # Less sure by the slide: the same pose with the rule off keeps its full confidence.
    plain = pointclm.refine_poses(
        part, table, pose, 0.1, viewpoint=viewpoint, icp=False, max_slid_fitness=1.0
    )
    factor = min(1.0, (1 - out.sliding.slid_fitness[0]) / (1 - MAX_SLID_FITNESS))
    assert out.sliding.confidence[0] == pytest.approx(plain.confidence[0] * factor, abs=1e-12)
    assert np.isnan(plain.slid_fitness[0])
    context = pointclm.RefinementContext(part, table, 0.1, viewpoint=viewpoint)
    assert [r.rule for r in context.rejections(pose, icp=False)] == ["max_slid_fitness"]
    # Where the table is the plate's own size, the part is pinned: kept, nothing apart.
    small_part, small = _plate_on_a_table(1.0)
    small = small[(small[:, 0] >= 0) & (small[:, 1] >= 0)]
    pinned = pointclm.refine_poses(small_part, small, pose, 0.1, viewpoint=viewpoint, icp=False)
    assert len(pinned.transformations) == 1 and pinned.slid_fitness[0] <= MAX_SLID_FITNESS
    assert pinned.sliding is not None and len(pinned.sliding.transformations) == 0


@pytest.fixture(scope="module")
def packed_row():  # type: ignore[no-untyped-def]
    """A row of touching boxes seen from 0.6 m by a structured-light camera."""
    from pointclm.datasets.sensed import SensedSceneParams, make_sensed_scene

    params = SensedSceneParams(parts=("box_95x36x68",), layout="row", copies=(5, 10))
    scene = make_sensed_scene(0, params)
    return scene, pointclm.register_point_clouds(scene.models[0], scene.scan)


def test_packed_boxes_come_back_as_ambiguous_poses_with_their_information(packed_row) -> None:
    _, res = packed_row
    assert res.ambiguous, "a row of flush boxes slides along its tops"
    for inst in res.instances:
        assert not inst.slid_fitness > MAX_SLID_FITNESS
    confidence = [a.confidence for a in res.ambiguous]
    assert confidence == sorted(confidence, reverse=True)
    for a in res.ambiguous:
        assert a.slid_fitness > MAX_SLID_FITNESS
        assert 0.0 <= a.confidence <= 1.0
        assert a.information is not None and a.information.shape == (6, 6)
        assert a.covariance is not None and np.all(np.isfinite(a.covariance))
        assert a.correspondence_set is not None  # the result's clouds reach them too
    # None repeats another: each explains scan points of its own.
    posed = [
        (a.transformation[:3, :3] @ res.source_points.T).T + a.transformation[:3, 3]
        for a in res.ambiguous
    ]
    centres = np.array([p.mean(0) for p in posed])
    gaps = np.linalg.norm(centres[:, None] - centres[None], axis=2) + np.eye(len(centres)) * 1e9
    assert gaps.min() > res.voxel_size


def test_the_result_json_lists_the_ambiguous_poses(packed_row) -> None:
    jsonschema = pytest.importorskip("jsonschema")
    _, res = packed_row
    record = registration_record(res, "")
    record = json.loads(json.dumps(record))
    assert len(record["ambiguous"]) == len(res.ambiguous)
    assert all(a["slid_fitness"] > MAX_SLID_FITNESS for a in record["ambiguous"])
    schema = result_schema()
    only = {k: v for k, v in schema.items() if k != "oneOf"}
    validator = jsonschema.Draft202012Validator({**only, "$ref": "#/$defs/registration"})
    assert [e.message for e in validator.iter_errors(record)] == []

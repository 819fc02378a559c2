"""The validation matrix's instrument: sensed scenes, sensor effects, symmetry-aware scoring,
and two quick cells of ``benchmarks/matrix/run.py``."""

from __future__ import annotations

import numpy as np
import pytest
from pointclm.datasets.cameras import Camera, look_at, render
from pointclm.datasets.parts import box_symmetries, load_part, model_form, surface_samples
from pointclm.datasets.sensed import SensedSceneParams, make_packed_boxes, make_sensed_scene
from pointclm.datasets.sensor_effects import SENSORS, SensorModel, sense
from pointclm.metrics import pose_match_matrix, symmetric_errors

from benchmarks.matrix import run as mx

SMALL = Camera(200, 150, 165.0, 165.0, 100.0, 75.0, 0.6)
IDEAL = SensorModel("gaussian", sigma0=0.0)


def _turned(pose: np.ndarray, deg: float) -> np.ndarray:
    a = np.deg2rad(deg)
    r = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
    out = pose.copy()
    out[:3, :3] = pose[:3, :3] @ r
    return out


@pytest.fixture(scope="module")
def packed():
    return make_packed_boxes(3, layout="grid", camera=SMALL, sensor=IDEAL)


def test_packed_boxes_truth_lies_on_the_scan(packed):
    sc = packed
    assert set(np.unique(sc.product)) == {0, 1}
    assert len(sc.models) == 2 and all(len(s) == 4 for s in sc.symmetries)
    assert np.all((sc.visible_fraction >= 0) & (sc.visible_fraction <= 1 + 1e-9))
    assert (sc.scan_ids == -2).any() and (sc.scan_ids == -3).any()  # floor and walls kept
    worst = []
    for k in np.flatnonzero(sc.visible_pixels > 50):
        part = load_part(sc.parts[sc.product[k]])
        half = part.extent / 2
        inv = np.linalg.inv(sc.poses[k])
        q = sc.scan[sc.scan_ids == k] @ inv[:3, :3].T + inv[:3, 3]
        # Distance of each point to the box's surface (inside: to the nearest face).
        d = np.abs(q) - half
        out = np.linalg.norm(np.clip(d, 0, None), axis=1)
        inside = np.clip(d.max(1), None, 0)
        err = out - inside
        pixel = sc.poses[k][2, 3] / SMALL.fx  # a pixel's footprint at the copy's depth
        worst.append((np.median(err) / pixel, np.percentile(err, 99) / pixel))
    # Faces exact; at silhouettes a splat reaches at most 1.25 pixels past the edge.
    assert worst and max(w[0] for w in worst) < 0.05 and max(w[1] for w in worst) < 1.3


def test_scenes_are_deterministic_and_seeds_differ():
    p = SensedSceneParams(parts=("box_95x36x68",), layout="pile", camera=SMALL, copies=(3, 4))
    a, b, c = make_sensed_scene(1, p), make_sensed_scene(1, p), make_sensed_scene(2, p)
    np.testing.assert_array_equal(a.scan, b.scan)
    np.testing.assert_array_equal(a.poses, b.poses)
    assert not np.array_equal(a.poses[0], c.poses[0])


def test_sensor_effects():
    part = load_part("box_95x36x68")
    pts, nrm = surface_samples(part, 20_000)
    cam = look_at(SMALL, np.zeros(3), np.array([0.3, 0.2, 1.0]))
    frame = render(cam, [(pts, nrm, 0.5)], [])
    rng = np.random.default_rng(0)
    quant = sense(frame, cam, SensorModel("gaussian", sigma0=1e-3, depth_unit=1e-3), rng)
    ok = np.isfinite(quant)
    assert ok.sum() > 300 and np.isnan(quant).any()  # returns on the box, none around it
    np.testing.assert_allclose(quant[ok] * 1000, np.round(quant[ok] * 1000), atol=1e-6)
    # Structured light: noise grows with depth squared; the same box farther is noisier.
    far_cam = look_at(Camera(200, 150, 165.0, 165.0, 100.0, 75.0, 2.0), np.zeros(3), [0.3, 0.2, 1])
    far = render(far_cam, [(pts, nrm, 0.5)], [])
    sl = SensorModel("structured_light", sigma0=1e-3)
    near_err = np.nanstd(sense(frame, cam, sl, np.random.default_rng(1)) - frame.depth)
    far_err = np.nanstd(sense(far, far_cam, sl, np.random.default_rng(1)) - far.depth)
    assert far_err > 5 * near_err
    # Time of flight loses nothing here but is noisier than the ideal frame; 1/8000 m units.
    tof = sense(frame, cam, SENSORS["tof"], np.random.default_rng(2))
    assert np.nanstd(tof - frame.depth) > 1e-3


def test_model_forms_are_in_the_part_frame():
    part = load_part("box_120x52x50")
    for form in ("fine_mesh", "coarse_mesh", "points", "scan"):
        m = model_form(part, form)
        assert m.ndim == 2 and m.shape[1] == 3 and np.isfinite(m).all()
        # Every form hugs the same box: its bounds within 5 mm of the part's.
        assert np.all(np.abs(m.max(0) - part.extent / 2) < 5e-3), form


def test_scoring_exact_shifted_and_symmetric():
    rng = np.random.default_rng(0)
    truth = np.tile(np.eye(4), (3, 1, 1))
    truth[:, :3, 3] = rng.uniform(-0.2, 0.2, size=(3, 3))
    visible = np.array([0.9, 0.6, 0.35])
    sym = box_symmetries()
    exact = mx.score_poses(truth, truth, visible, 0.12, sym)
    assert (exact.found30, exact.n30, exact.right, exact.n_pred) == (3, 3, 3, 3)
    shifted = truth.copy()
    shifted[:, :3, 3] += 0.2 * 0.12  # 20 % of the diagonal off
    miss = mx.score_poses(shifted, truth, visible, 0.12, sym)
    assert (miss.found30, miss.right) == (0, 0)
    # A half turn of a box is the same pose; a quarter turn is not.
    halves = np.stack([truth[i] @ sym[i + 1] for i in range(3)])
    same = mx.score_poses(halves, truth, visible, 0.12, sym)
    assert (same.found30, same.right) == (3, 3)
    quarter = np.stack([_turned(t, 90) for t in truth])
    assert mx.score_poses(quarter, truth, visible, 0.12, sym).right == 0
    # Without the symmetries the half turn is wrong; duplicates count once.
    assert mx.score_poses(halves, truth, visible, 0.12, None).right == 0
    dup = mx.score_poses(np.concatenate([truth[:1], truth[:1]]), truth, visible, 0.12, sym)
    assert (dup.right, dup.n_pred, dup.found30) == (1, 2, 1)
    re, te = symmetric_errors(halves, truth, sym)
    np.testing.assert_allclose(np.diag(re), 0, atol=1e-6)
    np.testing.assert_allclose(np.diag(te), 0, atol=1e-12)
    assert pose_match_matrix(halves, truth, symmetries=sym).trace() == 3


def test_quick_cells():
    import dataclasses

    cells = {c.name: c for c in mx.all_cells(0)}
    assert {"base", "boxes2 grid", "corr bunny structured_light"} <= set(cells)
    for axis, values in mx.AXES.items():
        assert len(values) >= 3, axis
    base = dataclasses.replace(cells["base"], copies=(4, 5))
    res, _ = mx.run_cell(base, [0], None)
    rows = res["rows"]
    assert set(rows) == {
        "default",
        "heap",
        "default+ambiguous",
        "heap+ambiguous",
        "exact",
        "exact+ambiguous",
    }
    assert rows["exact+ambiguous"]["all"]["recall30"] >= rows["exact"]["all"]["recall30"]
    assert rows["default"]["all"]["recall30"] >= 0.5
    assert rows["exact"]["all"]["recall30"] >= 0.75


def test_each_rule_read_alone_on_the_exact_poses_rejects_what_it_rejects_at_its_default():
    """`benchmarks.matrix.exact_rules` reads each rule's value at a threshold every pose
    fails; at the default threshold those values reject exactly the poses the rule alone does."""
    import pointclm.refinement as rf

    from benchmarks.matrix import exact_rules

    values = exact_rules.measure(["part=bracket"], [0])["part=bracket"]
    cell = {c.name: c for c in mx.all_cells()}["part=bracket"]
    scene = make_sensed_scene(0, cell.params())
    idx, ctx = mx.exact_context(scene, 0)
    for rule, (_, floor) in exact_rules.RULES.items():
        v = np.asarray(values[rule])
        assert len(v) == len(idx)
        default = getattr(rf, rule.upper())
        read = np.flatnonzero(v < default if floor else v > default)
        alone = ctx.rejections(scene.poses[idx], **{**exact_rules.OFF, rule: default})
        assert sorted(r.origin for r in alone) == read.tolist(), rule


def _run_json(f1: dict[str, tuple[float, float]]) -> dict:
    """A matrix run's JSON with `f1` (cell -> validation, test) on the default row."""
    cells = {
        name: {"rows": {"default": {"validation": {"f1": v}, "test": {"f1": t}}}}
        for name, (v, t) in f1.items()
    }
    return {"cells": cells, "pooled": {"default": {"validation": {"f1": 0.5}, "test": {}}}}


def test_choosing_a_rule_admits_the_values_within_the_tolerance_on_every_cell():
    from benchmarks.matrix import choose

    runs = {
        "a": _run_json({"x": (0.90, 0.1), "y": (0.50, 0.2), "z": (0.7, 0.7)}),
        "b": _run_json({"x": (0.88, 0.3), "y": (0.60, 0.4), "z": (0.7, 0.7)}),
    }
    out = choose.compare(runs, "default", 0.03)
    assert out["cells"]["y"]["loss"] == pytest.approx({"a": 0.10, "b": 0.0})
    # "a" loses 0.10 on y; "b" loses 0.02 on x only: admissible. The test half never decides.
    assert out["labels"]["a"]["over"] == ["y"]
    assert out["labels"]["b"]["over"] == []
    assert out["labels"]["b"]["worst_loss"] == pytest.approx(0.02)
    text = choose.report(out)
    assert "| y | 0.50 / 0.20 | 0.60 / 0.40 | b |" in text
    assert "| z |" not in text  # the same under every value
    assert "none (admissible)" in text


def test_a_run_can_change_a_scene_rule_and_a_bad_one_stops_it():
    assert mx._scene_rules(["heap_min_copies=3", "max_peel_rounds = 5"]) == {
        "heap_min_copies": 3,
        "max_peel_rounds": 5,
    }
    with pytest.raises(SystemExit, match="RULE=VALUE"):
        mx._scene_rules(["heap_min_copies"])
    with pytest.raises(Exception, match="no_such_rule"):
        mx._scene_rules(["no_such_rule=1"])

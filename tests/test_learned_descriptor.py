"""The learned local descriptor: its file, its forward pass in the core, the pipeline option,
the command line and training."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pointclm import register_point_clouds
from pointclm.descriptors import descriptor_choice, descriptor_weights, learned_descriptors
from pointclm.errors import InputError
from scipy.spatial.transform import Rotation


def _sphere(n: int = 600, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A bumpy sphere and its outward normals (of the sphere: the bumps are small)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = 0.1 * (1 + 0.15 * np.sin(5 * d[:, 0]) * np.cos(3 * d[:, 1]))
    return d * r[:, None], d


def test_names_and_paths_resolve_or_say_what_is_wrong(tmp_path: Path) -> None:
    assert descriptor_weights("fpfh") is None
    assert descriptor_weights(None) is None
    shipped = descriptor_weights("learned")
    assert shipped is not None and Path(shipped).with_suffix(".json").is_file()
    with pytest.raises(InputError, match="fpfh"):
        descriptor_weights("shot")
    with pytest.raises(InputError, match="descriptor must be"):
        descriptor_weights(3)  # type: ignore[arg-type]
    lone = tmp_path / "d.safetensors"
    lone.write_bytes(Path(shipped).read_bytes())
    with pytest.raises(InputError, match="d.json"):
        descriptor_weights(lone)
    (tmp_path / "d.json").write_text("{}")
    with pytest.raises(ValueError, match="descriptor"):
        learned_descriptors(*_sphere(), 0.01, lone)


def test_descriptors_are_unit_length_and_do_not_change_with_a_rotation() -> None:
    pts, nrm = _sphere()
    d = learned_descriptors(pts, nrm, 0.01)
    assert d.shape[0] == len(pts) and np.isfinite(d).all()
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-5)
    rot = Rotation.random(random_state=1).as_matrix()
    turned = learned_descriptors(pts @ rot.T + [1.0, -2.0, 0.5], nrm @ rot.T, 0.01)
    np.testing.assert_allclose(turned, d, atol=2e-4)


def test_bad_inputs_are_refused_and_nothing_given_is_changed() -> None:
    pts, nrm = _sphere(200)
    before = pts.copy()
    with pytest.raises(ValueError, match="normals"):
        learned_descriptors(pts, nrm[:-1], 0.01)
    with pytest.raises(ValueError, match="voxel"):
        learned_descriptors(pts, nrm, -1.0)
    bad = pts.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError):
        learned_descriptors(bad, nrm, 0.01)
    out = learned_descriptors(pts.astype(np.float32), nrm, 0.01)
    assert out.shape[0] == len(pts)
    np.testing.assert_array_equal(pts, before)


def test_the_torch_network_and_the_core_give_the_same_descriptors(tmp_path: Path) -> None:
    torch = pytest.importorskip("torch")
    pytest.importorskip("safetensors")
    from pointclm.training.descriptor import (
        DescriptorTrainConfig,
        descriptor_network,
        export_descriptor,
        pair_features,
    )

    cfg = DescriptorTrainConfig(widths=(8, 16, 12, 6), neighbours=12, candidates=40)
    torch.manual_seed(0)
    net = descriptor_network(cfg.widths)
    path = export_descriptor(net, cfg, tmp_path / "d.safetensors")
    pts, nrm = _sphere(500)
    voxel = 0.008
    feats, mask = pair_features(pts, nrm, cfg.radius_voxels * voxel, cfg.neighbours, 40)
    with torch.no_grad():
        want = net(torch.from_numpy(feats), torch.from_numpy(mask)).numpy()
    got = learned_descriptors(pts, nrm, voxel, path)
    np.testing.assert_allclose(got, want, atol=1e-4)


def _bunny_scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    from pointclm.datasets.scenes import SceneParams, make_realistic_scene

    s = make_realistic_scene(3, SceneParams(model="bunny", n_correspondences=10, clutter=(0, 0)))
    return s.source_points, s.target_points, s.poses


def test_register_point_clouds_matches_by_the_learned_descriptor_when_asked() -> None:
    model, scan, poses = _bunny_scene()
    fpfh = register_point_clouds(model, scan, seed=0, descriptor="fpfh")
    learned = register_point_clouds(model, scan, seed=0, descriptor="learned")
    assert (fpfh.descriptor, learned.descriptor) == ("fpfh", "learned")
    assert fpfh.source_points.shape == learned.source_points.shape
    assert not np.array_equal(fpfh.correspondences, learned.correspondences)
    assert len(learned.instances) >= 1
    for inst in learned.instances:
        err = [np.linalg.norm(inst.transformation[:3, 3] - p[:3, 3]) for p in poses]
        assert min(err) < 0.1 * np.linalg.norm(model.max(0) - model.min(0))
    with pytest.raises(InputError, match="descriptor"):
        register_point_clouds(model, scan, descriptor="sift")


def test_fpfh_and_learned_side_by_side_match_on_both() -> None:
    shipped = descriptor_weights("learned")
    assert descriptor_choice("fpfh+learned") == (shipped, "fpfh+learned")
    assert descriptor_choice("learned") == (shipped, "learned")
    assert descriptor_choice("fpfh") == (None, "fpfh")
    with pytest.raises(InputError, match="fpfh\\+learned"):
        descriptor_choice("fpfh+fpfh")
    model, scan, poses = _bunny_scene()
    both = register_point_clouds(model, scan, seed=0, descriptor="fpfh+learned")
    learned = register_point_clouds(model, scan, seed=0, descriptor="learned")
    assert both.source_points.shape == learned.source_points.shape
    assert not np.array_equal(both.correspondences, learned.correspondences)
    assert len(both.instances) >= 1
    diag = np.linalg.norm(model.max(0) - model.min(0))
    for inst in both.instances:
        err = [np.linalg.norm(inst.transformation[:3, 3] - p[:3, 3]) for p in poses]
        assert min(err) < 0.1 * diag


def test_auto_matches_curved_parts_by_both_and_flat_faced_ones_by_fpfh() -> None:
    from helpers import box_surface
    from pointclm.descriptors import described_by

    shipped = descriptor_weights("learned")
    assert descriptor_choice("auto") == (shipped, "auto")
    assert descriptor_choice("auto+learned") == (shipped, "auto")
    with pytest.raises(InputError, match="auto\\+learned"):
        descriptor_choice("auto+fpfh")
    model, scan, _ = _bunny_scene()
    auto = register_point_clouds(model, scan, seed=0)
    both = register_point_clouds(model, scan, seed=0, descriptor="fpfh+learned")
    assert (auto.descriptor, both.descriptor) == ("fpfh+learned", "fpfh+learned")
    np.testing.assert_array_equal(auto.correspondences, both.correspondences)
    np.testing.assert_array_equal(auto.transformations, both.transformations)
    assert "matched by: fpfh+learned" in repr(auto)
    # A box: six flat faces, nothing for a local descriptor to tell apart on them.
    box = box_surface((0.12, 0.08, 0.05))
    turn = Rotation.from_euler("xyz", [20, -35, 50], degrees=True).as_matrix()
    copies = np.vstack([box @ turn.T + [x, 0.0, 0.5] for x in (-0.15, 0.15)])
    auto = register_point_clouds(box, copies, seed=0)
    fpfh = register_point_clouds(box, copies, seed=0, descriptor="fpfh")
    assert (auto.descriptor, fpfh.descriptor) == ("fpfh", "fpfh")
    np.testing.assert_array_equal(auto.correspondences, fpfh.correspondences)
    np.testing.assert_array_equal(auto.transformations, fpfh.transformations)
    with pytest.raises(InputError, match="per model"):
        described_by("auto", scan[:10], scan[:10], np.ones((10, 33)), 0.01)


def test_the_command_line_takes_a_descriptor(tmp_path: Path) -> None:
    model, scan, _ = _bunny_scene()
    np.save(tmp_path / "model.npy", model)
    np.save(tmp_path / "scan.npy", scan)
    run = [sys.executable, "-m", "pointclm", "register", str(tmp_path / "model.npy"),
           str(tmp_path / "scan.npy"), "--out", str(tmp_path / "out.json"), "--quiet"]  # fmt: skip
    for name in ("learned", "auto"):
        done = subprocess.run([*run, "--descriptor", name], capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
        assert json.loads((tmp_path / "out.json").read_text())["instances"]
    bad = subprocess.run([*run, "--descriptor", "sift"], capture_output=True, text=True)
    assert bad.returncode == 2 and "descriptor" in bad.stderr


def test_train_descriptor_writes_a_file_the_pipeline_takes_and_resumes(tmp_path: Path) -> None:
    pytest.importorskip("torch")
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "pointclm", "train-descriptor", "--out", str(out),
           "--scenes", "2", "--epochs", "1", "--device", "cpu", "--quiet"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    path = out / "descriptor.safetensors"
    meta = json.loads(path.with_suffix(".json").read_text())
    assert meta["descriptor"]["neighbours"] == 32
    assert (out / "checkpoint.json").is_file()
    pts, nrm = _sphere()
    assert learned_descriptors(pts, nrm, 0.01, path).shape == (len(pts), 32)
    again = subprocess.run([*cmd, "--resume"], capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr


def test_described_by_gives_what_the_pipeline_matches() -> None:
    from pointclm import preprocessing as pp
    from pointclm.descriptors import described_by

    pts, _ = _sphere()
    d = pp.describe(pts, 0.01, away_from=np.zeros(3))
    fpfh = described_by("fpfh", d.points, d.normals, d.descriptors, 0.01)
    np.testing.assert_array_equal(fpfh, d.descriptors)
    learned = described_by("learned", d.points, d.normals, d.descriptors, 0.01)
    both = described_by("fpfh+learned", d.points, d.normals, d.descriptors, 0.01)
    assert both.shape == (len(d.points), d.descriptors.shape[1] + learned.shape[1])
    np.testing.assert_allclose(both[:, d.descriptors.shape[1] :], learned)
    head = np.linalg.norm(both[:, : d.descriptors.shape[1]], axis=1)
    np.testing.assert_allclose(head[head > 0], 1.0)

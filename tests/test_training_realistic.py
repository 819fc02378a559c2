"""Realistic training data: the scene bank, its samples, the units the network sees, and a
training run that mixes realistic scenes in."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pointclm.embedding import network_units
from pointclm.point_clouds import cloud_config, scaled_config
from pointclm.training.config import TrainConfig
from pointclm.training.realistic import SceneBank, near_misses, realistic_sample, scene_seed


def test_bank_round_trips_and_matches_the_scenes_it_came_from(bank: SceneBank) -> None:
    from pointclm.datasets.scenes import SceneParams, make_realistic_scene

    assert len(bank) == 2 and bank.models == ["bunny"]
    scene = make_realistic_scene(scene_seed(0, 0, 1), SceneParams(model="bunny"))
    np.testing.assert_allclose(bank.correspondences[1], scene.correspondences, rtol=1e-6)
    np.testing.assert_array_equal(bank.labels[1], scene.labels)
    np.testing.assert_allclose(bank.poses[1], scene.poses)
    assert bank.voxels[1] == pytest.approx(scene.voxel_size)
    assert bank.diameters[1] == pytest.approx(scene.diameter)


def test_bank_seeds_are_disjoint_from_the_benchmark_seeds() -> None:
    seeds = {scene_seed(0, m, k) for m in range(3) for k in range(100)}
    assert len(seeds) == 300 and not seeds & set(range(1000))


def test_samples_keep_labels_and_shapes_up_to_scale(bank: SceneBank) -> None:
    rng = np.random.default_rng(0)
    x, y = realistic_sample(bank, rng, sigma_d=0.05, max_correspondences=10_000)
    i = next(k for k in range(len(bank)) if len(bank.labels[k]) == len(y))
    np.testing.assert_array_equal(y, bank.labels[i])
    corr = bank.correspondences[i].astype(np.float64)
    scale = 0.05 / scaled_config(float(bank.voxels[i])).sigma_d
    for side in (slice(0, 3), slice(3, 6)):
        d_in = np.linalg.norm(corr[:5, side][:, None] - corr[:5, side][None], axis=2)
        d_out = np.linalg.norm(x[:5, side][:, None] - x[:5, side][None], axis=2)
        np.testing.assert_allclose(d_out, scale * d_in, rtol=1e-4, atol=1e-5)
        np.testing.assert_allclose(x[:, side].mean(0), 0.0, atol=1e-4)  # centred
    x2, y2 = realistic_sample(bank, np.random.default_rng(0), 0.05, 50)
    assert x2.shape == (50, 6) and y2.shape == (50,) and x2.dtype == np.float32


def test_network_units_centre_and_scale_without_touching_the_input() -> None:
    corr = np.random.default_rng(1).normal(size=(20, 6)) + 7.0
    before = corr.copy()
    out = network_units(corr, sigma_d=0.3, network_sigma_d=0.05)
    np.testing.assert_array_equal(corr, before)
    np.testing.assert_allclose(out.mean(0), 0.0, atol=1e-12)
    np.testing.assert_allclose(out[1] - out[0], (corr[1] - corr[0]) / 6.0)


def test_point_cloud_configs_scale_and_take_the_networks_thresholds() -> None:
    from pointclm.config import Config
    from pointclm.model import load_metadata
    from pointclm.point_clouds import REFINED_THRESHOLDS

    assert cloud_config(0.01, refine=False) == scaled_config(0.01) == Config.for_voxel(0.01)
    # Refined poses: verification on the clouds judges, so no a-contrario test before it.
    refined = Config(**REFINED_THRESHOLDS, max_nfa=None)
    assert cloud_config(0.01) == scaled_config(0.01, refined)
    assert scaled_config(0.01).sigma_d == pytest.approx(0.03)
    meta = load_metadata("default")
    for refine, key in ((True, ""), (False, "_no_refine")):
        wanted = dict(meta["recommended_point_cloud_config" + key])
        if refine:
            wanted["max_nfa"] = None
        assert cloud_config(0.01, "default", refine) == scaled_config(0.01, Config(**wanted))
    # The two defaults differ: refined poses want low count thresholds, raw ones do not.
    assert cloud_config(0.01, refine=True) != cloud_config(0.01, refine=False)


def test_config_rejects_leaks_and_bad_fractions() -> None:
    with pytest.raises(ValueError, match="realistic_models and val_shapes"):
        TrainConfig(realistic_models=("stanford/armadillo",))
    with pytest.raises(ValueError, match="realistic_fraction"):
        TrainConfig(realistic_fraction=1.5)


def test_training_mixes_realistic_scenes(bank: SceneBank, tmp_path: Path) -> None:
    pytest.importorskip("torch")
    from pointclm.training import train

    path = tmp_path / "bank.npz"
    bank.save(path)
    cfg = TrainConfig.preset(
        "smoke",
        train_shapes=("torus", "box"),
        val_shapes=("cone",),
        realistic_models=("bunny",),
        realistic_fraction=0.5,
        realistic_bank=str(path),
        val_realistic_bank=str(path),
        iterations=2,
        val_every=2,
    )
    result = train(cfg, tmp_path / "run", progress=False)
    assert result["finished"]
    import json

    rows = [json.loads(r) for r in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    assert "val_realistic" in rows[-1] and rows[-1]["val_realistic"]["n_scenes"] == 2


def test_near_misses_are_outliers_close_to_a_true_pose() -> None:
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 0.0, 0.0]
    src = np.zeros((4, 3))
    tgt = np.array([[1.0, 0, 0], [1.5, 0, 0], [3.0, 0, 0], [1.2, 0, 0]])
    labels = np.array([0, -1, -1, 0])
    near = near_misses(np.hstack([src, tgt]), labels, pose[None], radius=1.0)
    np.testing.assert_array_equal(near, [False, True, False, False])
    assert not near_misses(np.hstack([src, tgt]), labels, np.zeros((0, 4, 4)), 1.0).any()


def test_ignored_correspondences_are_never_negatives() -> None:
    torch = pytest.importorskip("torch")
    from pointclm.model.loss import IGNORE, negative_distances

    # anchor 0 (instance 0): its closest other correspondence is ignored, the next an outlier
    dist = torch.tensor([[[0.0, 0.1, 0.5], [0.1, 0.0, 0.7], [0.5, 0.7, 0.0]]])
    labels = torch.tensor([[0, IGNORE, -1]])
    chosen, valid = negative_distances(dist, labels)
    assert valid.tolist() == [[True, False, False]]
    assert float(chosen[0, 0]) == pytest.approx(0.5)

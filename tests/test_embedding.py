"""`pointclm.embedding`: resolving a network, its recommended thresholds, its units; and
`Config.for_voxel`. The point: `register(model=..., config=...)` is right in any units."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pointclm
import pytest
from helpers import assert_same_result
from pointclm import Config, Network
from pointclm.datasets import make_scene
from pointclm.embedding import (
    Embedding,
    check_backend,
    is_network,
    is_torch_module,
    is_weights,
    network_units,
    resolve,
)
from pointclm.errors import InputError
from pointclm.metrics import score_scene
from pointclm.model import SHIPPED, load_metadata, load_network


@pytest.fixture(scope="module")
def scene():
    return make_scene(1)


def _same_instances_scaled(small, big, factor: float) -> None:
    """`big` is `small` found on coordinates `factor` times larger."""
    assert len(big) == len(small) > 0
    np.testing.assert_array_equal(big.labels, small.labels)
    np.testing.assert_allclose(
        big.transformations[:, :3, :3], small.transformations[:, :3, :3], atol=1e-6
    )
    np.testing.assert_allclose(
        big.transformations[:, :3, 3], factor * small.transformations[:, :3, 3], atol=1e-5
    )


@pytest.mark.parametrize("config", [Config(), Config(tau_n=5, tau_s=0.85)])
def test_register_with_a_model_is_right_in_any_units(scene, config: Config) -> None:
    small = pointclm.register(scene.correspondences, config=config, model="default")
    big = pointclm.register(
        scene.correspondences * 10, config=config.scaled(10), model="default", num_threads=1
    )
    _same_instances_scaled(small, big, 10.0)
    gt = scene.poses.copy()
    gt[:, :3, 3] *= 10
    assert score_scene(big.transformations, gt, max_translation=1.0).n_matched >= 3


def test_the_network_sees_its_training_units(scene) -> None:
    emb = resolve("default")
    corr = scene.correspondences
    want = emb.embed(corr)
    # Converted, the scaled scene embeds as the original (up to float32 rounding) ...
    np.testing.assert_allclose(emb.embed(corr * 10, 0.5), want, atol=1e-4)
    # ... as it does not without the conversion (what register did before).
    assert np.abs(emb.embed(corr * 10) - want).max() > 0.1


def test_in_training_units_the_core_runs_the_network_unchanged(scene) -> None:
    # sigma_d equal to the network's: the core embeds the coordinates as given (and times it).
    r = pointclm.register(scene.correspondences, config=Config(), model="default")
    f = load_network("default").embed(scene.correspondences)
    assert_same_result(r, pointclm.register(scene.correspondences, f, Config()))
    assert r.timings["embedding"] > 0


def test_register_batch_converts_units_like_register() -> None:
    scenes = [make_scene(s).correspondences * 10 for s in (2, 3)]
    cfg = Config().scaled(10)
    batch = pointclm.register_batch(scenes, cfg, model="default", num_threads=2)
    for corr, r in zip(scenes, batch, strict=True):
        assert_same_result(r, pointclm.register(corr, config=cfg, model="default"))


def test_resolve_names_files_and_loaded_networks() -> None:
    by_name = resolve("default")
    assert by_name.backend == "rust" and is_network(by_name.network)
    assert by_name.path == SHIPPED["default"] and by_name.sigma_d == 0.05
    by_file = resolve(SHIPPED["paper"])
    assert by_file.network.width == 128 and by_file.path == SHIPPED["paper"]
    net = Network(SHIPPED["default"])
    assert resolve(net).network is net and resolve(net).path == SHIPPED["default"]
    assert resolve(by_name) is by_name
    assert is_weights("default") and is_weights(Path("x.safetensors")) and not is_weights(net)


def test_a_network_is_recognised_by_type_not_by_class_name() -> None:
    class Network:  # a look-alike: same class name, not a pointclm.Network
        sigma_d = 0.05

    fake = Network()
    assert not is_network(fake) and not is_torch_module(fake)
    with pytest.raises(InputError, match="shipped name .* or a torch module, got Network"):
        resolve(fake)
    with pytest.raises(InputError, match="needs backend='torch'"):
        resolve(fake, "rust")
    with pytest.raises(InputError, match="backend must be"):
        check_backend("onnx", "default", None)
    with pytest.raises(InputError, match="runs on backend='rust'"):
        resolve(resolve("default"), "torch")


def test_recommended_thresholds_come_from_the_weights() -> None:
    meta = load_metadata("default")
    emb = resolve("default")
    assert emb.recommended_config() == Config(**meta["recommended_config"])
    assert emb.recommended_config("point_clouds") == Config(
        **meta["recommended_point_cloud_config"]
    )
    assert emb.recommended_config("point_clouds_no_refine") == Config(
        **meta["recommended_point_cloud_config_no_refine"]
    )
    # A loaded network carries the same thresholds as its name, for every purpose.
    net = resolve(Network(SHIPPED["default"]))
    for purpose in ("correspondences", "point_clouds", "point_clouds_no_refine"):
        assert net.recommended_config(purpose) == emb.recommended_config(purpose)
    with pytest.raises(InputError, match="purpose"):
        emb.recommended_config("clouds")  # type: ignore[arg-type]


def test_network_units_centre_and_scale() -> None:
    corr = np.random.default_rng(0).normal(size=(30, 6)) + 100.0
    out = network_units(corr, sigma_d=0.5, network_sigma_d=0.05)
    np.testing.assert_allclose(out.mean(0), 0.0, atol=1e-12)
    np.testing.assert_allclose(out[3] - out[0], (corr[3] - corr[0]) / 10)


def test_torch_modules_run_on_torch_in_their_units(scene) -> None:
    pytest.importorskip("torch")
    from pointclm.model import load_model

    module = load_model("default")
    emb = resolve(module)
    assert is_torch_module(module) and emb.backend == "torch" and emb.path is None
    assert emb.sigma_d == 0.05 and emb.recommended_config() is None
    np.testing.assert_allclose(
        emb.embed(scene.correspondences * 10, 0.5),
        resolve("default").embed(scene.correspondences),
        atol=1e-4,
    )
    assert resolve("default", "torch").path == SHIPPED["default"]
    assert isinstance(resolve("default", "torch"), Embedding)


def test_config_for_voxel_is_the_point_cloud_rule() -> None:
    from pointclm.point_clouds import REFINED_THRESHOLDS, cloud_config, scaled_config

    cfg = Config.for_voxel(0.02)
    assert cfg.sigma_d == pytest.approx(0.06)  # 3 voxels
    assert cfg.inlier_threshold == pytest.approx(0.04)  # 2 voxels
    assert cfg.affinity_sigma / cfg.sigma_d == pytest.approx(Config().affinity_sigma / 0.05)
    base = Config(tau_s=0.7, inlier_threshold=0.2, max_rounds=3)
    mine = Config.for_voxel(0.02, base)
    assert mine.inlier_threshold == pytest.approx(0.08)  # in proportion to the base's
    assert (mine.tau_s, mine.max_rounds) == (0.7, 3)  # unitless fields are kept
    assert scaled_config(0.02, base) == mine
    assert cloud_config(0.02) == Config.for_voxel(0.02, Config(**REFINED_THRESHOLDS, max_nfa=None))


def test_an_unknown_model_name_lists_the_shipped_networks(scene) -> None:
    # A mistyped name is read as a relative path; the error says which names exist.
    from pointclm.errors import WeightsNotFoundError

    for call in (
        lambda: pointclm.register(scene.correspondences, model="nosuch"),
        lambda: load_network("nosuch"),
    ):
        with pytest.raises(WeightsNotFoundError, match="nosuch: no such file") as info:
            call()
        assert "'default', 'paper'" in str(info.value) and ".safetensors" in str(info.value)


def test_cuda_without_a_gpu_says_so_and_what_to_do(scene, monkeypatch) -> None:
    torch = pytest.importorskip("torch")
    pytest.importorskip("safetensors")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(InputError, match="CUDA is not available") as info:
        pointclm.register(scene.correspondences, model="default", backend="torch", device="cuda")
    assert "device='cpu'" in str(info.value) and "backend='rust'" in str(info.value)
    with pytest.raises(InputError, match="not a torch device"):
        pointclm.register(scene.correspondences, model="default", backend="torch", device="gpu0")

"""The embedding network's Rust forward pass: parity with torch and the stored fixture,
`register(model=...)` on the Rust backend, bad weight files, and thread independence.

Only the torch comparisons need torch; everything else runs on a torch-free install.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pointclm
import pytest
from helpers import assert_same_result, scene_with_inputs
from pointclm import Config, Network
from pointclm.datasets import make_scene
from pointclm.model import SHIPPED, load_network

FIXTURES = Path(__file__).parent / "fixtures"
N_SCENES = 20
# torch computes in float32 too; the two differ by rounding only (measured: <= 4e-5)
PARITY = 1e-4


@pytest.fixture(scope="module")
def scenes() -> list[np.ndarray]:
    return [make_scene(s).correspondences for s in range(N_SCENES)]


@pytest.mark.parametrize("name", ["default", "paper"])
def test_shipped_networks_reproduce_the_stored_embeddings(name: str) -> None:
    stored = np.load(FIXTURES / "embeddings.npz")
    out = load_network(name).embed(stored["correspondences"])
    assert out.shape == stored[name].shape and out.dtype == np.float64
    np.testing.assert_allclose(out, stored[name], rtol=0, atol=PARITY)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize("name", ["default", "paper"])
def test_rust_embeddings_equal_torch_on_20_scenes(name: str, scenes: list[np.ndarray]) -> None:
    torch = pytest.importorskip("torch")
    from pointclm.model import load_model

    rust, net = load_network(name), load_model(name)
    worst = 0.0
    for corr in scenes:
        with torch.no_grad():
            want = net(torch.tensor(corr, dtype=torch.float32)[None])[0].double().numpy()
        worst = max(worst, float(np.abs(rust.embed(corr) - want).max()))
    assert worst <= PARITY, f"max abs difference {worst:.2e}"


def test_rust_and_torch_backends_find_identical_instances(scenes: list[np.ndarray]) -> None:
    pytest.importorskip("torch")
    found = 0
    for corr in scenes:
        rust = pointclm.register(corr, model="default", backend="rust")
        torch_ = pointclm.register(corr, model="default", backend="torch")
        assert_same_result(rust, torch_)
        found += len(rust)
    assert found >= 3 * N_SCENES  # the scenes hold several instances each


def test_register_batch_is_independent_of_threads(scenes: list[np.ndarray]) -> None:
    one = pointclm.register_batch(scenes, model="default", num_threads=1, seed=3)
    two = pointclm.register_batch(scenes, model="default", num_threads=2, seed=3)
    for a, b in zip(one, two, strict=True):
        assert_same_result(a, b)
    for k in (0, 7):
        alone = pointclm.register(scenes[k], model="default", seed=3, num_threads=2)
        assert_same_result(alone, one[k])


def test_embedding_is_independent_of_threads(scenes: list[np.ndarray]) -> None:
    net = load_network("default")
    np.testing.assert_array_equal(
        net.embed(scenes[0], num_threads=1), net.embed(scenes[0], num_threads=2)
    )


def test_network_object_and_recommended_config(scenes: list[np.ndarray]) -> None:
    net = Network(SHIPPED["default"])
    assert (net.depth, net.width, net.sigma_d) == (6, 64, 0.05)
    assert Path(net.path) == SHIPPED["default"]
    assert "depth=6" in repr(net)
    assert Config(**net.recommended_config()) == Config(tau_n=5, tau_s=0.85)
    by_object = pointclm.register(scenes[1], model=net)
    by_name = pointclm.register(scenes[1], model="default")
    assert_same_result(by_object, by_name)
    assert by_name.timings["embedding"] > 0
    assert "embedding" not in pointclm.register(scenes[1]).timings
    # the paper's thresholds are still the defaults without a model
    assert len(by_name) >= len(make_scene(1).poses) - 1


def test_a_caller_config_overrides_the_recommended_one(scenes: list[np.ndarray]) -> None:
    cfg = Config(tau_n=40)
    a = pointclm.register(scenes[2], model="default", config=cfg)
    f = load_network("default").embed(scenes[2])
    b = pointclm.register(scenes[2], features=f, config=cfg)
    assert_same_result(a, b)


def _copy_shipped(tmp_path: Path, name: str = "m") -> Path:
    dst = tmp_path / f"{name}.safetensors"
    shutil.copy(SHIPPED["default"], dst)
    shutil.copy(SHIPPED["default"].with_suffix(".json"), dst.with_suffix(".json"))
    return dst


def _set_architecture(path: Path, **arch: int) -> None:
    meta_path = path.with_suffix(".json")
    meta = json.loads(meta_path.read_text())
    meta["architecture"].update(arch)
    meta_path.write_text(json.dumps(meta))


def test_bad_weight_files_give_value_errors(tmp_path: Path) -> None:
    corr = make_scene(0).correspondences
    with pytest.raises(ValueError, match="no weights at .*missing.safetensors"):
        Network(tmp_path / "missing.safetensors")
    with pytest.raises(ValueError, match="no weights"):
        pointclm.register(corr, model=tmp_path / "missing.safetensors")

    path = _copy_shipped(tmp_path, "nojson")
    path.with_suffix(".json").unlink()
    with pytest.raises(ValueError, match=r"no weights at .*nojson\.json"):
        Network(path)

    wide = _copy_shipped(tmp_path, "wide")
    _set_architecture(wide, width=32)
    with pytest.raises(ValueError, match=r"lift.weight has shape \[64, 6, 1\].*\[32, 6, 1\]"):
        Network(wide)
    deep = _copy_shipped(tmp_path, "deep")
    _set_architecture(deep, depth=7)
    with pytest.raises(ValueError, match="depth 7 needs 184 tensors"):
        pointclm.register_batch([corr], model=deep)
    shallow = _copy_shipped(tmp_path, "shallow")
    _set_architecture(shallow, depth=5)
    with pytest.raises(ValueError, match="unexpected tensor .*5"):
        Network(shallow)

    corrupt = _copy_shipped(tmp_path, "corrupt")
    corrupt.write_bytes(b"not a safetensors file")
    with pytest.raises(ValueError, match="malformed weights .*not a safetensors file"):
        pointclm.register(corr, model=corrupt)
    truncated = _copy_shipped(tmp_path, "truncated")
    truncated.write_bytes(SHIPPED["default"].read_bytes()[:100_000])
    with pytest.raises(ValueError, match="malformed weights"):
        Network(truncated)
    badjson = _copy_shipped(tmp_path, "badjson")
    badjson.with_suffix(".json").write_text("{")
    with pytest.raises(ValueError, match="not valid JSON"):
        Network(badjson)


def test_many_consistent_correspondences_beyond_the_dense_limit_are_refused_up_front() -> None:
    # 50,000 uniform rows in a unit cube: most pairs are length-consistent at the network's
    # sigma_d, so only the dense attention (time ~ N^2, minutes here) could run.
    corr = np.random.default_rng(0).uniform(-0.5, 0.5, size=(50_000, 6))
    limit = "at most 32768 correspondences"
    t = time.perf_counter()
    with pytest.raises(pointclm.errors.InputError, match=limit) as err:
        pointclm.register(corr, model="default")
    assert isinstance(err.value, ValueError)
    assert "got 50000" in str(err.value) and "model=None" in str(err.value)
    with pytest.raises(ValueError, match=limit):
        load_network("default").embed(corr)
    assert time.perf_counter() - t < 30  # both refusals together, on a loaded 2-core machine


def test_a_rewritten_weight_file_is_reloaded(tmp_path: Path) -> None:
    path = _copy_shipped(tmp_path)
    assert load_network(path).width == 64
    _set_architecture(path, width=32)
    with pytest.raises(ValueError, match="has shape"):
        load_network(path)


def test_backend_and_device_arguments_are_checked(scenes: list[np.ndarray]) -> None:
    corr = scenes[0]
    with pytest.raises(ValueError, match="backend must be"):
        pointclm.register(corr, model="default", backend="onnx")
    with pytest.raises(ValueError, match="needs backend='torch'"):
        pointclm.register(corr, model="default", device="cuda")
    with pytest.raises(ValueError, match="pass model= too"):
        pointclm.register(corr, device="cpu")
    with pytest.raises(ValueError, match="backend='rust'"):
        pointclm.register(corr, model=load_network("default"), backend="torch")
    with pytest.raises(ValueError, match="needs backend='torch'"):
        pointclm.register(corr, model=object())
    with pytest.raises(ValueError, match="either features or model"):
        pointclm.register(corr, np.ones((len(corr), 4)), model="default")
    with pytest.raises(ValueError, match="either per-scene features or model"):
        pointclm.register_batch([(corr, np.ones((len(corr), 4)))], model="default")
    with pytest.raises(ValueError, match="either features or network"):
        pointclm._core.register(corr, np.ones((len(corr), 4)), network=load_network("default"))
    # device="cpu" is accepted by both backends
    pointclm.register(corr, model="default", device="cpu")


def test_rust_backend_needs_no_torch(tmp_path: Path) -> None:
    script = (
        "import sys\n"
        "sys.modules['torch'] = None  # any 'import torch' now raises ImportError\n"
        "import pointclm\n"
        "from pointclm.datasets import make_scene\n"
        "from pointclm.model import load_metadata, load_network\n"
        "scene = make_scene(4)\n"
        "r = pointclm.register(scene.correspondences, model='default')\n"
        "b = pointclm.register_batch([scene], model='paper', num_threads=1)\n"
        "assert len(r) >= 2 and len(b[0]) >= 2, (len(r), len(b[0]))\n"
        "assert load_metadata('default')['architecture']['width'] == 64\n"
        "try:\n"
        "    pointclm.register(scene.correspondences, model='default', backend='torch')\n"
        "except ImportError as e:\n"
        "    assert 'torch' in str(e)\n"
        "else:\n"
        "    raise AssertionError('torch backend ran without torch')\n"
        "print('ok')\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=tmp_path, check=False
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


# ---- inputs beyond the coordinates (normals, similarity) ----

INPUT_SETS = [("normals",), ("similarity",), ("normals", "similarity")]


def _packed(
    inputs: tuple[str, ...], corr: np.ndarray, nrm: np.ndarray, sim: np.ndarray
) -> np.ndarray:
    """The torch network's input columns for `inputs`."""
    extra = [nrm] if "normals" in inputs else []
    return np.hstack([corr, *extra, *([sim[:, None]] if "similarity" in inputs else [])])


def _randomise_batch_norms(torch: Any, net: Any) -> None:
    """Random BatchNorm statistics and affine parameters, drawn from torch's generator."""
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm1d):
                c = m.num_features
                m.running_mean.copy_(0.3 * torch.randn(c))
                m.running_var.copy_(0.5 + torch.rand(c))
                m.weight.copy_(0.5 + torch.rand(c))
                m.bias.copy_(0.2 * torch.randn(c))


def _random_network(torch: Any, inputs: tuple[str, ...], tmp_path: Path) -> tuple[Any, Path]:
    """A depth-3, width-32 torch network with random BatchNorm statistics and its
    convolutions scaled up (sharper attention, so that beta's normal term shows in the
    embedding), saved under `tmp_path`: (torch module, path)."""
    from pointclm.model import EmbeddingConfig, SCNonlocal, save_model

    torch.manual_seed(len(inputs))
    net = SCNonlocal(EmbeddingConfig(depth=3, width=32, inputs=inputs))
    _randomise_batch_norms(torch, net)
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, torch.nn.Conv1d):
                m.weight.mul_(2.0)
    net.eval()
    return net, save_model(net, tmp_path / f"{'_'.join(inputs)}.safetensors")


def _differences(
    torch: Any, inputs: tuple[str, ...], net: Any, rust: Network, other: Any
) -> tuple[float, float]:
    """Over 6 scenes with cues: the largest |Rust - torch| of `net`'s embedding, and the
    largest |other(x) - net(x)| (`other`: a torch variant that must differ)."""
    worst, moved = 0.0, 0.0
    for seed in range(6):
        corr, nrm, sim = scene_with_inputs(seed)
        x = torch.tensor(_packed(inputs, corr, nrm, sim), dtype=torch.float32)[None]
        with torch.no_grad():
            want = net(x)[0].double().numpy()
            changed = other(x)[0].double().numpy()
        worst = max(worst, float(np.abs(rust.embed(corr, nrm, sim) - want).max()))
        moved = max(moved, float(np.abs(changed - want).max()))
    return worst, moved


@pytest.mark.parametrize("inputs", INPUT_SETS, ids="+".join)
def test_networks_with_inputs_equal_torch(inputs: tuple[str, ...], tmp_path: Path) -> None:
    torch = pytest.importorskip("torch")
    net, path = _random_network(torch, inputs, tmp_path)
    rust = Network(path)
    assert rust.inputs == inputs and rust.normal_tolerance == 0.5
    assert f"inputs={inputs!r}" in repr(rust)
    worst, moved = _differences(
        torch, inputs, net, rust, lambda x: net(x, beta=net._beta(x[..., :6], None))
    )
    # measured <= 1.3e-6: float32 rounding, as for the plain networks
    assert worst <= PARITY, f"max abs difference {worst:.2e}"
    # the normal term of beta changes the embedding far beyond the parity tolerance
    assert ("normals" not in inputs) or moved > 100 * PARITY, moved


def test_missing_inputs_are_value_errors_naming_them(tmp_path: Path) -> None:
    torch = pytest.importorskip("torch")
    corr, nrm, sim = scene_with_inputs(1)
    both = Network(_random_network(torch, INPUT_SETS[2], tmp_path)[1])
    with pytest.raises(ValueError, match='needs the input "normals".*normals='):
        both.embed(corr, similarity=sim)
    with pytest.raises(ValueError, match='needs the input "similarity".*similarity='):
        both.embed(corr, normals=nrm)
    with pytest.raises(ValueError, match="normals"):
        pointclm._core.register(corr, network=both)
    # (N, 12) correspondences carry the normals too
    np.testing.assert_array_equal(
        both.embed(np.hstack([corr, nrm]), similarity=sim), both.embed(corr, nrm, sim)
    )
    # normals are rescaled to unit length, as Correspondences.with_normals does
    np.testing.assert_array_equal(both.embed(corr, 3 * nrm, sim), both.embed(corr, nrm, sim))


def test_bad_inputs_are_value_errors_naming_the_argument() -> None:
    net = load_network("default")
    corr, nrm, sim = scene_with_inputs(2)
    n = len(corr)
    for bad, match in [
        (dict(normals=nrm[:, :3]), "normals must have shape \\(N, 6\\)"),
        (dict(normals=nrm[:-1]), "normals must have shape"),
        (dict(normals=nrm.ravel()), "normals must be a 2-D array"),
        (dict(normals=np.zeros((n, 6))), "source normals"),
        (dict(normals=np.full((n, 6), np.nan)), "normals has a non-finite value"),
        (dict(similarity=sim[:, None]), "similarity must be a 1-D array"),
        (dict(similarity=sim[:-1]), "similarity must have shape \\(N,\\)"),
        (
            dict(similarity=np.where(np.arange(n) == 4, np.inf, sim)),
            r"similarity has a non-finite value .* in row 4",
        ),
        (dict(similarity=["a"] * n), "similarity must hold real numbers"),
    ]:
        with pytest.raises(ValueError, match=match):
            net.embed(corr, **bad)
    with pytest.raises(ValueError, match="not both"):
        net.embed(np.hstack([corr, nrm]), normals=nrm)


def test_the_plain_network_ignores_inputs_it_does_not_read() -> None:
    net = load_network("default")
    assert net.inputs == () and "inputs" not in repr(net)
    corr, nrm, sim = scene_with_inputs(3)
    np.testing.assert_array_equal(net.embed(corr, nrm, sim), net.embed(corr))


SCENE_INPUT_SETS = [(), ("normals",), ("normals", "similarity")]


def _scene_network(torch: Any, inputs: tuple[str, ...], tmp_path: Path) -> tuple[Any, Path]:
    """A torch network with per-scene normalization, saved under `tmp_path`: the shipped
    default's trained convolutions (the lift's columns of `inputs` random), random BatchNorm
    weights, biases and running statistics. (Random convolutions make a poor test: their
    attention output is nearly constant over the rows, and normalising it by its tiny spread
    amplifies float32 rounding until torch itself differs from float64 torch by ~1e-3.)"""
    from pointclm.model import SCNonlocal, load_model, save_model

    torch.manual_seed(10 + len(inputs))
    trained = load_model("default")
    config = dataclasses.replace(trained.config, inputs=inputs, normalization="scene")
    net = SCNonlocal(config)
    state = trained.state_dict()
    with torch.no_grad():
        lift = net.lift.weight.clone()
        lift[:, :6] = state["lift.weight"]
        net.load_state_dict({**state, "lift.weight": lift})
    _randomise_batch_norms(torch, net)
    net.eval()
    return net, save_model(net, tmp_path / f"scene_{'_'.join(inputs)}.safetensors")


@pytest.mark.parametrize("inputs", SCENE_INPUT_SETS, ids=lambda t: "+".join(t) or "plain")
def test_scene_normalization_equals_torch(inputs: tuple[str, ...], tmp_path: Path) -> None:
    torch = pytest.importorskip("torch")
    from pointclm.model import SCNonlocal

    net, path = _scene_network(torch, inputs, tmp_path)
    rust = Network(path)
    assert rust.normalization == "scene" and rust.inputs == inputs
    assert "normalization='scene'" in repr(rust)
    # the same weights with their (random) running statistics: a wrong use of them shows
    running = SCNonlocal(dataclasses.replace(net.config, normalization="running"))
    running.load_state_dict(net.state_dict())
    running.eval()
    worst, moved = _differences(torch, inputs, net, rust, running)
    # measured <= 2.7e-5 (float32 rounding, amplified where a channel varies little)
    assert worst <= PARITY, f"max abs difference {worst:.2e}"
    # per-scene statistics change the embedding far beyond the parity tolerance
    assert moved > 100 * PARITY, moved


def test_running_normalization_is_the_default() -> None:
    net = load_network()
    assert net.normalization == "running"
    assert "normalization" not in repr(net)

"""The embedding network, its loss and its training (skipped without torch)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("safetensors")

import pointclm  # noqa: E402
from helpers import DATA, DATA_HINT, needs_data, scene_with_inputs  # noqa: E402
from pointclm import _core  # noqa: E402
from pointclm.datasets import make_scene  # noqa: E402
from pointclm.model import (  # noqa: E402
    EmbeddingConfig,
    SCNonlocal,
    contrastive_loss,
    load_metadata,
    load_model,
    negative_distances,
    normal_consistency,
    save_model,
    spatial_consistency,
)
from pointclm.staged import spatial_consistency as core_beta  # noqa: E402
from pointclm.training import TrainConfig, train  # noqa: E402

FIXTURES = Path(__file__).parent / "fixtures"


def unit(*v: float) -> list[float]:
    n = math.sqrt(sum(x * x for x in v))
    return [x / n for x in v]


def test_paper_size_parameter_count() -> None:
    assert sum(p.numel() for p in SCNonlocal().parameters()) == 1_048_448


def test_beta_equals_the_rust_core() -> None:
    corr = make_scene(3, n_keep=400).correspondences
    ours = spatial_consistency(torch.tensor(corr)[None], 0.05)[0].numpy()
    np.testing.assert_allclose(ours, core_beta(corr, 0.05), rtol=0, atol=1e-12)


def test_loss_matches_hand_computation() -> None:
    f = [unit(1, 0), unit(1, 0.2), unit(0, 1), unit(-1, 0.1)]
    labels = [0, 0, 1, -1]
    d = [[math.dist(a, b) for b in f] for a in f]
    pos = [d[0][1], d[1][0]]  # ordered pairs within instance 0
    pos_term = sum(max(x - 0.1, 0) ** 2 for x in pos) / len(pos)
    # anchors 0, 1, 2 (inliers); hardest negative = nearest row with another label
    hardest = [min(d[i][j] for j in range(4) if labels[j] != labels[i]) for i in (0, 1, 2)]
    neg_term = sum(max(1.4 - x, 0) ** 2 for x in hardest) / 3
    loss, _ = contrastive_loss(torch.tensor([f], dtype=torch.float64), torch.tensor([labels]))
    assert float(loss) == pytest.approx(pos_term + neg_term, rel=1e-12)


def test_hardest_negatives_are_the_true_minimum() -> None:
    g = torch.Generator().manual_seed(0)
    feats = torch.nn.functional.normalize(torch.randn(2, 60, 8, generator=g), dim=-1)
    labels = torch.randint(-1, 3, (2, 60), generator=g)
    dist = torch.cdist(feats, feats)
    chosen, valid = negative_distances(dist, labels, "hardest")
    for b in range(2):
        for i in range(60):
            if labels[b, i] < 0:
                assert not valid[b, i]
                continue
            others = [float(dist[b, i, j]) for j in range(60) if labels[b, j] != labels[b, i]]
            assert float(chosen[b, i]) == pytest.approx(min(others))
    rand, _ = negative_distances(dist, labels, "random", torch.Generator().manual_seed(1))
    assert (rand[valid] >= chosen[valid] - 1e-12).all()


def test_a_few_steps_lower_the_loss() -> None:
    torch.manual_seed(0)
    scene = make_scene(1, n_keep=300, n_outlier_blocks=10)
    x = torch.tensor(scene.correspondences, dtype=torch.float32)[None]
    y = torch.tensor(scene.labels)[None]
    net = SCNonlocal(EmbeddingConfig(depth=2, width=32))
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    losses = []
    for _ in range(30):
        loss, _ = contrastive_loss(net(x), y)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert np.mean(losses[-5:]) < 0.8 * np.mean(losses[:5])


@pytest.mark.parametrize("name", ["default", "paper"])
def test_shipped_weights_reproduce_stored_embeddings(name: str) -> None:
    stored = np.load(FIXTURES / "embeddings.npz")
    net = load_model(name)
    with torch.no_grad():
        out = net(torch.tensor(stored["correspondences"], dtype=torch.float32)[None])[0]
    np.testing.assert_allclose(out.numpy(), stored[name], atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(out.numpy(), axis=1), 1.0, atol=1e-5)


def test_register_with_the_shipped_model_finds_instances() -> None:
    scene = make_scene(11)
    result = pointclm.register(scene.correspondences, model="default")
    free = pointclm.register(scene.correspondences)
    assert len(result) >= len(scene.poses) - 1
    assert len(result) >= len(free) - 1
    batch = pointclm.register_batch([scene], model="default", num_threads=1)
    np.testing.assert_array_equal(batch[0].transformations, result.transformations)
    with pytest.raises(ValueError, match="either features or model"):
        pointclm.register(scene.correspondences, np.ones((1000, 4)), model="default")


def test_bad_weight_files_give_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no weights"):
        load_model(tmp_path / "missing.safetensors")
    path = save_model(SCNonlocal(EmbeddingConfig(depth=1, width=8)), tmp_path / "m.safetensors")
    meta = path.with_suffix(".json")
    meta.write_text(meta.read_text().replace('"width": 8', '"width": 16'))
    with pytest.raises(ValueError, match="do not match"):
        load_model(path)
    path.write_bytes(b"not a safetensors file")
    with pytest.raises(ValueError, match="unreadable"):
        load_model(path)


def test_embedding_config_inputs_are_checked_and_canonical() -> None:
    cfg = EmbeddingConfig(depth=1, width=8, inputs=["similarity", "normals"])  # type: ignore[arg-type]
    assert cfg.inputs == ("normals", "similarity") and cfg.input_channels == 13
    assert cfg == EmbeddingConfig(depth=1, width=8, inputs=("normals", "similarity"))
    assert EmbeddingConfig(inputs=("normals",)).input_channels == 12
    assert EmbeddingConfig(inputs=("similarity",)).input_channels == 7
    assert EmbeddingConfig().input_channels == 6
    assert EmbeddingConfig().as_dict() == {"depth": 12, "width": 128, "sigma_d": 0.05}
    assert cfg.as_dict() == {
        "depth": 1,
        "width": 8,
        "sigma_d": 0.05,
        "inputs": ["normals", "similarity"],
        "normal_tolerance": 0.5,
    }
    for bad, match in [
        ({"inputs": ("colour",)}, "unknown network inputs \\['colour'\\]"),
        ({"inputs": "normals"}, "sequence of input names"),
        ({"inputs": ("normals", "normals")}, "twice"),
        ({"normal_tolerance": 0.0}, "normal_tolerance"),
        ({"normal_tolerance": 2.5}, "normal_tolerance"),
    ]:
        with pytest.raises(ValueError, match=match):
            EmbeddingConfig(**bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="reads 13 input channels .*got 6"):
        SCNonlocal(cfg)(torch.zeros(1, 5, 6))


def test_inputs_round_trip_through_weight_files(tmp_path: Path) -> None:
    plain_keys = {"depth", "width", "sigma_d"}
    for inputs in [(), ("normals",), ("similarity",), ("normals", "similarity")]:
        cfg = EmbeddingConfig(depth=1, width=8, inputs=inputs, normal_tolerance=0.3)
        path = save_model(SCNonlocal(cfg), tmp_path / f"m{len(inputs)}{inputs[:1]}.safetensors")
        arch = load_metadata(path)["architecture"]
        # the plain network's metadata is what it was before inputs existed
        assert set(arch) == plain_keys | ({"inputs", "normal_tolerance"} if inputs else set())
        model = load_model(path)
        assert model.config == (cfg if inputs else EmbeddingConfig(depth=1, width=8))
        assert model.lift.in_channels == cfg.input_channels
        assert pointclm.Network(path).inputs == inputs
    meta = path.with_suffix(".json")
    meta.write_text(meta.read_text().replace('"similarity"', '"colour"'))
    with pytest.raises(ValueError, match="colour"):
        load_model(path)
    with pytest.raises(ValueError, match='unknown network input "colour"'):
        pointclm.Network(path)


def test_normal_beta_equals_the_rust_core() -> None:
    corr, nrm, _ = scene_with_inputs(3)
    corr, nrm = corr[:500], nrm[:500]
    ours = normal_consistency(torch.tensor(corr)[None], torch.tensor(nrm)[None], 0.05, 0.5)[0]
    # (N, 12) rows give the core's normal term at its default tolerance, 0.5
    want = _core.spatial_consistency(np.hstack([corr, nrm]), 0.05)
    np.testing.assert_allclose(ours.numpy(), want, rtol=0, atol=1e-12)
    assert torch.equal(ours, ours.T)
    plain = spatial_consistency(torch.tensor(corr)[None], 0.05)[0]
    assert int((ours < plain - 0.1).sum()) > 100  # the normal term cuts pairs


def _rigid(
    rng: np.random.Generator, points: np.ndarray, normals: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """`points` and `normals` (N, 3) moved by one random rigid motion, normals' signs flipped
    at random (beta ignores them)."""
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    r = q * np.sign(np.linalg.det(q))
    flips = rng.choice([-1.0, 1.0], size=(len(normals), 1))
    return points @ r.T + rng.uniform(-2, 2, size=3), flips * normals @ r.T


def test_normal_beta_is_invariant_to_rigid_motions_of_each_side() -> None:
    """The network's embedding is not rotation invariant (it reads raw coordinates), but its
    beta is: each side's points and normals rotated together leave it unchanged."""
    corr, nrm, sim = scene_with_inputs(5)
    rng = np.random.default_rng(5)
    src, ns = _rigid(rng, corr[:, :3], nrm[:, :3])
    dst, nt = _rigid(rng, corr[:, 3:], nrm[:, 3:])
    net = SCNonlocal(EmbeddingConfig(depth=1, width=8, inputs=("normals", "similarity")))
    net = net.double()
    before = net.consistency(torch.tensor(np.hstack([corr, nrm, sim[:, None]]))[None])
    after = net.consistency(torch.tensor(np.hstack([src, dst, ns, nt, sim[:, None]]))[None])
    np.testing.assert_allclose(after.numpy(), before.numpy(), rtol=0, atol=1e-9)
    assert float(before.sum()) > len(corr)  # more than the diagonal
    # the normals do enter beta: turning the source normals alone changes it
    turned = np.hstack([corr, ns, nrm[:, 3:], sim[:, None]])
    assert not torch.allclose(net.consistency(torch.tensor(turned)[None]), before)


@needs_data
def test_cpu_training_smoke_run_and_resume(tmp_path: Path) -> None:
    cfg = TrainConfig.preset("smoke", data_dir=str(DATA))
    first = train(cfg, tmp_path, progress=False)
    assert first["finished"] and (tmp_path / "model.safetensors").is_file()
    assert (tmp_path / "train_config.json").is_file() and (tmp_path / "checkpoint.json").is_file()
    more = TrainConfig.preset("smoke", data_dir=str(DATA), iterations=9)
    again = train(more, tmp_path, resume=True, progress=False)
    assert again["iteration"] == 9
    load_model(tmp_path / "model.safetensors")


def test_training_is_deterministic(tmp_path: Path) -> None:
    if not DATA.is_dir():
        pytest.skip(DATA_HINT)
    cfg = TrainConfig.preset("smoke", data_dir=str(DATA), iterations=3, val_every=3)
    train(cfg, tmp_path / "a", progress=False)
    train(cfg, tmp_path / "b", progress=False)
    la = (tmp_path / "a" / "log.jsonl").read_text().splitlines()
    lb = (tmp_path / "b" / "log.jsonl").read_text().splitlines()
    assert la == lb

"""Cues beyond coordinates (normals at both ends, match similarity): how they are computed,
packed for a network, kept in the realistic scene bank and augmented with the scene."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pointclm.cues import INPUTS, check_inputs, input_channels, pack, similarity
from pointclm.errors import InputError
from pointclm.training.config import TrainConfig
from pointclm.training.realistic import SceneBank, bank_cues, realistic_sample


def test_similarity_is_one_for_equal_descriptors_and_half_at_the_median() -> None:
    d = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    s = similarity(d)
    assert s[0] == 1.0 and s[2] == pytest.approx(0.5)
    assert np.all(np.diff(s) < 0) and np.all(s > 0)
    # scale-free: FPFH distances grow with noise and density, the cue must not
    np.testing.assert_allclose(similarity(7.5 * d), s)
    assert np.all(similarity(np.zeros(4)) == 1.0)
    assert similarity([]).shape == (0,)
    with pytest.raises(InputError, match="finite"):
        similarity([1.0, np.nan])
    with pytest.raises(InputError, match=">= 0"):
        similarity([1.0, -1.0])


def test_inputs_are_checked_and_ordered() -> None:
    assert check_inputs(["similarity", "normals"]) == INPUTS
    assert input_channels(()) == 6 and input_channels(INPUTS) == 13
    assert input_channels(["similarity"]) == 7
    with pytest.raises(ValueError, match="unknown network inputs"):
        check_inputs(["colour"])
    with pytest.raises(ValueError, match="unknown network inputs"):
        check_inputs("normals")  # a string is not a list of names


def test_pack_lays_out_the_columns_and_names_what_is_missing() -> None:
    rng = np.random.default_rng(0)
    corr, normals, sims = rng.normal(size=(5, 6)), 3.0 * rng.normal(size=(5, 6)), rng.random(5)
    x = pack(corr, INPUTS, normals, sims)
    assert x.shape == (5, 13)
    np.testing.assert_array_equal(x[:, :6], corr)
    np.testing.assert_allclose(np.linalg.norm(x[:, 6:9], axis=1), 1.0)  # unit normals
    np.testing.assert_allclose(
        x[:, 9:12] * np.linalg.norm(normals[:, 3:], axis=1)[:, None], normals[:, 3:]
    )
    np.testing.assert_array_equal(x[:, 12], sims)
    np.testing.assert_array_equal(pack(corr, (), normals, sims), corr)  # not taken: ignored
    with pytest.raises(InputError, match="takes normals.*pass normals="):
        pack(corr, ("normals",))
    with pytest.raises(InputError, match="similarity must have shape"):
        pack(corr, ("similarity",), similarity=sims[:3])
    with pytest.raises(InputError, match="non-zero"):
        pack(corr, ("normals",), np.zeros((5, 6)))


def test_the_bank_keeps_each_rows_cues(bank: SceneBank) -> None:
    from pointclm.datasets.scenes import SceneParams, make_realistic_scene
    from pointclm.training.realistic import scene_seed

    scene = make_realistic_scene(scene_seed(0, 0, 1), SceneParams(model="bunny"))
    assert bank.normals is not None and bank.similarities is not None
    # half precision in the file: a normal to 1e-3
    np.testing.assert_allclose(bank.normals[1], scene.pair_normals, atol=2e-3)
    np.testing.assert_allclose(bank.similarities[1], similarity(scene.match_distance), atol=2e-3)
    normals, sims = bank_cues(bank, 1, ("similarity",))
    assert normals is None and sims is not None and sims.dtype == np.float64


def test_samples_turn_normals_with_their_side(bank: SceneBank) -> None:
    x, y = realistic_sample(bank, np.random.default_rng(3), 0.05, 10_000, 0.0, INPUTS)
    assert x.shape[1] == 13 and x.dtype == np.float32
    i = next(k for k in range(len(bank)) if len(bank.labels[k]) == len(y))
    inl = np.flatnonzero(y == np.bincount(y[y >= 0]).argmax())
    # Inliers of one copy: the angle between two of their normals is the same on both sides
    # after each side's own random rotation, as it was in the bank.
    ns, nt = x[inl, 6:9].astype(np.float64), x[inl, 9:12].astype(np.float64)
    bs, bt = bank.normals[i][inl, :3], bank.normals[i][inl, 3:]  # type: ignore[index]
    np.testing.assert_allclose(ns @ ns.T, bs @ bs.T, atol=5e-3)
    np.testing.assert_allclose(nt @ nt.T, bt @ bt.T, atol=5e-3)
    np.testing.assert_allclose(x[:, 12], bank.similarities[i], atol=1e-6)  # type: ignore[index]


def test_old_banks_without_cues_load_and_say_what_is_missing(
    bank: SceneBank, tmp_path: Path
) -> None:
    old = SceneBank(
        *[
            getattr(bank, f)
            for f in (
                "correspondences",
                "labels",
                "voxels",
                "diameters",
                "poses",
                "models",
                "model_of",
            )
        ]
    )
    old.save(tmp_path / "old.npz")
    loaded = SceneBank.load(tmp_path / "old.npz")
    assert loaded.normals is None
    realistic_sample(loaded, np.random.default_rng(0), 0.05, 100)  # coordinates only: fine
    with pytest.raises(ValueError, match="holds no cues"):
        realistic_sample(loaded, np.random.default_rng(0), 0.05, 100, 0.0, ("normals",))


def test_banks_built_in_parts_join_into_the_whole(bank: SceneBank) -> None:
    first = SceneBank.build(["bunny", "torus"], [2, 0], seed=0, workers=1)
    second = SceneBank.build(["bunny", "torus"], [0, 1], seed=0, workers=1)
    whole = SceneBank.concat([first, second])
    assert len(whole) == 3 and list(whole.model_of) == [0, 0, 1]
    np.testing.assert_allclose(whole.correspondences[1], bank.correspondences[1], rtol=1e-6)
    with pytest.raises(ValueError, match="same model list"):
        SceneBank.concat([first, bank])


def test_config_with_inputs_trains_on_realistic_scenes_only() -> None:
    with pytest.raises(ValueError, match="realistic_fraction to 1"):
        TrainConfig(inputs=("normals",), realistic_fraction=0.5)
    with pytest.raises(ValueError, match="order"):
        TrainConfig(inputs=("similarity", "normals"), realistic_fraction=1.0)
    with pytest.raises(ValueError, match="unknown network inputs"):
        TrainConfig(inputs=("colour",), realistic_fraction=1.0)
    cfg = TrainConfig.preset("realistic-gpu")
    assert cfg.inputs == INPUTS and cfg.realistic_fraction == 1.0


def test_a_network_with_cues_trains_and_registers_on_every_path(
    bank: SceneBank, tmp_path: Path
) -> None:
    pytest.importorskip("torch")
    import pointclm
    from pointclm.datasets.scenes import SceneParams, make_realistic_scene
    from pointclm.training import train

    path = tmp_path / "bank.npz"
    bank.save(path)
    cfg = TrainConfig.preset(
        "smoke",
        realistic_models=("bunny",),
        realistic_fraction=1.0,
        realistic_bank=str(path),
        val_realistic_bank=str(path),
        inputs=INPUTS,
        iterations=2,
        val_every=2,
    )
    assert train(cfg, tmp_path / "run", progress=False)["finished"]
    weights = tmp_path / "run" / "model.safetensors"
    assert pointclm.Network(weights).inputs == INPUTS

    scene = make_realistic_scene(5, SceneParams(model="bunny"))
    cues = {"normals": scene.pair_normals, "similarity": similarity(scene.match_distance)}
    corr = scene.correspondences
    for backend in ("rust", "torch"):
        r = pointclm.register(corr, model=str(weights), backend=backend, **cues)
        assert len(r.labels) == len(corr)
    with pytest.raises(ValueError, match="takes normals"):
        pointclm.register(corr, model=str(weights), similarity=cues["similarity"])
    out = pointclm.register_point_clouds(
        scene.source_points, scene.target_points, model=str(weights), num_threads=1
    )
    assert out.transformations.shape[1:] == (4, 4)


def _normal_beta_reference(corr: np.ndarray, normals: np.ndarray, sigma: float, tol: float):
    """The core's `NormalRow::beta` (consistency.rs), one pair at a time in float64."""
    n = len(corr)
    out = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            ds, dt = corr[j, :3] - corr[i, :3], corr[j, 3:] - corr[i, 3:]
            ls, lt = np.linalg.norm(ds), np.linalg.norm(dt)
            length = max(0.0, 1 - (ls - lt) ** 2 / sigma**2)
            nsi, nti, nsj, ntj = normals[i, :3], normals[i, 3:], normals[j, :3], normals[j, 3:]
            da = abs(nsi @ nsj) - abs(nti @ ntj)
            dp = abs(nsi @ ds) - abs(nti @ dt)
            dq = abs(nsj @ ds) - abs(ntj @ dt)
            w = tol * 0.5 * (ls + lt) + sigma
            planes = max(0.0, 1 - dp**2 / w**2) * max(0.0, 1 - dq**2 / w**2)
            out[i, j] = length * max(0.0, 1 - da**2 / tol**2) * planes
    return out


def test_the_torch_normal_term_is_the_cores() -> None:
    torch = pytest.importorskip("torch")
    from pointclm.model.network import normal_consistency

    rng = np.random.default_rng(2)
    src = rng.normal(size=(30, 3)) * 0.2
    rot, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    nrm = rng.normal(size=(30, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    corr = np.hstack([src, src @ rot.T + rng.normal(scale=0.01, size=(30, 3))])
    normals = np.hstack([nrm, nrm @ rot.T + rng.normal(scale=0.05, size=(30, 3))])
    normals[:, 3:] /= np.linalg.norm(normals[:, 3:], axis=1, keepdims=True)
    want = _normal_beta_reference(corr, normals, 0.05, 0.5)
    got = normal_consistency(torch.tensor(corr)[None], torch.tensor(normals)[None], 0.05, 0.5)[
        0
    ].numpy()
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert 0.1 < (want > 0).mean() < 1  # the test exercises both sides of the clamps


def test_scene_normalization_normalises_each_scene_by_its_own_rows(tmp_path: Path) -> None:
    torch = pytest.importorskip("torch")
    from pointclm.model import EmbeddingConfig, SCNonlocal, load_model, save_model

    torch.manual_seed(0)
    net = SCNonlocal(EmbeddingConfig(2, 16, normalization="scene"))
    x = torch.randn(1, 60, 6)
    net.train()
    for _ in range(3):
        net(torch.randn(1, 60, 6) * 5.0)  # running statistics far from this scene's
    with torch.no_grad():
        net.train()
        trained = net(x)
        net.eval()
        inferred = net(x)
    # Eval mode normalises as training did: by the scene's own statistics.
    torch.testing.assert_close(inferred, trained)
    save_model(net, tmp_path / "scene.safetensors")
    loaded = load_model(tmp_path / "scene.safetensors")
    assert loaded.config.normalization == "scene"
    with torch.no_grad():
        torch.testing.assert_close(loaded(x), inferred)
        running = SCNonlocal(EmbeddingConfig(2, 16))
        running.load_state_dict(net.state_dict())
        running.eval()
        assert (running(x) - inferred).abs().max() > 1e-2  # the test can tell them apart
        # Scenes sharing a batch are normalised apart: each embeds as it would alone.
        other = torch.randn(1, 60, 6) * 3.0
        batched = loaded(torch.cat([x, other]))[:1]
        torch.testing.assert_close(batched, inferred, atol=1e-4, rtol=0)  # f32 sums differ
    assert "normalization" not in EmbeddingConfig(2, 16).as_dict()  # plain files unchanged
    with pytest.raises(ValueError, match="normalization must be one of"):
        EmbeddingConfig(2, 16, normalization="layer")
    TrainConfig(normalization="scene", realistic_fraction=0.5)  # stacked scenes: each alone


def test_banks_only_builds_both_banks_for_another_machine(tmp_path: Path) -> None:
    import json

    from pointclm.cli import main

    cfg = tmp_path / "cfg.json"
    cfg.write_text(
        json.dumps(
            {
                "preset": "smoke",
                "realistic_fraction": 1.0,
                "realistic_models": ["torus"],
                "realistic_scenes_per_model": 1,
                "procedural_shapes": 1,
                "procedural_scenes_per_shape": 1,
                "val_shapes": ["bunny"],
                "val_realistic_scenes_per_model": 1,
                "num_workers": 0,
            }
        )
    )
    out = tmp_path / "banks"
    assert main(["train", "--config", str(cfg), "--out", str(out), "--banks-only"]) == 0
    bank = SceneBank.load(out / "scene_bank.npz")
    assert len(bank) == 2 and bank.models[0] == "torus" and bank.normals is not None
    assert bank.models[1].split("-")[0] in ("superquadric", "blend", "extrusion")
    assert len(SceneBank.load(out / "val_scene_bank.npz")) == 1
    assert main(["train", "--preset", "smoke", "--out", str(out), "--banks-only"]) == 2


def test_realistic_samples_stack_by_size_into_fewer_batches(bank: SceneBank) -> None:
    from pointclm.training.loop import stacked_by_size

    rng = np.random.default_rng(0)
    samples = [realistic_sample(bank, rng, 0.05, 1000, 0.0, INPUTS) for _ in range(5)]
    alone = stacked_by_size(samples, 1, np.random.default_rng(1))
    assert [x.shape[0] for x, _ in alone] == [1] * 5  # size 1: each whole and alone
    assert sorted(len(y) for _, y in samples) == [y.shape[1] for _, y in alone]
    groups = stacked_by_size(samples, 2, np.random.default_rng(1))
    assert [x.shape[0] for x, _ in groups] == [2, 2, 1]
    for x, y in groups:
        assert x.shape[:2] == y.shape and x.shape[2] == 13
    # a stacked scene is a subset of its own rows
    x, y = groups[0]
    rows = {tuple(r) for s in samples for r in s[0].tolist()}
    assert all(tuple(r) in rows for r in x[0].tolist())

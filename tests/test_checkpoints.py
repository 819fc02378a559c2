"""Training checkpoints: safetensors + JSON, never a pickle; a resumed run equals an
uninterrupted one."""

from __future__ import annotations

import json
import os
import pickle
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
safetensors_torch = pytest.importorskip("safetensors.torch")

from helpers import DATA, needs_data  # noqa: E402
from pointclm.cli import main  # noqa: E402
from pointclm.model import EmbeddingConfig, SCNonlocal  # noqa: E402
from pointclm.training import TrainConfig, train  # noqa: E402
from pointclm.training.checkpoint import load_checkpoint, save_checkpoint  # noqa: E402


def _model_and_optimizer(seed: int = 0) -> tuple[object, object]:
    torch.manual_seed(seed)
    model = SCNonlocal(EmbeddingConfig(2, 8, 0.05))
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    x = torch.randn(1, 20, 6)
    model(x).sum().backward()
    opt.step()
    return model, opt


def test_checkpoint_round_trip(tmp_path: Path) -> None:
    model, opt = _model_and_optimizer()
    best = {"key": [0.5, 0.25], "iteration": 3, "metrics": {"mean_f1": 0.5}}
    save_checkpoint(tmp_path, model, opt, iteration=3, best=best, elapsed=1.5)
    rng_after_save = torch.get_rng_state()
    torch.rand(5)  # move the RNG: loading must restore it
    other, other_opt = _model_and_optimizer(seed=1)
    meta = load_checkpoint(tmp_path, other, other_opt)
    assert meta == {"iteration": 3, "elapsed": 1.5, "best": best}
    assert torch.equal(torch.get_rng_state(), rng_after_save)
    for (ka, va), (kb, vb) in zip(
        model.state_dict().items(), other.state_dict().items(), strict=True
    ):
        assert ka == kb and torch.equal(va, vb)
    sa, sb = opt.state_dict(), other_opt.state_dict()
    assert sa["param_groups"] == sb["param_groups"]
    for pid in sa["state"]:
        for key, value in sa["state"][pid].items():
            assert torch.equal(value, sb["state"][pid][key])
    # one tensor file is kept, named by the iteration
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "checkpoint-000000003.safetensors",
        "checkpoint.json",
    ]


def test_tampered_checkpoints_are_refused(tmp_path: Path) -> None:
    model, opt = _model_and_optimizer()
    save_checkpoint(tmp_path, model, opt, iteration=1, best=None, elapsed=0.0)
    meta_path = tmp_path / "checkpoint.json"
    meta = json.loads(meta_path.read_text())
    tensors = tmp_path / meta["tensors"]
    good = tensors.read_bytes()
    tensors.write_bytes(good[:-1] + bytes([good[-1] ^ 0xFF]))
    with pytest.raises(ValueError, match="not the file it was saved with"):
        load_checkpoint(tmp_path, model, opt)
    tensors.write_bytes(good)
    for bad in (
        {**meta, "tensors": "../../etc/passwd"},
        {**meta, "iteration": -1},
        {**meta, "optimizer": []},
        {**meta, "format": "something"},
        [1, 2],
    ):
        meta_path.write_text(json.dumps(bad))
        with pytest.raises(ValueError):
            load_checkpoint(tmp_path, model, opt)
    meta_path.write_text("{not json")
    with pytest.raises(ValueError, match="unreadable"):
        load_checkpoint(tmp_path, model, opt)
    # a checkpoint of another architecture
    meta_path.write_text(json.dumps(meta))
    small = SCNonlocal(EmbeddingConfig(1, 8, 0.05))
    with pytest.raises(ValueError, match="does not fit"):
        load_checkpoint(tmp_path, small, torch.optim.Adam(small.parameters()))


def test_legacy_pickle_checkpoint_is_never_loaded(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"

    class Exploit:
        def __reduce__(self) -> tuple[object, tuple[str]]:
            return (os.system, (f"touch {marker}",))

    (tmp_path / "checkpoint.pt").write_bytes(pickle.dumps(Exploit()))
    model, opt = _model_and_optimizer()
    with pytest.raises(ValueError, match="pickle checkpoint"):
        load_checkpoint(tmp_path, model, opt)
    assert not marker.exists()
    assert main(["train", "--preset", "smoke", "--out", str(tmp_path), "--resume"]) == 2
    assert not marker.exists()


@needs_data
def test_resumed_run_equals_uninterrupted_run(tmp_path: Path) -> None:
    cfg = TrainConfig.preset("smoke", data_dir=str(DATA))
    whole = train(cfg, tmp_path / "whole", progress=False)
    # max_minutes=0: stop after the first iteration's checkpoint, as a killed job would.
    part = train(cfg, tmp_path / "split", progress=False, max_minutes=0)
    assert part["iteration"] == 1 and not part["finished"]
    rest = train(cfg, tmp_path / "split", progress=False, resume=True)
    assert rest["finished"] and rest["iteration"] == whole["iteration"]
    log_whole = (tmp_path / "whole" / "log.jsonl").read_text().splitlines()
    log_split = (tmp_path / "split" / "log.jsonl").read_text().splitlines()
    assert log_whole == log_split
    a = safetensors_torch.load_file(str(tmp_path / "whole" / "model.safetensors"))
    b = safetensors_torch.load_file(str(tmp_path / "split" / "model.safetensors"))
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k].numpy(), b[k].numpy())
    assert not list((tmp_path / "split").glob("*.pt"))


def test_training_caches_are_read_without_pickle(tmp_path: Path) -> None:
    from pointclm.training.data import ShapeBank
    from pointclm.training.realistic import SceneBank

    bank = ShapeBank({"a": np.ones((4, 3)), "b": np.zeros((5, 3))})
    bank.save(tmp_path / "shapes.npz")
    back = ShapeBank.load(tmp_path / "shapes.npz")
    assert sorted(back.clouds) == ["a", "b"] and back["b"].shape == (5, 3)
    np.savez(tmp_path / "objects.npz", a=np.array([object()], dtype=object))
    with pytest.raises(ValueError, match="pickle"):
        ShapeBank.load(tmp_path / "objects.npz")
    with pytest.raises(FileNotFoundError):
        ShapeBank.load(tmp_path / "missing.npz")

    scenes = SceneBank(
        [np.zeros((3, 6)), np.ones((2, 6))],
        [np.zeros(3, np.int64), np.ones(2, np.int64)],
        np.array([0.1, 0.2]),
        np.array([1.0, 2.0]),
        [np.stack([np.eye(4)]), np.stack([np.eye(4), np.eye(4)])],
        ["m"],
        np.array([0, 0]),
    )
    scenes.save(tmp_path / "scenes.npz")
    again = SceneBank.load(tmp_path / "scenes.npz")
    assert len(again) == 2 and again.poses[1].shape == (2, 4, 4) and again.models == ["m"]
    with np.load(tmp_path / "scenes.npz") as z:
        arrays = dict(z)
    arrays["counts"] = np.array([3, 10**6])  # more rows than the file holds
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ValueError, match="inconsistent"):
        SceneBank.load(tmp_path / "bad.npz")

"""`pointclm eval` and `pointclm demo`: the method flags override each path's own default
config, as they do in `register` and `batch`: on realistic scenes the thresholds for
refined or raw poses, with a network its recommended thresholds; and `evaluate` takes them as
``config_overrides``."""

from __future__ import annotations

import dataclasses
import inspect
import json
from pathlib import Path
from typing import Any

import pointclm.cli.commands
import pointclm.datasets.scenes
import pointclm.evaluation
import pointclm.registration
import pytest
from pointclm import Config
from pointclm.cli import main
from pointclm.datasets import make_scenes
from pointclm.embedding import resolve
from pointclm.errors import ConfigError
from pointclm.evaluation import evaluate
from pointclm.point_clouds import cloud_base_config, cloud_config


def _spy_on_register(monkeypatch: pytest.MonkeyPatch, module: Any) -> list[Any]:
    """The configs `pointclm.register` receives from `module` (where it was imported), call by
    call, however they are passed."""
    seen: list[Any] = []
    real = pointclm.registration.register
    signature = inspect.signature(real)

    def spy(*args: Any, **kwargs: Any) -> Any:
        seen.append(signature.bind(*args, **kwargs).arguments.get("config"))
        return real(*args, **kwargs)

    monkeypatch.setattr(module, "register", spy)
    return seen


def _spy_on_voxels(monkeypatch: pytest.MonkeyPatch) -> list[float]:
    """The voxel of every realistic scene built, in order."""
    voxels: list[float] = []
    real = pointclm.datasets.scenes.make_realistic_scene

    def spy(*args: Any, **kwargs: Any) -> Any:
        scene = real(*args, **kwargs)
        voxels.append(scene.voxel_size)
        return scene

    monkeypatch.setattr(pointclm.datasets.scenes, "make_realistic_scene", spy)
    return voxels


def _eval(capsys: pytest.CaptureFixture[str], tmp_path: Path, *argv: str) -> dict[str, Any]:
    out = tmp_path / "eval.json"
    rc = main(["eval", "--scenes", "1", "--quiet", "--json", str(out), *argv])
    assert rc == 0, capsys.readouterr().err
    return dict(json.loads(out.read_text()))


@pytest.mark.parametrize(
    ("flags", "model", "refine"),
    [((), None, True), (("--model", "default", "--no-refine"), "default", False)],
)
def test_eval_flags_override_the_realistic_scenes_defaults(
    flags: tuple[str, ...],
    model: str | None,
    refine: bool,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """`--sigma-d` changes only sigma_d of `register_point_clouds`' default for the scene's
    path (not `Config(sigma_d=...)`), scaled to the voxel; the JSON records both."""
    seen = _spy_on_register(monkeypatch, pointclm.evaluation)
    voxels = _spy_on_voxels(monkeypatch)
    argv = ("--dataset", "scenes", "--shapes", "bunny", "--sigma-d", "0.2", *flags)
    record = _eval(capsys, tmp_path, *argv)
    overrides = {"sigma_d": 0.2}
    assert seen == [cloud_config(voxels[0], model, refine, False, overrides)]
    base = cloud_base_config(model, refine)
    assert base.tau_n != Config().tau_n  # so replacing the default would show
    assert seen[0] != Config.for_voxel(voxels[0], Config(**overrides))
    assert record["config_overrides"] == overrides
    assert record["config"] == dataclasses.replace(base, sigma_d=0.2).to_dict()


def test_eval_without_flags_keeps_each_paths_default(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    seen = _spy_on_register(monkeypatch, pointclm.evaluation)
    voxels = _spy_on_voxels(monkeypatch)
    realistic = _eval(capsys, tmp_path, "--dataset", "scenes", "--shapes", "bunny")
    synthetic = _eval(capsys, tmp_path)
    assert seen == [cloud_config(voxels[0]), Config()]
    assert realistic["config_overrides"] == synthetic["config_overrides"] == {}
    assert realistic["config"] == cloud_base_config().to_dict()
    assert synthetic["config"] == Config().to_dict()


@pytest.mark.parametrize("command", ["eval", "demo"])
def test_model_flags_keep_the_networks_other_thresholds(
    command: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """With `--model`, a flag replaces one of the network's recommended thresholds; the
    others stay (not `Config()`'s). `demo`'s realistic scene gets the flags too."""
    recommended = resolve("default").recommended_config()
    assert recommended is not None and recommended.tau_n != Config().tau_n
    synthetic = _spy_on_register(monkeypatch, pointclm.cli.commands)
    realistic = _spy_on_register(monkeypatch, pointclm.evaluation)
    voxels = _spy_on_voxels(monkeypatch)
    argv = [command, "--scenes", "1", "--model", "default", "--ransac-iterations", "500"]
    assert main([*argv, "--quiet"] if command == "eval" else argv) == 0, capsys.readouterr().err
    wanted = dataclasses.replace(recommended, ransac_iterations=500)
    if command == "eval":
        assert realistic == [wanted]
    else:
        overrides = {"ransac_iterations": 500}
        assert synthetic == [wanted]
        assert realistic == [cloud_config(voxels[0], "default", True, False, overrides)]


def test_evaluate_takes_a_config_or_overrides_not_both() -> None:
    with pytest.raises(ConfigError, match="config_overrides"):
        evaluate(make_scenes(1), Config(), config_overrides={"tau_n": 3})
    with pytest.raises(ConfigError, match="tau_x"):
        evaluate(make_scenes(1), config_overrides={"tau_x": 3})


def test_evaluate_overrides_apply_over_the_default_and_are_recorded() -> None:
    given = evaluate(make_scenes(3, seed=2), Config(tau_n=3))
    overridden = evaluate(make_scenes(3, seed=2), config_overrides={"tau_n": 3})
    assert given.config == overridden.config == Config(tau_n=3)
    assert given.scores == overridden.scores
    assert evaluate(make_scenes(1)).config == Config()

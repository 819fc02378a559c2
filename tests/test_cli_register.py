"""`pointclm register`: the report and its JSON carry the result's diagnosis (an empty result
says why and what to try, in the command's flags), `--ground-truth` scores the copies found
(RE < 15 deg, TE < 10 % of the model's diagonal) and the picture draws the missed ones."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pointclm.point_clouds
import pointclm.visualize
import pytest
from pointclm.cli import main
from pointclm.datasets import load_shape
from pointclm.io import write_ply


def _pose(angles: tuple[float, float, float], t: np.ndarray) -> np.ndarray:
    a, b, c = np.radians(angles)
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rx = np.array([[1, 0, 0], [0, np.cos(c), -np.sin(c)], [0, np.sin(c), np.cos(c)]])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rz @ ry @ rx, t
    return T


@pytest.fixture
def bunnies(tmp_path: Path) -> dict[str, Any]:
    """The bundled bunny, a scene of two posed copies of it, and three true poses: the two
    copies and a third copy the scene does not hold (so it must be reported missed)."""
    model = load_shape("bunny", 3000)
    d = float(np.linalg.norm(np.ptp(model, axis=0)))
    truth = np.stack(
        [
            _pose((40, 10, 0), np.array([2 * d, 0, 0])),
            _pose((-70, 0, 30), np.array([-2 * d, 0.5 * d, 0])),
            _pose((0, 0, 0), np.array([0, 5 * d, 0])),
        ]
    )
    scene = np.vstack([model @ T[:3, :3].T + T[:3, 3] for T in truth[:2]])
    write_ply(tmp_path / "model.ply", model)
    write_ply(tmp_path / "scene.ply", scene)
    np.save(tmp_path / "truth.npy", truth)
    (tmp_path / "truth.json").write_text(json.dumps(truth.tolist()))
    return {"model": str(tmp_path / "model.ply"), "scene": str(tmp_path / "scene.ply"), "d": d}


def _register(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    rc = main(["register", *argv, "--quiet"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    return out.out


@pytest.mark.parametrize("truth_file", ["truth.npy", "truth.json"])
def test_ground_truth_is_scored_in_the_report_and_the_json(
    truth_file: str, bunnies: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out_json = tmp_path / "r.json"
    text = _register(
        capsys,
        bunnies["model"],
        bunnies["scene"],
        "--ground-truth",
        str(tmp_path / truth_file),
        "--out",
        str(out_json),
    )
    assert "ground truth: 2 of 3 true pose(s) found (RE < 15 deg, TE < " in text
    assert "10% of the model's diagonal); missed [2]" in text
    assert "match no true pose" not in text
    assert sorted(line[-1] for line in text.splitlines() if "= true pose" in line) == ["0", "1"]
    result = json.loads(out_json.read_text())
    gt = result["ground_truth"]
    assert (gt["poses"], gt["found"], gt["missed"]) == (3, [0, 1], [2])
    assert gt["max_translation"] == pytest.approx(0.1 * bunnies["d"], rel=1e-6)
    assert sorted(inst["true_pose"] for inst in result["instances"]) == [0, 1]
    assert result["diagnosis"] == ""


def test_an_earlier_result_is_ground_truth_too(
    bunnies: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    first = tmp_path / "first.json"
    _register(capsys, bunnies["model"], bunnies["scene"], "--out", str(first))
    assert "ground_truth" in json.loads(first.read_text())  # null without --ground-truth
    text = _register(capsys, bunnies["model"], bunnies["scene"], "--ground-truth", str(first))
    assert "ground truth: 2 of 2 true pose(s) found" in text
    # An empty list: the scene holds no copy, so every instance is a false one.
    (tmp_path / "none.json").write_text("[]")
    text = _register(
        capsys, bunnies["model"], bunnies["scene"], "--ground-truth", str(tmp_path / "none.json")
    )
    assert "0 of 0 true pose(s) found" in text and "2 instance(s) match no true pose" in text


def test_an_empty_result_says_why_and_what_to_try(
    bunnies: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(1)
    sphere = rng.normal(size=(3000, 3))
    sphere *= bunnies["d"] / np.linalg.norm(sphere, axis=1, keepdims=True)
    write_ply(tmp_path / "sphere.ply", sphere)
    out_json = tmp_path / "r.json"
    text = _register(
        capsys,
        bunnies["model"],
        str(tmp_path / "sphere.ply"),
        "--out",
        str(out_json),
        "--ground-truth",
        str(tmp_path / "truth.npy"),
    )
    assert text.startswith("0 instance(s)")
    assert "ground truth: 0 of 3 true pose(s) found" in text and "missed [0, 1, 2]" in text
    notes = [line for line in text.splitlines() if line.startswith("note: nothing found")]
    assert len(notes) == 1, text
    # The advice is in the command's flags, not register_point_clouds' argument names.
    assert "--viewpoint x,y,z" in notes[0] and "viewpoint=" not in notes[0]
    assert json.loads(out_json.read_text())["diagnosis"] == notes[0].removeprefix("note: ")


def test_the_png_is_the_registration_picture_with_the_ground_truth(
    bunnies: dict[str, Any],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    pytest.importorskip("matplotlib")
    drawn: dict[str, Any] = {}
    real = pointclm.visualize.save_registration_png

    def spy(path: str, reg: Any, **kwargs: Any) -> None:
        drawn.update(kwargs, reg=reg)
        real(path, reg, **kwargs)

    monkeypatch.setattr(pointclm.visualize, "save_registration_png", spy)
    png = tmp_path / "r.png"
    _register(
        capsys,
        bunnies["model"],
        bunnies["scene"],
        "--png",
        str(png),
        "--ground-truth",
        str(tmp_path / "truth.npy"),
    )
    assert png.read_bytes().startswith(b"\x89PNG")
    np.testing.assert_array_equal(drawn["ground_truth"], np.load(tmp_path / "truth.npy"))
    assert len(drawn["reg"].instances) == 2 and "model.ply in scene.ply" in drawn["title"]


def _spy_on_register(monkeypatch: pytest.MonkeyPatch, option: str) -> list[Any]:
    """The values of `option` that `register_point_clouds` receives, call by call."""
    seen: list[Any] = []
    real = pointclm.point_clouds.register_point_clouds

    def spy(*args: Any, **kwargs: Any) -> Any:
        seen.append(kwargs[option])
        return real(*args, **kwargs)

    monkeypatch.setattr(pointclm.point_clouds, "register_point_clouds", spy)
    return seen


def test_viewpoint_none_overrides_the_file(
    bunnies: dict[str, Any], capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    seen = _spy_on_register(monkeypatch, "viewpoint")
    # A PCD scene would otherwise lend its VIEWPOINT; "none" means no sensor position at all.
    monkeypatch.setattr(pointclm.point_clouds, "file_viewpoint", lambda path: np.ones(3))
    _register(capsys, bunnies["model"], bunnies["scene"], "--viewpoint", "none")
    _register(capsys, bunnies["model"], bunnies["scene"], "--viewpoint", "1,2,3")
    _register(capsys, bunnies["model"], bunnies["scene"])
    assert seen[0] is None and seen[1] == (1.0, 2.0, 3.0)
    np.testing.assert_array_equal(seen[2], np.ones(3))


def test_method_flags_are_in_synthetic_units_over_the_path_defaults(
    bunnies: dict[str, Any], capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A method flag changes only its own field of `register_point_clouds`' default config,
    and lengths are scaled to the voxel as `pointclm eval` scales them."""
    seen = _spy_on_register(monkeypatch, "config")
    voxel = bunnies["d"] / 20
    common = (bunnies["model"], bunnies["scene"], "--voxel-size", str(voxel))
    _register(capsys, *common, "--ransac-iterations", "77")
    _register(capsys, *common, "--sigma-d", "0.2")
    _register(capsys, *common)
    default = pointclm.point_clouds.cloud_config(voxel, peel=True)
    only_iterations, only_sigma, none = seen
    assert none is None
    assert only_iterations == pointclm.Config.from_dict(
        {**default.to_dict(), "ransac_iterations": 77}
    )
    assert only_sigma.sigma_d == pytest.approx(
        pointclm.Config.for_voxel(voxel, pointclm.Config(sigma_d=0.2)).sigma_d
    )
    assert only_sigma.cluster_level == default.cluster_level is not None
    assert only_sigma.tau_n == default.tau_n != pointclm.Config().tau_n


@pytest.mark.parametrize("flag, heap", [((), None), (("--heap",), True)])
def test_heap_flag_reaches_the_registration(
    flag: tuple[str, ...],
    heap: bool | None,
    bunnies: dict[str, Any],
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    seen: dict[str, Any] = {}
    register = pointclm.point_clouds.register_point_clouds

    def spy(*args: Any, **kwargs: Any) -> Any:
        seen.update(kwargs)
        return register(*args, **kwargs)

    monkeypatch.setattr(pointclm.point_clouds, "register_point_clouds", spy)
    _register(capsys, bunnies["model"], bunnies["scene"], *flag)
    assert seen["heap"] is heap

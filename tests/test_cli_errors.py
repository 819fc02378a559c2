"""The command line's error contract: one line on stderr, a non-zero exit code, never a
traceback; outputs and optional dependencies checked before the work; no partial outputs."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pointclm.io
import pointclm.point_clouds
import pointclm.visualize
import pytest
from pointclm.cli import main
from pointclm.io import write_ply

RNG = np.random.default_rng(0)


@pytest.fixture
def clouds(tmp_path: Path) -> tuple[str, str]:
    model = RNG.normal(size=(300, 3))
    scene = np.vstack([model + [3.0, 0.0, 0.0], RNG.normal(size=(100, 3)) * 4])
    write_ply(tmp_path / "model.ply", model)
    write_ply(tmp_path / "scene.ply", scene)
    return str(tmp_path / "model.ply"), str(tmp_path / "scene.ply")


def one_line_error(capsys: pytest.CaptureFixture[str], *words: str) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, f"expected one line on stderr, got:\n{err}"
    assert "Traceback" not in err
    for word in words:
        assert word in lines[0], f"{word!r} not in {lines[0]!r}"
    return lines[0]


@pytest.fixture
def no_work(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail the test if the command starts reading clouds."""

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("the command started the work before checking its outputs")

    monkeypatch.setattr(pointclm.io, "load_points", refuse)


@pytest.mark.parametrize(
    "argv, words",
    [
        (["demo", "--scenes", "0"], ["--scenes", "must be >= 1"]),
        (["demo", "--num-threads", "-2"], ["--num-threads"]),
        (["demo", "--seed", "x"], ["--seed", "integer"]),
        (["demo", "--sigma-d", "nan"], ["--sigma-d", "finite"]),
        (["register", "a.ply", "b.ply", "--viewpoint", "1,2"], ["--viewpoint", "x,y,z"]),
        (["register", "a.ply", "b.ply", "--correspondences", "0"], ["--correspondences"]),
        (["eval", "--outlier-blocks", "-1"], ["--outlier-blocks"]),
        (["train", "--out", "x", "--iterations", "0"], ["--iterations"]),
        (["nonsense"], ["invalid choice"]),
    ],
)
def test_bad_flags_are_one_line(
    argv: list[str], words: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    one_line_error(capsys, *words)


@pytest.mark.parametrize("flag", ["--out", "--png", "--ply"])
def test_register_checks_outputs_before_the_work(
    flag: str,
    clouds: tuple[str, str],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    no_work: None,
) -> None:
    model, scene = clouds
    for target, words in (
        (tmp_path / "missing" / "out.x", ["does not exist"]),
        (tmp_path, ["is a directory"]),
    ):
        assert main(["register", model, scene, flag, str(target), "--quiet"]) == 2
        one_line_error(capsys, flag, *words)


def test_png_needs_matplotlib_before_the_work(
    clouds: tuple[str, str],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    no_work: None,
) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    model, scene = clouds
    assert main(["register", model, scene, "--png", str(tmp_path / "r.png"), "--quiet"]) == 2
    one_line_error(capsys, "matplotlib")


def test_failed_output_leaves_no_partial_file(
    clouds: tuple[str, str],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    model, scene = clouds
    out = tmp_path / "result.ply"
    out.write_bytes(b"the previous result")

    def half_written(path: str, *args: object) -> None:
        Path(path).write_bytes(b"ply\nformat binary_lit")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(pointclm.visualize, "save_ply", half_written)
    assert main(["register", model, scene, "--ply", str(out), "--quiet"]) == 2
    one_line_error(capsys, "No space left")
    assert out.read_bytes() == b"the previous result"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.ply", "result.ply", "scene.ply"]


def test_register_writes_outputs(
    clouds: tuple[str, str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model, scene = clouds
    out, ply = tmp_path / "r.json", tmp_path / "r.ply"
    rc = main(["register", model, scene, "--out", str(out), "--ply", str(ply), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    assert out.read_text().startswith("{") and len(pointclm.io.read_point_cloud(ply)) > 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporaries


def test_internal_errors_are_one_line_too(
    clouds: tuple[str, str],
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def bug(*args: object, **kwargs: object) -> None:
        raise RuntimeError("something\nunexpected")

    monkeypatch.setattr(pointclm.point_clouds, "register_point_clouds", bug)
    model, scene = clouds
    assert main(["register", model, scene, "--quiet"]) == 1
    one_line_error(capsys, "internal error", "RuntimeError", "POINTCLM_DEBUG")


def test_missing_and_hostile_inputs(
    tmp_path: Path, clouds: tuple[str, str], capsys: pytest.CaptureFixture[str]
) -> None:
    model, _ = clouds
    assert main(["register", model, str(tmp_path / "nope.ply"), "--quiet"]) == 2
    one_line_error(capsys, "nope.ply")
    bomb = tmp_path / "bomb.npy"
    bomb.write_bytes(
        b"\x93NUMPY\x01\x00v\x00{'descr': '<f8', 'fortran_order': False, 'shape': (10**9, 3), }"
        + b" " * 40
        + b"\n"
    )
    assert main(["register", model, str(bomb), "--quiet"]) == 2
    one_line_error(capsys, "bomb.npy")


def test_an_unknown_network_is_refused_before_the_work_naming_the_shipped_ones(
    clouds: tuple[str, str], capsys: pytest.CaptureFixture[str], no_work: None
) -> None:
    model, scene = clouds
    assert main(["register", model, scene, "--model", "nosuch", "--quiet"]) == 2
    one_line_error(capsys, "no weights at", "nosuch", "'default', 'paper'", "--model default")


def test_a_scan_with_nan_rows_is_read_with_a_one_line_warning(
    tmp_path: Path, clouds: tuple[str, str], capsys: pytest.CaptureFixture[str]
) -> None:
    model, scene = clouds
    holes = tmp_path / "holes.xyz"
    points = pointclm.io.load_points(scene)
    points[[5, 9]] = np.nan  # two missing returns, as a scanner writes them
    holes.write_text("\n".join(" ".join(str(v) for v in p) for p in points))
    assert main(["register", model, str(holes), "--quiet"]) == 0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines == [
        f"pointclm: warning: {holes}: dropped 2 rows with NaN/inf coordinates (missing "
        f"returns), kept {len(points) - 2} points"
    ], err


def test_a_diagnosis_asking_for_the_viewpoint_says_how_to_know_it() -> None:
    from pointclm.cli import flag_names

    text = flag_names(
        "nothing found: ... The scan's normals were oriented without a sensor position: if "
        "you know it, pass viewpoint=."
    )
    assert "pass --viewpoint x,y,z (the sensor's position in the scan's coordinates: 0,0,0" in text
    assert "viewpoint=" not in text
    other = flag_names("pass its position, or viewpoint=None to orient the normals without one")
    assert other == "pass its position, or --viewpoint none to orient the normals without one"


def test_eval_and_train_check_outputs_first(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["eval", "--scenes", "1", "--json", str(tmp_path), "--quiet"]) == 2
    one_line_error(capsys, "--json", "is a directory")
    afile = tmp_path / "file"
    afile.write_text("x")
    pytest.importorskip("torch")
    assert main(["train", "--preset", "smoke", "--out", str(afile)]) == 2
    one_line_error(capsys, "--out", "not a directory")
    assert (
        main(["train", "--preset", "smoke", "--out", str(tmp_path / "r"), "--device", "tpu9"]) == 2
    )
    one_line_error(capsys, "--device")
    assert main(["train", "--preset", "nope", "--out", str(tmp_path / "r")]) == 2
    one_line_error(capsys, "unknown preset")
    bad = tmp_path / "cfg.json"
    bad.write_text('{"depth": [1]}')
    assert main(["train", "--config", str(bad), "--out", str(tmp_path / "r")]) == 2
    one_line_error(capsys, "depth")


def _write_truth(path: Path, content: object) -> None:
    if isinstance(content, str) and content == "bomb":  # a header claiming 128 GB
        header = b"{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000, 4, 4), }"
        header += b" " * (117 - len(header)) + b"\n"  # 10 + 118 bytes: aligned to 64
        path.write_bytes(b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header)
    elif path.suffix == ".npy":
        np.save(path, np.asarray(content))
    else:
        path.write_text(str(content))


@pytest.mark.parametrize(
    "name, content, words",
    [
        ("missing.npy", None, ["no such ground-truth file", "missing.npy"]),
        ("t.npy", np.zeros((2, 3, 3)), ["--ground-truth", "(G, 4, 4)", "(2, 3, 3)"]),
        ("t.npy", np.full((1, 4, 4), np.nan), ["--ground-truth", "non-finite"]),
        ("t.npy", 2 * np.eye(4)[None], ["--ground-truth", "pose 0 is not a rigid transform"]),
        (
            "t.npy",
            np.diag([1.0, 1.0, -1.0, 1.0])[None],
            ["--ground-truth", "pose 0 is not a rigid transform"],
        ),
        ("t.json", "[[1, 2], [3]]", ["--ground-truth", "could not be read as poses"]),
        ("t.json", "{not json", ["--ground-truth", "could not be read"]),
        ("t.txt", "1 0 0 0", ["--ground-truth", "expected a .npy or .json file"]),
        ("t.npy", np.array([{"a": 1}], dtype=object), ["--ground-truth", "never unpickles"]),
        ("bomb.npy", "bomb", ["--ground-truth", "the header declares shape (1000000000, 4, 4)"]),
    ],
)
def test_a_bad_ground_truth_fails_before_the_work(
    name: str,
    content: object,
    words: list[str],
    clouds: tuple[str, str],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    no_work: None,
) -> None:
    path = tmp_path / name
    if content is not None:
        _write_truth(path, content)
    model, scene = clouds
    assert main(["register", model, scene, "--ground-truth", str(path), "--quiet"]) == 2
    one_line_error(capsys, *words)

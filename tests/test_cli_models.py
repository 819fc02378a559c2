"""Several part types from the command line and in a batch: `pointclm register MODEL MODEL
SCENE` and `pointclm batch MODEL --add-model FILE SCANS`, with a symmetry and a ground truth
per model; usage errors are one line and exit code 2."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pointclm
import pytest
from pointclm.batch import without_timings
from pointclm.cli import main
from pointclm.io import write_ply
from pointclm.schemas import result_schema
from posed_copies import posed_copies
from scipy.spatial.transform import Rotation

HALF_X = [1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1]
HALF_Y = [-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1]
BOX_SYMMETRY = {"symmetries_discrete": [HALF_X, HALF_Y]}


def _box(sides: np.ndarray, n: int = 3000) -> np.ndarray:
    """`n` points on the faces of a box centred on the origin."""
    rng = np.random.default_rng(0)
    areas = np.array([sides[1] * sides[2], sides[0] * sides[2], sides[0] * sides[1]])
    axis = rng.choice(3, n, p=areas / areas.sum())
    p = (rng.random((n, 3)) - 0.5) * sides
    p[np.arange(n), axis] = np.where(rng.random(n) < 0.5, -0.5, 0.5) * sides[axis]
    return p


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Two bunnies and a box in one scan; the models, the truths and the box's symmetry."""
    tmp = tmp_path_factory.mktemp("models")
    bunny, scan, bunny_poses = posed_copies(2)
    d = float(np.linalg.norm(np.ptp(bunny, axis=0)))
    box = _box(np.array([0.3, 0.48, 0.72]) * d)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = Rotation.random(random_state=7).as_matrix(), [-2 * d, 0, 0]
    write_ply(tmp / "bunny.ply", bunny)
    write_ply(tmp / "box.ply", box)
    write_ply(tmp / "scan.ply", np.vstack([scan, box @ T[:3, :3].T + T[:3, 3]]))
    write_ply(tmp / "bunnies.ply", scan)
    np.save(tmp / "bunny_gt.npy", bunny_poses)
    # The box's truth written turned by one of its symmetries: found all the same.
    np.save(tmp / "box_gt.npy", (T @ np.array(HALF_X, dtype=float).reshape(4, 4))[None])
    (tmp / "box_sym.json").write_text(json.dumps(BOX_SYMMETRY))
    return {k: str(tmp / f"{k}{s}") for k, s in (
        ("bunny", ".ply"), ("box", ".ply"), ("scan", ".ply"), ("bunnies", ".ply"),
        ("bunny_gt", ".npy"), ("box_gt", ".npy"), ("box_sym", ".json"),
    )} | {"tmp": tmp}  # fmt: skip


def _validator() -> Any:
    jsonschema = pytest.importorskip("jsonschema")
    return jsonschema.Draft202012Validator(result_schema())


def _ok(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    rc = main([*argv, "--quiet"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    return out.out


def _usage_error(capsys: pytest.CaptureFixture[str], argv: list[str], *words: str) -> None:
    assert main([*argv, "--quiet"]) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    for word in words:
        assert word in lines[0], f"{word!r} not in {lines[0]!r}"


def test_register_several_models_reports_scores_and_writes_one_entry_per_model(
    files: dict[str, Any], capsys: pytest.CaptureFixture[str]
) -> None:
    out = files["tmp"] / "several.json"
    text = _ok(capsys, [
        "register", files["bunny"], files["box"], files["scan"],
        "--symmetry", "none", "--symmetry", files["box_sym"],
        "--ground-truth", files["bunny_gt"], "--ground-truth", files["box_gt"],
        "--out", str(out),
    ])  # fmt: skip
    lines = text.splitlines()
    assert lines[0] == "2 models in scan.ply, judged together:"
    assert "true found" in lines[1]
    assert lines[2].split()[:3] == ["bunny.ply", "2", "0"] and lines[2].endswith("2 of 2")
    assert lines[3].split()[:3] == ["box.ply", "1", "0"] and lines[3].endswith("1 of 1")
    assert f"\n{files['bunny']}:\n" in text and f"\n{files['box']}:\n" in text
    result = json.loads(out.read_text())
    assert list(_validator().iter_errors(result)) == []
    assert result["format_version"] == "1.4" and result["scene"] == files["scan"]
    bunny, box = result["models"]
    assert (bunny["model"], box["model"]) == (files["bunny"], files["box"])
    assert bunny["ground_truth"]["found"] == [0, 1] and box["ground_truth"]["found"] == [0]
    # The box's pose comes out canonical under its symmetry.
    sym = pointclm.symmetry.from_bop(BOX_SYMMETRY)
    pose = np.array(box["instances"][0]["T_target_source"])
    np.testing.assert_allclose(sym.canonical(pose), pose, atol=1e-9)


def test_register_several_models_is_register_models(
    files: dict[str, Any], capsys: pytest.CaptureFixture[str]
) -> None:
    out = files["tmp"] / "joint.json"
    _ok(capsys, ["register", files["bunny"], files["box"], files["scan"], "--symmetry", "auto",
                 "--out", str(out)])  # fmt: skip
    got = json.loads(out.read_text())["models"]
    expected = pointclm.register_models([files["bunny"], files["box"]], files["scan"],
                                        symmetry="auto")  # fmt: skip
    for entry, reg in zip(got, expected, strict=True):
        assert entry["ground_truth"] is None
        np.testing.assert_array_equal(
            np.array([i["T_target_source"] for i in entry["instances"]]).reshape(-1, 4, 4),
            reg.transformations.reshape(-1, 4, 4),
        )


def test_one_model_keeps_its_output(files: dict[str, Any], capsys) -> None:  # type: ignore[no-untyped-def]
    out = files["tmp"] / "one.json"
    text = _ok(capsys, ["register", files["bunny"], files["bunnies"], "--symmetry", "none",
                        "--out", str(out)])  # fmt: skip
    assert "judged together" not in text and text.startswith("2 instance(s)")
    record = json.loads(out.read_text())
    assert record["model"] == files["bunny"] and "models" not in record
    assert list(_validator().iter_errors(record)) == []


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--symmetry", "auto", "--symmetry", "none", "--symmetry", "auto"],
         ["3 --symmetry for 2 model(s)", "one per model"]),
        (["--ground-truth", "GT"], ["1 --ground-truth for 2 model(s)"]),
        (["--png", "x.png"], ["--png", "2 models", "--out"]),
        (["--bop-csv", "x.csv"], ["0 --obj-id for 2 model(s)", "one object id per model"]),
        (["--bop-csv", "x.csv", "--obj-id", "3"], ["1 --obj-id for 2 model(s)"]),
        (["--symmetry", "missing.json"], ["missing.json"]),
    ],
)  # fmt: skip
def test_register_usage_errors_with_several_models(
    files: dict[str, Any], capsys: pytest.CaptureFixture[str], extra: list[str], words: list[str]
) -> None:
    extra = [files["bunny_gt"] if e == "GT" else e for e in extra]
    _usage_error(capsys, ["register", files["bunny"], files["box"], files["scan"], *extra], *words)


def test_several_models_in_one_bop_csv_an_object_id_each(
    files: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from pointclm.io import read_bop_csv

    out, csv = tmp_path / "r.json", tmp_path / "r.csv"
    ids = ["--obj-id", "4", "--obj-id", "9", "--im-id", "2"]
    _ok(capsys, ["register", files["bunny"], files["box"], files["scan"], "--out", str(out),
                 "--bop-csv", str(csv), *ids])  # fmt: skip
    models = json.loads(out.read_text())["models"]
    rows = read_bop_csv(csv)
    assert [r.obj_id for r in rows] == [4] * len(models[0]["instances"]) + [9] * len(
        models[1]["instances"]
    )
    assert {r.im_id for r in rows} == {2}
    poses = [i["T_target_source"] for m in models for i in m["instances"]]
    for row, pose in zip(rows, poses, strict=True):
        np.testing.assert_allclose(row.transformation, pose, atol=1e-6)
    # And a batch's: one image per scan, each model's poses under its id.
    lines, batch_csv = tmp_path / "b.jsonl", tmp_path / "b.csv"
    _ok(capsys, ["batch", files["bunny"], files["scan"], files["bunnies"], "--add-model",
                 files["box"], "--out", str(lines), "--bop-csv", str(batch_csv),
                 "--obj-id", "4", "--obj-id", "9"])  # fmt: skip
    records = [json.loads(x) for x in lines.read_text().splitlines()]
    expected = [(im, oid, inst["T_target_source"], rec["seconds"])
                for im, rec in enumerate(records)
                for oid, res in zip((4, 9), rec["results"], strict=True)
                for inst in res["instances"]]  # fmt: skip
    rows = read_bop_csv(batch_csv)
    assert [(r.im_id, r.obj_id) for r in rows] == [(im, oid) for im, oid, _, _ in expected]
    for row, (_, _, pose, seconds) in zip(rows, expected, strict=True):
        np.testing.assert_allclose(row.transformation, pose, atol=1e-6)
        assert row.time == pytest.approx(seconds, abs=1e-6)  # the scan's whole time


def test_register_a_missing_model_file_is_one_line(files: dict[str, Any], capsys) -> None:  # type: ignore[no-untyped-def]
    missing = str(files["tmp"] / "nope.ply")
    _usage_error(capsys, ["register", files["bunny"], missing, files["scan"]], "nope.ply")
    _usage_error(capsys, ["register", files["bunny"], files["scan"], "--symmetry", "auto",
                          "--symmetry", "none"], "2 --symmetry for 1 model(s)")  # fmt: skip


def test_batch_with_several_models_writes_one_line_per_scan_with_each_models_result(
    files: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "b.jsonl"
    argv = [
        "batch",
        files["bunny"],
        files["scan"],
        files["bunnies"],
        "--add-model",
        files["box"],
        "--symmetry",
        "none",
        "--symmetry",
        files["box_sym"],
        "--out",
        str(out),
    ]
    _ok(capsys, argv)  # fmt: skip
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r["scan"] for r in lines] == [files["scan"], files["bunnies"]]
    validator = _validator()
    for line in lines:
        assert list(validator.iter_errors(line)) == []
        assert line["status"] == "ok" and line["models"] == [files["bunny"], files["box"]]
        assert [r["model"] for r in line["results"]] == line["models"]
        assert line["options"]["symmetry"][0] is None
    assert [len(r["instances"]) for r in lines[0]["results"]] == [2, 1]
    assert [len(r["instances"]) for r in lines[1]["results"]] == [2, 0]
    # Each line is register_models on that scan, the symmetry per model.
    joint = pointclm.register_models([files["bunny"], files["box"]], files["scan"],
                                     symmetry=[None, BOX_SYMMETRY])  # fmt: skip
    for entry, reg in zip(lines[0]["results"], joint, strict=True):
        poses = np.array([i["T_target_source"] for i in entry["instances"]]).reshape(-1, 4, 4)
        np.testing.assert_array_equal(poses, reg.transformations.reshape(-1, 4, 4))
    # Resumed with the same models: nothing runs again; with other symmetries: refused.
    _ok(capsys, [*argv, "--resume"])
    assert [without_timings(json.loads(x)) for x in out.read_text().splitlines()] == [
        without_timings(x) for x in lines
    ]
    _usage_error(capsys, [*argv[:-6], "--symmetry", "auto", "--out", str(out), "--resume"],
                 "different options")  # fmt: skip


def test_batch_symmetry_with_one_model_is_recorded_and_canonical(
    files: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "one.jsonl"
    _ok(capsys, ["batch", files["box"], files["scan"], "--symmetry", files["box_sym"],
                 "--out", str(out)])  # fmt: skip
    (line,) = [json.loads(x) for x in out.read_text().splitlines()]
    assert list(_validator().iter_errors(line)) == []
    assert line["model"] == files["box"] and "models" not in line
    assert line["options"]["symmetry"] == pointclm.symmetry.from_bop(BOX_SYMMETRY).to_bop()
    sym = pointclm.symmetry.from_bop(BOX_SYMMETRY)
    pose = np.array(line["instances"][0]["T_target_source"])
    np.testing.assert_allclose(sym.canonical(pose), pose, atol=1e-9)
    # Without a symmetry a line records none (as lines written before the option existed).
    plain = tmp_path / "plain.jsonl"
    _ok(capsys, ["batch", files["box"], files["scan"], "--out", str(plain)])
    assert "symmetry" not in json.loads(plain.read_text())["options"]


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--symmetry", "auto", "--symmetry", "none", "--symmetry", "auto"],
         ["3 --symmetry for 2 model(s)"]),
        (["--png-dir", "pics"], ["--png-dir", "2 models"]),
        (["--bop-csv", "x.csv"], ["0 --obj-id for 2 model(s)"]),
    ],
)  # fmt: skip
def test_batch_usage_errors_with_several_models(
    files: dict[str, Any],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    extra: list[str],
    words: list[str],
) -> None:
    out = tmp_path / "bad.jsonl"
    argv = ["batch", files["bunny"], files["scan"], "--add-model", files["box"],
            "--out", str(out), *extra]  # fmt: skip
    _usage_error(capsys, argv, *words)
    assert not out.exists() or out.stat().st_size == 0


def test_batch_a_missing_added_model_stops_before_any_scan(
    files: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "missing.jsonl"
    argv = ["batch", files["bunny"], files["scan"], "--add-model", str(tmp_path / "nope.ply"),
            "--out", str(out)]  # fmt: skip
    _usage_error(capsys, argv, "nope.ply")
    assert not out.exists() or out.stat().st_size == 0


def test_register_files_takes_several_models_and_checks_the_symmetries(
    files: dict[str, Any], tmp_path: Path
) -> None:
    from pointclm.batch import register_files

    out = tmp_path / "api.jsonl"
    summary = register_files([files["bunny"], files["box"]], [files["scan"]], out,
                             progress=False, symmetry=[None, "auto"])  # fmt: skip
    assert summary.done == 1
    (line,) = [json.loads(x) for x in out.read_text().splitlines()]
    assert line["options"]["symmetry"] == [None, "auto"]
    with pytest.raises(ValueError, match="3 symmetries for 2 model"):
        register_files([files["bunny"], files["box"]], [files["scan"]], tmp_path / "x.jsonl",
                       progress=False, symmetry=[None, None, None])  # fmt: skip
    with pytest.raises(ValueError, match="no model"):
        register_files([], [files["scan"]], tmp_path / "y.jsonl", progress=False)

"""The JSON `register --out` and `batch` write follows the schema shipped in the package, and
carries its format version."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
from pointclm.batch.records import FORMAT_VERSION
from pointclm.cli import main
from pointclm.io import write_ply
from pointclm.schemas import result_schema
from posed_copies import posed_copies

jsonschema = pytest.importorskip("jsonschema")


@pytest.fixture(scope="module")
def outputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[dict]]:
    """Real outputs: `register` with and without ground truth, and a batch of a good scan,
    a line of points (no copy to find) and an unreadable one, with its clouds written."""
    tmp = tmp_path_factory.mktemp("outputs")
    model, scan, poses = posed_copies(2)
    write_ply(tmp / "model.ply", model)
    write_ply(tmp / "scan.ply", scan)
    (tmp / "flat.xyz").write_text("".join(f"{i} 0 0\n" for i in range(50)))
    (tmp / "bad.xyz").write_text("1 2\n")
    np.save(tmp / "truth.npy", poses)
    files = [str(tmp / "model.ply"), str(tmp / "scan.ply")]
    records = []
    for extra in ([], ["--ground-truth", str(tmp / "truth.npy")]):
        out = tmp / f"r{len(extra)}.json"
        assert main(["register", *files, "--quiet", "--out", str(out), *extra]) == 0
        records.append(json.loads(out.read_text()))
    scans = [files[1], str(tmp / "flat.xyz"), str(tmp / "bad.xyz")]
    out = tmp / "batch.jsonl"
    argv = ["batch", files[0], *scans, "--out", str(out), "--quiet", "--ply-dir", str(tmp / "ply")]
    assert main(argv) == 0
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    # Several models (the same one twice: judged together, the second finds nothing new).
    several = tmp / "several.json"
    argv = ["register", files[0], files[0], files[1], "--quiet", "--out", str(several)]
    truth = ["--ground-truth", str(tmp / "truth.npy")]
    assert main([*argv, *truth, *truth]) == 0
    out = tmp / "several.jsonl"
    argv = ["batch", files[0], *scans, "--add-model", files[0], "--out", str(out), "--quiet"]
    assert main(argv) == 0
    return {
        "register": records,
        "batch": lines,
        "register_models": [json.loads(several.read_text())],
        "batch_models": [json.loads(line) for line in out.read_text().splitlines()],
    }


@pytest.fixture(scope="module")
def schema() -> dict:
    s = result_schema()
    jsonschema.Draft202012Validator.check_schema(s)
    return s


def _errors(schema: dict, record: dict, part: str) -> list[str]:
    """The messages of `record` against the whole schema and against its `part`, which says
    where a failure is (the whole one's oneOf only says that no branch fits)."""
    whole = jsonschema.Draft202012Validator(schema)
    only = {k: v for k, v in schema.items() if k != "oneOf"}
    branch = jsonschema.Draft202012Validator({**only, "$ref": f"#/$defs/{part}"})
    messages = [e.message for e in branch.iter_errors(record)]
    return messages or [e.message for e in whole.iter_errors(record)]


def test_register_and_batch_outputs_follow_the_schema(schema, outputs) -> None:
    register, batch = outputs["register"], outputs["batch"]
    assert register[1]["ground_truth"] is not None and register[0]["instances"]
    assert batch[0]["status"] == "ok" and batch[-1]["status"] == "error"
    assert "ply" in batch[0]
    for record in register:
        assert record["format_version"] == FORMAT_VERSION
        assert _errors(schema, record, "register_output") == []
    for line in batch:
        assert line["format_version"] == FORMAT_VERSION
        assert _errors(schema, line, "batch_line") == []


def test_several_model_outputs_follow_the_schema(schema, outputs) -> None:
    (register,) = outputs["register_models"]
    assert register["format_version"] == FORMAT_VERSION
    assert [m["model"] for m in register["models"]] == [register["models"][0]["model"]] * 2
    assert register["models"][0]["ground_truth"]["found"] == [0, 1]
    assert _errors(schema, register, "register_models_output") == []
    batch = outputs["batch_models"]
    assert [line["status"] for line in batch] == [line["status"] for line in outputs["batch"]]
    assert batch[0]["status"] == "ok" and batch[-1]["status"] == "error"
    for line in batch:
        assert line["format_version"] == FORMAT_VERSION and len(line["models"]) == 2
        assert _errors(schema, line, "batch_models_line") == []


@pytest.mark.parametrize(
    ("path", "value"),
    [
        (["models"], []),  # several models means at least two
        (["models", 0, "surprise"], 1),
        (["models", 1, "instances"], None),
        (["models", 0, "model"], 3),
        (["format_version"], "1.2"),
    ],
)
def test_the_schema_refuses_a_several_model_output_it_does_not_describe(
    schema, outputs, path, value
) -> None:
    record = copy.deepcopy(outputs["register_models"][0])
    target = record
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    assert _errors(schema, record, "register_models_output")
    ok = copy.deepcopy(outputs["batch_models"][0])
    del ok["results"]
    assert _errors(schema, ok, "batch_models_line")


def test_each_instance_carries_a_finite_symmetric_covariance(outputs) -> None:
    for inst in outputs["register"][0]["instances"]:
        cov = np.array(inst["covariance"])
        assert cov.shape == (6, 6) and np.isfinite(cov).all()
        np.testing.assert_allclose(cov, cov.T, atol=1e-12 * np.abs(cov).max())
        assert 0 <= inst["unobservable"] <= 6


def test_the_schema_names_the_current_format_version(schema) -> None:
    assert schema["$defs"]["format_version"]["const"] == FORMAT_VERSION


@pytest.mark.parametrize(
    ("path", "value"),
    [
        (["surprise"], 1),  # a field the schema does not document
        (["instances", 0, "fitness"], "high"),
        (["instances", 0, "T_target_source"], [[1, 0, 0], [0, 1, 0], [0, 0, 1]]),
        (["instances", 0, "extra"], 0),
        (["format_version"], "0.1"),
        (["viewpoint"], [0, 0]),
    ],
)
def test_the_schema_refuses_what_it_does_not_describe(schema, outputs, path, value) -> None:
    record = copy.deepcopy(outputs["register"][0])
    target = record
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    assert _errors(schema, record, "register_output")


def test_a_batch_line_needs_its_status_fields(schema, outputs) -> None:
    error = copy.deepcopy(outputs["batch"][-1])
    assert _errors(schema, error, "batch_line") == []
    del error["message"]
    assert _errors(schema, error, "batch_line")
    ok = copy.deepcopy(outputs["batch"][0])
    del ok["instances"]
    assert _errors(schema, ok, "batch_line")


def test_the_schema_ships_in_the_package() -> None:
    import pointclm.schemas

    folder = Path(pointclm.schemas.__file__).parent
    assert (folder / pointclm.schemas.RESULT_SCHEMA).is_file()

"""`pointclm batch --bop-csv`: one BOP CSV for the whole batch, its poses those of the JSON
lines to 1e-6, a scan per image (its index, or the number its file is named by)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pointclm.batch import expand_scans
from pointclm.batch.bop import write_batch_bop_csv
from pointclm.cli import main
from pointclm.datasets import load_shape
from pointclm.errors import InputError
from pointclm.io import read_bop_csv, write_ply

SEED = 3


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A 400-point bunny, three scans of two posed copies named by BOP image numbers (in
    that order: 7, 3, 12) and one file that is not a point cloud."""
    root = tmp_path_factory.mktemp("bop")
    model = load_shape("bunny", 400)
    d = float(np.linalg.norm(np.ptp(model, axis=0)))
    write_ply(root / "model.ply", model)
    (root / "scans").mkdir()
    rng = np.random.default_rng(5)
    scans = []
    for i, number in enumerate((7, 3, 12)):
        parts = []
        for j in range(2):
            q, r = np.linalg.qr(rng.normal(size=(3, 3)))
            q *= np.sign(np.diag(r))
            q *= np.linalg.det(q)
            parts.append(model @ q.T + [(2 * j - 1) * d, 0.3 * i * d, 1.0])
        scans.append(root / "scans" / f"{number:06d}.ply")
        write_ply(scans[-1], np.vstack(parts))
    bad = root / "scans" / "000020.ply"
    bad.write_text("not a point cloud\n")
    return {"root": root, "model": str(root / "model.ply"), "scans": [*map(str, scans), str(bad)]}


def _batch(data: dict[str, Any], out: Path, scans: list[str], *extra: str) -> int:
    argv = ["batch", data["model"], *scans, "--out", str(out), "--seed", str(SEED), "--quiet"]
    return main([*argv, *extra])


def _records(out: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in out.read_text().splitlines()]


def test_the_batch_csv_holds_every_pose_of_the_json_lines(
    data: dict[str, Any], tmp_path: Path
) -> None:
    out, csv = tmp_path / "r.jsonl", tmp_path / "r.csv"
    flags = ["--bop-csv", str(csv), "--scene-id", "48", "--obj-id", "5"]
    assert _batch(data, out, data["scans"], *flags) == 0
    records = _records(out)
    assert [r["status"] for r in records] == ["ok", "ok", "ok", "error"]
    rows = read_bop_csv(csv)
    expected = [(i, inst, r) for i, r in enumerate(records) for inst in r.get("instances", [])]
    assert len(rows) == len(expected) >= 5
    for row, (index, inst, record) in zip(rows, expected, strict=True):
        assert (row.scene_id, row.im_id, row.obj_id) == (48, index, 5)
        np.testing.assert_allclose(row.transformation, inst["T_target_source"], atol=1e-6)
        assert row.score == pytest.approx(inst["confidence"], abs=1e-6)
        assert row.time == pytest.approx(record["timings_s"]["total"], abs=1e-6)
    # Millimetres in the file: the metres of the JSON times 1000.
    raw = read_bop_csv(csv, unit_to_mm=1)
    t = np.asarray(expected[0][1]["T_target_source"])[:3, 3]
    np.testing.assert_allclose(raw[0].translation, 1000 * t, atol=1e-6)


def test_image_ids_from_the_file_names_and_a_resumed_batch(
    data: dict[str, Any], tmp_path: Path
) -> None:
    out, csv = tmp_path / "r.jsonl", tmp_path / "r.csv"
    flags = ["--bop-csv", str(csv), "--im-id-from", "stem"]
    assert _batch(data, out, data["scans"][:2], *flags) == 0
    assert {row.im_id for row in read_bop_csv(csv)} == {7, 3}
    # Resumed with the third scan: the CSV is the whole batch's, the first two not run again.
    assert _batch(data, out, data["scans"][:3], *flags, "--resume") == 0
    assert [row.im_id for row in read_bop_csv(csv)] == [7, 7, 3, 3, 12, 12]


def test_bad_bop_arguments_are_clear_errors(data: dict[str, Any], tmp_path: Path, capsys) -> None:
    out = tmp_path / "r.jsonl"
    missing = tmp_path / "no" / "r.csv"
    assert _batch(data, out, data["scans"][:1], "--bop-csv", str(missing)) != 0
    assert "--bop-csv" in capsys.readouterr().err
    assert not out.exists()  # refused before any scan
    named = tmp_path / "scene.ply"
    named.write_bytes(Path(data["scans"][0]).read_bytes())
    assert _batch(data, out, [str(named)]) == 0
    with pytest.raises(InputError, match="not named by a number"):
        write_batch_bop_csv(out, [str(named)], tmp_path / "r.csv", im_id_from="stem")
    with pytest.raises(InputError, match="im_id_from must be one of index, stem"):
        write_batch_bop_csv(out, [str(named)], tmp_path / "r.csv", im_id_from="name")
    twice = [*expand_scans([data["scans"][0]]), str(tmp_path / "other" / "000007.ply")]
    with pytest.raises(InputError, match="are both image 7"):
        write_batch_bop_csv(out, twice, tmp_path / "r.csv", im_id_from="stem")

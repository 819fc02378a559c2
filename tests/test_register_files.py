"""`pointclm.register_files` and `pointclm batch`: one JSON line per scan, in the scans' order,
resumable after a kill, the same bit for bit in this process, in a process pool and on Ray,
and a bad scan (or a dead worker) recorded without stopping the batch."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter, deque
from concurrent.futures import Future
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

import numpy as np
import pointclm
import pytest
from pointclm.batch import expand_scans, register_files, without_timings
from pointclm.batch.local import MAX_ATTEMPTS, _drain
from pointclm.batch.options import BatchJob
from pointclm.batch.scans import picture_names
from pointclm.batch.worker import CRASH_ENV
from pointclm.cli import main
from pointclm.datasets import load_shape
from pointclm.errors import InputError
from pointclm.io import load_points, write_ply
from pointclm.metrics import pose_match_matrix

SEED = 3
#: The scan a test makes a worker process die on, the first time it is started.
CRASH_SCAN = "s2.ply"


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q * np.linalg.det(q)  # det -1 flips to +1: a rotation


def _write_pcd(path: Path, points: np.ndarray, viewpoint: np.ndarray) -> None:
    n = len(points)
    head = (
        "VERSION .7\nFIELDS x y z\nSIZE 8 8 8\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT {' '.join(map(repr, viewpoint.tolist()))} 1 0 0 0\n"
        f"POINTS {n}\nDATA ascii\n"
    )
    path.write_text(head + "\n".join(" ".join(map(repr, p)) for p in points.tolist()) + "\n")


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The bundled bunny and a folder of scans of two posed copies each (four PLY, one PCD
    with a sensor VIEWPOINT), one file that is not a point cloud, and their true poses."""
    root = tmp_path_factory.mktemp("batch")
    model = load_shape("bunny", 1500)
    d = float(np.linalg.norm(np.ptp(model, axis=0)))
    write_ply(root / "model.ply", model)
    (root / "scans").mkdir()
    rng = np.random.default_rng(7)
    truth = {}
    for i in range(5):
        poses = np.tile(np.eye(4), (2, 1, 1))
        for j, pose in enumerate(poses):
            pose[:3, :3], pose[:3, 3] = _rotation(rng), [(2 * j - 1) * d, 0.3 * i * d, 0]
        scan = np.vstack([model @ T[:3, :3].T + T[:3, 3] for T in poses])
        path = root / "scans" / (f"s{i}.ply" if i < 4 else "s4.pcd")
        if i < 4:
            write_ply(path, scan)
        else:
            _write_pcd(path, scan, np.array([0.0, -3 * d, 2 * d]))
        truth[str(path)] = poses
    (root / "scans" / "s5.ply").write_text("not a point cloud\n")
    return {"root": root, "model": str(root / "model.ply"), "d": d, "truth": truth}


def _lines(path: Path | str) -> list[dict[str, Any]]:
    return [without_timings(json.loads(line)) for line in Path(path).read_text().splitlines()]


def _run(data: dict[str, Any], out: Path, **kw: Any) -> pointclm.batch.BatchSummary:
    kw.setdefault("seed", SEED)
    return register_files(data["model"], data["root"] / "scans", out, progress=False, **kw)


@pytest.fixture(scope="module")
def reference(data: dict[str, Any]) -> list[dict[str, Any]]:
    """The lines of an uninterrupted run in this process."""
    out = data["root"] / "reference.jsonl"
    summary = _run(data, out)
    assert (summary.done, summary.failed, summary.skipped) == (5, 1, 0)
    return _lines(out)


def test_one_line_per_scan_in_order_with_the_copies_found(
    data: dict[str, Any], reference: list[dict[str, Any]]
) -> None:
    scans = [str(data["root"] / "scans" / n) for n in ("s0.ply", "s1.ply", "s2.ply", "s3.ply")]
    scans += [str(data["root"] / "scans" / n) for n in ("s4.pcd", "s5.ply")]
    assert [r["scan"] for r in reference] == scans
    for record in reference[:5]:
        assert record["status"] == "ok"
        assert record["model"] == data["model"] and record["network"] is None
        poses = np.array([inst["T_target_source"] for inst in record["instances"]])
        match = pose_match_matrix(poses, data["truth"][record["scan"]], 5.0, 0.02 * data["d"])
        assert poses.shape == (2, 4, 4) and match.any(0).all() and match.any(1).all()
        assert all(0 < inst["fitness"] <= 1 for inst in record["instances"])
        for inst in record["instances"]:
            # The sensor's scores: null where no viewpoint judged the poses (JSON has no NaN).
            seen = inst["visible_fitness"]
            assert seen is None or 0.0 <= seen <= 1.0
            assert inst["voted"] is False  # not a heap: every pose from correspondences
            assert (inst["contradiction"] is None) == (seen is None)
            rmse = inst["visible_rmse"]
            assert rmse is None or 0.0 <= rmse < 0.05 * data["d"]
            # Scores from a sensor need the viewpoint they were judged from, which is recorded.
            assert seen is None or record["viewpoint"] is not None
        assert record["viewpoint"] is None or len(record["viewpoint"]) == 3
        assert record["scan_normals"]
    assert [r["diagnosis"] for r in reference[:4]] == [""] * 4
    # The PCD's VIEWPOINT is the sensor's: verification judged the poses from it.
    np.testing.assert_allclose(reference[4]["viewpoint"], [0.0, -6.263, 4.175], atol=2e-3)
    bad = reference[5]
    assert bad["status"] == "error" and bad["error"] == "ValueError"
    assert "s5.ply" in bad["message"] and "instances" not in bad


def test_a_line_is_register_point_clouds_on_that_file(
    data: dict[str, Any], reference: list[dict[str, Any]]
) -> None:
    model = load_points(data["model"])
    for record in (reference[0], reference[4]):  # a PLY, and a PCD whose VIEWPOINT is used
        reg = pointclm.register_point_clouds(model, record["scan"], seed=SEED)
        assert np.array_equal(
            reg.transformations, [i["T_target_source"] for i in record["instances"]]
        )
    assert "VIEWPOINT" in reg.orientation
    # viewpoint="none": the PCD's sensor position is not used.
    out = data["root"] / "none.jsonl"
    register_files(
        data["model"], reference[4]["scan"], out, seed=SEED, viewpoint="none", progress=False
    )
    reg = pointclm.register_point_clouds(model, load_points(reference[4]["scan"]), seed=SEED)
    assert "VIEWPOINT" not in reg.orientation
    [line] = _lines(out)
    assert np.array_equal(reg.transformations, [i["T_target_source"] for i in line["instances"]])


def test_register_out_and_a_batch_line_agree(
    data: dict[str, Any], reference: list[dict[str, Any]], tmp_path: Path, capsys: Any
) -> None:
    out = tmp_path / "one.json"
    scan = reference[0]["scan"]
    assert main(["register", data["model"], scan, "--out", str(out), "--seed", str(SEED)]) == 0
    single = json.loads(out.read_text())
    for key in ("voxel_size", "config", "instances", "diagnosis"):
        assert single[key] == reference[0][key], key


def test_a_process_pool_agrees_bit_for_bit_and_outlives_a_dead_worker(
    data: dict[str, Any], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The learned network too: each worker loads it itself.
    alone = _run(data, tmp_path / "one.jsonl", model="default")
    monkeypatch.setenv(CRASH_ENV, f"{CRASH_SCAN}:{tmp_path / 'crashed'}")
    pooled = _run(data, tmp_path / "pool.jsonl", model="default", workers=2)
    assert (tmp_path / "crashed").exists(), "no worker was killed"
    assert (pooled.done, pooled.failed) == (alone.done, alone.failed) == (5, 1)
    lines = _lines(tmp_path / "pool.jsonl")
    assert lines == _lines(tmp_path / "one.jsonl")
    assert lines[0]["network"] == "default" and len(lines[0]["instances"]) == 2


class _DyingPool:
    """A process pool whose worker dies during its `runs`-th scan: that scan fails with
    BrokenProcessPool and later submits raise it, as Python's pool does once broken."""

    def __init__(self, runs: int) -> None:
        self.runs = runs

    def submit(self, fn: Any, scan: str, picture: str, position: int) -> Future[dict[str, Any]]:
        if self.runs == 0:
            raise BrokenProcessPool("a child process terminated abruptly")
        self.runs -= 1
        future: Future[dict[str, Any]] = Future()
        if self.runs > 0:
            future.set_result({"scan": scan})
        else:
            future.set_exception(BrokenProcessPool("a child process terminated abruptly"))
        return future


def test_a_pool_that_breaks_between_waits_gives_back_its_scans() -> None:
    tasks = deque((i, f"s{i}.ply", f"s{i}") for i in range(6))
    attempts: Counter[int] = Counter()
    job = BatchJob("model.ply")
    got = list(_drain(_DyingPool(3), tasks, 4, attempts, job))  # type: ignore[arg-type]
    # s0 and s1 finished; s2 was in flight when the worker died; s3 was never submitted.
    assert sorted(p for p, _ in got) == [0, 1]
    assert [t[0] for t in tasks] == [2, 3, 4, 5] and attempts == {2: 1}
    attempts[2] = MAX_ATTEMPTS - 1
    tasks = deque([(2, "s2.ply", "s2")])
    [(position, record)] = list(_drain(_DyingPool(1), tasks, 4, attempts, job))  # type: ignore[arg-type]
    assert position == 2 and record["error"] == "WorkerCrashedError" and not tasks


def test_ray_agrees_bit_for_bit_and_retries_a_dead_worker(
    data: dict[str, Any],
    reference: list[dict[str, Any]],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    pytest.importorskip("ray")
    monkeypatch.setenv(CRASH_ENV, f"{CRASH_SCAN}:{tmp_path / 'crashed'}")
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")  # a throwaway local cluster
    summary = _run(data, tmp_path / "ray.jsonl", engine="ray", workers=2)
    assert (tmp_path / "crashed").exists(), "no worker was killed"
    assert (summary.done, summary.failed) == (5, 1)
    assert _lines(tmp_path / "ray.jsonl") == reference


def test_resume_after_a_torn_last_line_writes_the_uninterrupted_file(
    data: dict[str, Any], reference: list[dict[str, Any]], tmp_path: Path
) -> None:
    full = (data["root"] / "reference.jsonl").read_text().splitlines(keepends=True)
    out = tmp_path / "r.jsonl"
    out.write_text("".join(full[:2]) + full[2][: len(full[2]) // 2])  # killed mid-write
    summary = _run(data, out, resume=True)
    assert (summary.done, summary.failed, summary.skipped) == (3, 1, 2)
    assert _lines(out) == reference
    summary = _run(data, out, resume=True)  # nothing left to do
    assert (summary.done, summary.failed, summary.skipped) == (0, 0, 6)
    assert _lines(out) == reference


def test_resume_with_every_kind_of_option(data: dict[str, Any], tmp_path: Path) -> None:
    out, scans = tmp_path / "o.jsonl", data["root"] / "scans" / "s[01].ply"
    kw = {"config": pointclm.Config(ransac_iterations=50), "viewpoint": (0, 0, 5.0)}
    register_files(data["model"], scans, out, voxel_size=0.05, progress=False, **kw)
    summary = register_files(data["model"], scans, out, voxel_size=0.05, resume=True, **kw)
    assert (summary.done, summary.skipped) == (0, 2)
    assert _lines(out)[0]["options"]["viewpoint"] == [0, 0, 5.0]
    with pytest.raises(InputError, match="different options"):
        register_files(data["model"], scans, out, voxel_size=0.06, resume=True, **kw)


def test_a_killed_command_resumes_to_the_same_file(
    data: dict[str, Any], reference: list[dict[str, Any]], tmp_path: Path
) -> None:
    out = tmp_path / "killed.jsonl"
    argv = [sys.executable, "-m", "pointclm", "batch", data["model"], str(data["root"] / "scans")]
    argv += ["--out", str(out), "--seed", str(SEED), "--quiet"]
    # The pointclm these tests import (a source tree with its built extension, or the
    # installed package), not necessarily the checkout's python/ folder.
    env = {**os.environ, "PYTHONPATH": str(Path(pointclm.__file__).resolve().parents[1])}
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline:
        if out.exists() and out.read_text().count("\n") >= 1:
            proc.send_signal(signal.SIGKILL)
            break
        time.sleep(0.005)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL, "the batch ended before it could be killed"
    assert 1 <= len(out.read_text().splitlines()) < len(reference)
    argv = ["batch", data["model"], str(data["root"] / "scans"), "--out", str(out), "--quiet"]
    assert main([*argv, "--seed", str(SEED)]) == 2  # no --resume
    assert main([*argv, "--resume"]) == 2  # another seed
    assert main([*argv, "--seed", str(SEED), "--resume"]) == 0
    # The command's diagnosis names its flags.
    flags = [
        {**r, "diagnosis": r["diagnosis"].replace('viewpoint="none"', "--viewpoint none")}
        if "diagnosis" in r
        else r
        for r in reference
    ]
    assert _lines(out) == flags


def test_the_command_reports_counts_and_writes_pictures(
    data: dict[str, Any], reference: list[dict[str, Any]], tmp_path: Path, capsys: Any
) -> None:
    pytest.importorskip("matplotlib")
    out, png, ply = tmp_path / "c.jsonl", tmp_path / "png", tmp_path / "ply"
    scans = [reference[0]["scan"], reference[5]["scan"], reference[1]["scan"]]
    argv = ["batch", data["model"], *scans, "--out", str(out), "--seed", str(SEED), "--quiet"]
    assert main([*argv, "--png-dir", str(png), "--ply-dir", str(ply)]) == 0
    text = capsys.readouterr().out
    assert "2 registered, 1 failed, 0 skipped" in text and "scans/s" in text
    lines = _lines(out)
    assert [without_timings(r) for r in lines] == [
        {**reference[0], "png": str(png / "s0.png"), "ply": str(ply / "s0.ply")},
        reference[5],
        {**reference[1], "png": str(png / "s1.png"), "ply": str(ply / "s1.ply")},
    ]
    assert sorted(p.name for p in png.iterdir()) == ["s0.png", "s1.png"]
    assert len(load_points(ply / "s1.ply")) > 1000


def test_scans_are_files_folders_and_globs_without_repeats(data: dict[str, Any]) -> None:
    scans = data["root"] / "scans"
    by_folder = expand_scans(scans)
    assert [Path(s).name for s in by_folder] == [f"s{i}.ply" for i in range(4)] + [
        "s4.pcd",
        "s5.ply",
    ]
    spelled_twice = [str(scans / "s3.ply"), str(scans / "s*.ply"), f"{scans}/../scans/s0.ply"]
    assert [Path(s).name for s in expand_scans(spelled_twice)] == [
        "s3.ply",
        "s0.ply",
        "s1.ply",
        "s2.ply",
        "s5.ply",
    ]
    assert expand_scans(str(data["root"] / "**" / "*.pcd")) == [str(scans / "s4.pcd")]
    with pytest.raises(InputError, match="matches no file"):
        expand_scans(str(scans / "*.off"))
    (data["root"] / "empty").mkdir()
    (data["root"] / "empty" / "notes.md").write_text("no scans here")
    with pytest.raises(InputError, match="holds no point-cloud file"):
        expand_scans(data["root"] / "empty")
    with pytest.raises(InputError, match="no scan given"):
        expand_scans([])
    assert picture_names(["a/x.ply", "b/y.pcd"]) == ["x", "y"]
    assert picture_names(["a/x.ply", "b/x.ply"]) == ["a__x", "b__x"]
    assert picture_names(["a/x.ply", "a/x.pcd"]) == ["x.ply", "x.pcd"]


def test_bad_arguments_fail_before_any_scan(data: dict[str, Any], tmp_path: Path) -> None:
    out = tmp_path / "never.jsonl"
    bad: list[tuple[dict[str, Any], str]] = [
        ({"voxel": 1.0}, "unknown option"),
        ({"workers": 0}, "workers must be"),
        ({"engine": "spark"}, "engine must be one of"),
        ({"ray_address": "auto"}, "needs engine='ray'"),
        ({"num_threads": 0}, "num_threads"),
        ({"config": {"tau_x": 1}}, "tau_x"),
        ({"model": "no-such-network.safetensors"}, "no-such-network"),
    ]
    for kw, message in bad:
        with pytest.raises(ValueError, match=message):
            _run(data, out, **kw)
    with pytest.raises(ValueError, match="not a PLY"):
        register_files(data["root"] / "scans" / "s5.ply", data["root"] / "scans", out)
    assert not out.exists()


def test_failed_checks_leave_no_picture_or_cloud_folder(
    data: dict[str, Any], reference: list[dict[str, Any]], tmp_path: Path, capsys: Any
) -> None:
    pytest.importorskip("matplotlib")
    png, ply = tmp_path / "pictures" / "png", tmp_path / "clouds"
    folders = ["--png-dir", str(png), "--ply-dir", str(ply), "--quiet"]
    taken = tmp_path / "taken.jsonl"
    taken.write_text(json.dumps(reference[0]) + "\n")
    scan = reference[1]["scan"]
    for argv, message in [
        (["batch", data["model"], scan, "--out", str(taken)], "pass --resume"),
        (
            ["batch", str(tmp_path / "no-model.ply"), scan, "--out", str(tmp_path / "a.jsonl")],
            "no-model",
        ),
        (
            ["batch", data["model"], str(tmp_path / "*.pcd"), "--out", str(tmp_path / "b.jsonl")],
            "matches no file",
        ),
    ]:
        assert main([*argv, *folders]) == 2
        assert message in capsys.readouterr().err
        assert not png.exists() and not png.parent.exists() and not ply.exists()
    # A folder that cannot be made is refused before the work, naming it.
    (tmp_path / "file").write_text("not a folder")
    bad = ["--ply-dir", str(tmp_path / "file" / "clouds")]
    assert main(["batch", data["model"], scan, "--out", str(tmp_path / "c.jsonl"), *bad]) == 2
    assert "file is not a folder" in capsys.readouterr().err
    assert not (tmp_path / "c.jsonl").exists()
    # Once the checks pass, the folders are made, parents included.
    out = tmp_path / "d.jsonl"
    assert (
        main(["batch", data["model"], scan, "--out", str(out), "--seed", str(SEED), *folders]) == 0
    )
    assert png.is_dir() and ply.is_dir()


def test_an_existing_output_needs_resume_and_the_same_model(
    data: dict[str, Any], reference: list[dict[str, Any]], tmp_path: Path, capsys: Any
) -> None:
    out = tmp_path / "o.jsonl"
    out.write_text(json.dumps({**reference[0], "model": "other.ply"}) + "\n")
    argv = ["batch", data["model"], reference[1]["scan"], "--out", str(out), "--quiet"]
    assert main(argv) == 2
    assert "pass --resume" in capsys.readouterr().err
    assert main([*argv, "--resume"]) == 2
    assert "other.ply" in capsys.readouterr().err
    out.write_text("{not json\n" + json.dumps(reference[0]) + "\n")
    assert main([*argv, "--resume"]) == 2
    assert "line 1" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:
        main(["batch", data["model"], reference[1]["scan"], "--out", str(out), "--workers", "0"])
    assert exit_.value.code == 2 and "--workers" in capsys.readouterr().err

"""`pointclm batch` under faults with Ray as the executor (skipped without ray), and an
output made read-only while a batch runs (local pool and Ray): a short version of
benchmarks/batch/faults_ray.py. Each ends with a clear message and exit code; the output
holds whole lines of the uninterrupted run, in order, with at most one line cut short;
``--resume`` completes it to the uninterrupted run's lines."""

from __future__ import annotations

import ctypes
import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pointclm
import pytest
from pointclm.batch import without_timings
from pointclm.datasets import load_shape
from pointclm.io import write_ply

pytestmark = pytest.mark.skipif(
    not Path("/proc/self/stat").exists(), reason="needs Linux's /proc to find Ray's processes"
)

SEED = 3
N_SCANS = 16
ENV = {
    **os.environ,
    "PYTHONPATH": str(Path(pointclm.__file__).resolve().parents[1]),
    "RAY_AUTH_MODE": "disabled",  # throwaway local clusters
}
RAY = ["--engine", "ray", "--workers", "2"]
needs_ray = pytest.mark.skipif(
    importlib.util.find_spec("ray") is None, reason="needs ray: pip install 'pointclm[ray]'"
)
#: Ray's per-node agents notice their raylet gone only after about a minute.
RAY_AGENTS = (b"ray::DashboardAgent", b"ray::RuntimeEnvAgent")


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Small scans (two posed copies of a 400-point bunny each) and the lines of an
    uninterrupted local run of the command."""
    root = tmp_path_factory.mktemp("ray_faults")
    model = load_shape("bunny", 400)
    d = float(np.linalg.norm(np.ptp(model, axis=0)))
    write_ply(root / "model.ply", model)
    (root / "scans").mkdir()
    rng = np.random.default_rng(5)
    for i in range(N_SCANS):
        parts = []
        for j in range(2):
            q, r = np.linalg.qr(rng.normal(size=(3, 3)))
            q *= np.sign(np.diag(r))
            q *= np.linalg.det(q)  # a reflection turned into a rotation
            parts.append(model @ q.T + [(2 * j - 1) * d, 0.3 * i * d, 0])
        write_ply(root / "scans" / f"s{i:02d}.ply", np.vstack(parts))
    data = {"model": root / "model.ply", "scans": root / "scans"}
    done = _run(_argv(data, root / "reference.jsonl"))
    assert done.returncode == 0, done.stderr
    data["reference"], torn = _read(root / "reference.jsonl")
    assert len(data["reference"]) == N_SCANS and not torn
    return data


def _argv(data: dict[str, Any], out: Path, *extra: str) -> list[str]:
    cmd = [sys.executable, "-m", "pointclm", "batch", str(data["model"]), str(data["scans"])]
    return [*cmd, "--out", str(out), "--seed", str(SEED), "--quiet", *extra]


def _run(argv: list[str], preexec: Any = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        argv, env=ENV, capture_output=True, text=True, timeout=300, preexec_fn=preexec
    )


def _start(argv: list[str], preexec: Any = None) -> subprocess.Popen[str]:
    return subprocess.Popen(
        argv, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        preexec_fn=preexec,
    )  # fmt: skip


def _read(path: Path) -> tuple[list[dict[str, Any]], bool]:
    """The whole lines of `path` (timings and picture paths dropped) and whether one cut
    short follows."""
    if not path.exists():
        return [], False
    raw = path.read_bytes()
    good = raw.rfind(b"\n") + 1
    lines = [without_timings(json.loads(x)) for x in raw[:good].splitlines()]
    return [{k: v for k, v in x.items() if k != "ply"} for x in lines], good < len(raw)


def _lines_written(out: Path) -> int:
    return out.read_bytes().count(b"\n") if out.exists() else 0


def _wait_for_a_line(proc: subprocess.Popen[str], out: Path, more_than: int = 0) -> None:
    while proc.poll() is None and _lines_written(out) <= more_than:
        time.sleep(0.005)


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def _descendants(pid: int) -> list[int]:
    parents = {}
    for entry in Path("/proc").iterdir():
        try:
            stat = (entry / "stat").read_text() if entry.name.isdigit() else ""
        except OSError:
            continue
        if stat and stat.rsplit(")", 1)[1].split()[0] != "Z":
            parents[int(entry.name)] = int(stat.rsplit(")", 1)[1].split()[1])
    found, frontier = [], {pid}
    while frontier:
        frontier = {p for p, parent in parents.items() if parent in frontier}
        found += frontier
    return found


def _alive(pids: list[int]) -> list[int]:
    out = []
    for p in pids:
        try:
            if Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z":
                out.append(p)
        except OSError:
            pass
    return out


def _without_dac_override() -> None:
    # Root writes through file modes; without CAP_DAC_OVERRIDE in the bounding set the
    # exec'd command (and every process it starts, Ray's too) is held to them.
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (1, 2):  # CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH
        if libc.prctl(24, cap, 0, 0, 0) != 0:  # PR_CAPBSET_DROP
            os._exit(99)


PREEXEC = _without_dac_override if os.geteuid() == 0 else None


@pytest.mark.parametrize("engine", ["local", pytest.param("ray", marks=needs_ray)])
def test_a_picture_folder_made_read_only_mid_run_stops_then_resumes(
    engine: str, data: dict[str, Any], tmp_path: Path
) -> None:
    flags = RAY if engine == "ray" else ["--workers", "2"]
    out, ply = tmp_path / "p.jsonl", tmp_path / "ply"
    proc = _start(_argv(data, out, *flags, "--ply-dir", str(ply)), preexec=PREEXEC)
    _wait_for_a_line(proc, out)
    ply.chmod(0o555)
    try:
        err = proc.communicate(timeout=300)[1]
    finally:
        ply.chmod(0o755)
    if proc.returncode == 99:
        pytest.skip("root without CAP_SETPCAP: file modes do not hold")
    assert proc.returncode == 2, err
    assert "could not write" in err and "permission denied" in err and "--resume" in err
    lines, torn = _read(out)
    assert 1 <= len(lines) < N_SCANS and lines == data["reference"][: len(lines)]
    assert not torn  # the line of the scan whose cloud failed was never begun
    done = _run(_argv(data, out, *flags, "--ply-dir", str(ply), "--resume"))
    assert done.returncode == 0, done.stderr
    assert _read(out) == (data["reference"], False)
    # A cloud begun as the folder turned read-only leaves its hidden temporary file behind
    # (a read-only folder cannot lose a file); the clouds themselves are all there.
    assert len([p for p in ply.glob("*.ply") if not p.name.startswith(".")]) == N_SCANS


WRITE_AS_FOLDER_TURNS = """
import os, sys
from pointclm.batch.results import OutputWriteError
from pointclm.batch.worker import _writing
from pointclm.io.files import check_output_path
folder = sys.argv[1]
try:
    with _writing(os.path.join(folder, "a.ply")) as tmp:
        os.chmod(folder, 0o555)
        check_output_path(tmp)  # as the cloud and picture writers do before writing
except OutputWriteError as e:
    print(type(e).__name__, e.errno)
"""


def test_a_folder_turning_read_only_between_temp_file_and_write_stops_the_batch(
    tmp_path: Path,
) -> None:
    # The race the mid-run test can hit: the writer's own check fails with a ValueError,
    # which must stop the batch like any failed write, not be recorded as the scan's error.
    folder = tmp_path / "ply"
    folder.mkdir()
    try:
        done = _run([sys.executable, "-c", WRITE_AS_FOLDER_TURNS, str(folder)], preexec=PREEXEC)
    finally:
        folder.chmod(0o755)
    if done.returncode == 99:
        pytest.skip("root without CAP_SETPCAP: file modes do not hold")
    assert done.stdout.split() == ["OutputWriteError", "13"], done.stderr


def test_an_output_file_made_read_only_mid_run(data: dict[str, Any], tmp_path: Path) -> None:
    out = tmp_path / "f.jsonl"
    proc = _start(_argv(data, out, "--workers", "2"), preexec=PREEXEC)
    _wait_for_a_line(proc, out)
    out.chmod(0o444)
    err = proc.communicate(timeout=300)[1]
    if proc.returncode == 99:
        pytest.skip("root without CAP_SETPCAP: file modes do not hold")
    # The mode holds at open: the batch writes on through the file it opened, to the end.
    assert proc.returncode == 0, err
    assert _read(out) == (data["reference"], False)
    again = _run(_argv(data, out, "--resume"), preexec=PREEXEC)
    assert again.returncode == 2
    assert f"out {out} exists and is not writable" in again.stderr


@needs_ray
def test_ray_workers_killed_again_and_again(data: dict[str, Any], tmp_path: Path) -> None:
    out = tmp_path / "w.jsonl"
    proc = _start(_argv(data, out, *RAY))
    kills, seen = 0, 0
    while proc.poll() is None:
        now = _lines_written(out)
        running = [p for p in _descendants(proc.pid) if _cmdline(p).startswith(b"ray::_scan")]
        # Once the batch moved on since the last kill: a scan killed every time would fail.
        if kills < 2 and now > seen and running:
            os.kill(running[0], signal.SIGKILL)
            kills, seen = kills + 1, now
        time.sleep(0.005)
    err = proc.stderr.read() if proc.stderr else ""
    assert proc.returncode == 0, err
    assert kills, "the batch ended before a Ray worker could be killed"
    assert _read(out) == (data["reference"], False)  # Ray ran each dead worker's task again


@needs_ray
def test_ray_read_only_folder_is_refused_before_any_scan(
    data: dict[str, Any], tmp_path: Path
) -> None:
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        done = _run(_argv(data, folder / "x.jsonl", *RAY), preexec=PREEXEC)
    finally:
        folder.chmod(0o755)
    if done.returncode == 99:
        pytest.skip("root without CAP_SETPCAP: file modes do not hold")
    assert done.returncode == 2
    assert f"the folder {folder} is not writable" in done.stderr


@needs_ray
def test_ray_batch_killed_then_resumed_on_ray(data: dict[str, Any], tmp_path: Path) -> None:
    out = tmp_path / "k.jsonl"
    proc = _start(_argv(data, out, *RAY))
    _wait_for_a_line(proc, out)
    below = _descendants(proc.pid)
    killed = proc.poll() is None
    proc.kill()
    proc.communicate()
    agents = [p for p in below if _cmdline(p).startswith(RAY_AGENTS)]
    deadline = time.monotonic() + 20
    while _alive([p for p in below if p not in agents]) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = _alive([p for p in below if p not in agents])
    for p in _alive(below):  # ours to end, whatever the verdict
        os.kill(p, signal.SIGKILL)
    assert killed, "the batch ended before it could be killed"
    assert not left, "Ray's GCS, raylet or workers outlived the killed command"
    lines, torn = _read(out)
    assert lines == data["reference"][: len(lines)]
    done = _run(_argv(data, out, *RAY, "--resume"))
    assert done.returncode == 0, done.stderr
    assert _read(out) == (data["reference"], False)

"""`pointclm batch` under faults (a short version of benchmarks/batch/faults.py): killed at
random moments, a file-size limit, a read-only folder, workers killed, a scan truncated while
the batch runs. Each ends with a clear message and exit code; the output holds whole lines of
the uninterrupted run, in order, with at most one line cut short; ``--resume`` completes it
to the uninterrupted run's lines; no worker process outlives a killed batch."""

from __future__ import annotations

import ctypes
import errno
import io
import json
import os
import random
import resource
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections import Counter, deque
from concurrent.futures import Future
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

import numpy as np
import pointclm
import pytest
from pointclm.batch import without_timings
from pointclm.batch.local import MAX_ATTEMPTS, Task, _requeue
from pointclm.batch.options import BatchJob
from pointclm.batch.results import OrderedWriter, OutputWriteError
from pointclm.datasets import load_shape
from pointclm.io import write_ply

pytestmark = pytest.mark.skipif(
    not Path("/proc/self/stat").exists(), reason="needs Linux's /proc to find worker processes"
)

SEED = 3
N_SCANS = 16
ENV = {**os.environ, "PYTHONPATH": str(Path(pointclm.__file__).resolve().parents[1])}


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Small scans (two posed copies of a 400-point bunny each) and the lines of an
    uninterrupted run of the command."""
    root = tmp_path_factory.mktemp("faults")
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
    data["size"] = (root / "reference.jsonl").stat().st_size
    return data


def _argv(data: dict[str, Any], out: Path, *extra: str) -> list[str]:
    cmd = [sys.executable, "-m", "pointclm", "batch", str(data["model"]), str(data["scans"])]
    return [*cmd, "--out", str(out), "--seed", str(SEED), "--quiet", *extra]


def _run(argv: list[str], preexec: Any = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        argv, env=ENV, capture_output=True, text=True, timeout=300, preexec_fn=preexec
    )


def _read(path: Path) -> tuple[list[dict[str, Any]], bool]:
    """The whole lines of `path` (timings dropped) and whether one cut short follows."""
    if not path.exists():
        return [], False
    raw = path.read_bytes()
    good = raw.rfind(b"\n") + 1
    return [without_timings(json.loads(x)) for x in raw[:good].splitlines()], good < len(raw)


def _check_prefix(path: Path, reference: list[dict[str, Any]]) -> int:
    lines, _ = _read(path)
    assert lines == reference[: len(lines)], "not the uninterrupted run's first lines"
    return len(lines)


def _resume_completes(data: dict[str, Any], out: Path) -> None:
    done = _run(_argv(data, out, "--resume"))
    assert done.returncode == 0, done.stderr
    assert _read(out) == (data["reference"], False)


def _children(pid: int) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        try:
            stat = (entry / "stat").read_text() if entry.name.isdigit() else ""
        except OSError:
            continue
        if stat and int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            found.append(int(entry.name))
    return found


def _running(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _is_worker(pid: int) -> bool:
    try:
        return b"spawn_main" in Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False


def _lines_written(out: Path) -> int:
    return out.read_bytes().count(b"\n") if out.exists() else 0


def test_killed_at_random_moments_resumes_to_the_uninterrupted_lines(
    data: dict[str, Any], tmp_path: Path
) -> None:
    out, rng, kills = tmp_path / "k.jsonl", random.Random(1), 0
    for attempt in range(12):
        workers = "2" if attempt % 2 else "1"
        proc = subprocess.Popen(
            _argv(data, out, "--resume", "--workers", workers),
            env=ENV,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        start = _lines_written(out)
        deadline = time.monotonic() + 60
        # Killed once it has written a few lines more (or at once when nothing is left).
        target = start + rng.randint(0, 3)
        while proc.poll() is None and _lines_written(out) < target and time.monotonic() < deadline:
            time.sleep(0.002)
        kids = _children(proc.pid)
        if proc.poll() is None:
            proc.kill()
            kills += 1
        proc.wait()
        _check_prefix(out, data["reference"])
        deadline = time.monotonic() + 10
        while any(_running(p) for p in kids) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not [p for p in kids if _running(p)], "a process outlived the killed batch"
        if kills == 4:
            break
    assert kills == 4
    _resume_completes(data, out)


def test_a_file_size_limit_stops_the_batch_with_a_clear_message(
    data: dict[str, Any], tmp_path: Path
) -> None:
    out, limit = tmp_path / "f.jsonl", data["size"] // 3

    def small_files() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    done = _run(_argv(data, out, "--workers", "2"), preexec=small_files)
    assert done.returncode == 2
    assert "the file would exceed the file-size limit" in done.stderr
    assert "--resume" in done.stderr and "Traceback" not in done.stderr
    assert out.stat().st_size == limit  # filled up to the limit: a line was cut short
    assert 1 <= _check_prefix(out, data["reference"]) < N_SCANS
    _resume_completes(data, out)


def test_a_cloud_that_cannot_be_written_stops_the_batch(
    data: dict[str, Any], tmp_path: Path
) -> None:
    def small_files() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))

    out = tmp_path / "p.jsonl"
    done = _run(_argv(data, out, "--ply-dir", str(tmp_path / "ply")), preexec=small_files)
    # Not recorded as the scan's error, line after line: the batch stops at the first.
    assert done.returncode == 2
    assert "could not write" in done.stderr and "s00.ply" in done.stderr
    assert _read(out) == ([], False)


def _without_dac_override() -> None:
    # Root writes through file modes; without CAP_DAC_OVERRIDE in the bounding set the
    # exec'd command is held to them like any user.
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (1, 2):  # CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH
        if libc.prctl(24, cap, 0, 0, 0) != 0:  # PR_CAPBSET_DROP
            os._exit(99)


def test_a_read_only_folder_is_refused_before_any_scan(
    data: dict[str, Any], tmp_path: Path
) -> None:
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        preexec = _without_dac_override if os.geteuid() == 0 else None
        done = _run(_argv(data, folder / "x.jsonl"), preexec=preexec)
        if done.returncode == 99:
            pytest.skip("root without CAP_SETPCAP: file modes do not hold")
    finally:
        folder.chmod(0o755)
    assert done.returncode == 2
    assert f"the folder {folder} is not writable" in done.stderr
    assert not (folder / "x.jsonl").exists()


def test_a_worker_killed_again_and_again(data: dict[str, Any], tmp_path: Path) -> None:
    out = tmp_path / "w.jsonl"
    proc = subprocess.Popen(
        _argv(data, out, "--workers", "2"),
        env=ENV,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    kills = []

    def killer() -> None:
        seen = 0
        while len(kills) < 2 and proc.poll() is None:
            now = _lines_written(out)
            # Killed while it registers: once the batch moved on since the last kill.
            workers = [p for p in _children(proc.pid) if _running(p) and _is_worker(p)]
            if now > seen and workers:
                os.kill(workers[0], signal.SIGKILL)
                kills.append(workers[0])
                seen = now
            time.sleep(0.002)

    thread = threading.Thread(target=killer)
    thread.start()
    _, err = proc.communicate(timeout=300)
    thread.join()
    assert proc.returncode == 0, err
    assert kills, "the batch ended before a worker could be killed"
    # Each death is charged to the scan its worker ran, not to those that ended with the
    # pool or waited in its queue: no scan reaches three tries, every one runs to the end.
    assert _read(out) == (data["reference"], False)


def test_a_worker_death_is_charged_to_its_own_scan() -> None:
    def lost(position: int) -> tuple[Future[dict[str, Any]], Task]:
        future: Future[dict[str, Any]] = Future()
        future.set_exception(BrokenProcessPool("a child process terminated abruptly"))
        return future, (position, f"s{position}.ply", f"s{position}")

    job = BatchJob("model.ply")
    for named, charged in (({3}, {3: 1}), (set(), {2: 1, 3: 1, 4: 1})):
        running, todo, attempts = dict(lost(p) for p in (2, 3, 4)), deque[Task](), Counter[int]()
        assert list(_requeue(running, todo, attempts, job, lambda n=named: n)) == []
        assert attempts == charged and [t[0] for t in todo] == [2, 3, 4]
    attempts = Counter({3: MAX_ATTEMPTS - 1})
    running, todo = dict(lost(p) for p in (2, 3)), deque[Task]()
    [(position, record)] = _requeue(running, todo, attempts, job, lambda: {3})
    assert position == 3 and record["error"] == "WorkerCrashedError"
    assert [t[0] for t in todo] == [2] and attempts[2] == 0


def test_a_scan_truncated_while_the_batch_runs(data: dict[str, Any], tmp_path: Path) -> None:
    scans = tmp_path / "scans"
    shutil.copytree(data["scans"], scans)
    last = sorted(scans.iterdir())[-1]
    out = tmp_path / "t.jsonl"
    argv = _argv(data, out)
    argv[argv.index(str(data["scans"]))] = str(scans)
    proc = subprocess.Popen(
        argv, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    while proc.poll() is None and _lines_written(out) < 1:
        time.sleep(0.001)
    assert proc.poll() is None, "the batch ended before the scan could be truncated"
    os.truncate(last, last.stat().st_size // 2)
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr
    assert f"{N_SCANS - 1} registered, 1 failed" in stdout
    lines, _ = _read(out)
    renamed = [{**x, "scan": x["scan"].replace(str(scans), str(data["scans"]))} for x in lines]
    assert renamed[:-1] == data["reference"][:-1]
    assert lines[-1]["status"] == "error" and "truncated" in lines[-1]["message"]


class _FillingFile(io.RawIOBase):
    """A file on a disk with `room` bytes left: a write takes what fits, then ENOSPC."""

    name = "out.jsonl"

    def __init__(self, room: int) -> None:
        self.room, self.data = room, b""

    def writable(self) -> bool:
        return True

    def write(self, b: Any) -> int:
        if self.room == 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        taken = bytes(b[: self.room])
        self.data += taken
        self.room -= len(taken)
        return len(taken)

    def fileno(self) -> int:
        return -1


def test_a_full_disk_mid_line_leaves_whole_lines_and_one_cut_short(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(os, "fsync", lambda fd: None)
    fh = _FillingFile(room=100)
    writer = OrderedWriter(fh, [0, 1, 2])  # type: ignore[arg-type]
    with pytest.raises(OutputWriteError, match="out.jsonl: the disk is full") as e:
        writer.add(0, {"scan": "a", "pad": "x" * 60})
        writer.add(1, {"scan": "b", "pad": "x" * 60})
    assert e.value.errno == errno.ENOSPC
    with pytest.raises(OutputWriteError):  # nothing more goes to a failed output
        writer.add(2, {"scan": "c"})
    whole, _, rest = fh.data.rpartition(b"\n")
    assert json.loads(whole)["scan"] == "a" and rest and b"\n" not in rest

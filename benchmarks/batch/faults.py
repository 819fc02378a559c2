"""`pointclm batch` under faults: SIGKILL at random moments, a full disk, a read-only output,
worker processes killed again and again, a scan truncated while the batch runs.

    python -m benchmarks.batch.faults [--kills 100] [--scans 40] [--quick] [--no-mount]

Every fault runs the command (``python -m pointclm batch``, the local engine, 1 or 2
workers) in a subprocess on ``--scans`` small scans (two posed copies of the bundled bunny,
600 points each) and checks what it leaves:

- the exit code and the one-line message on stderr;
- the output: its whole lines must be the first lines of an uninterrupted run (timings
  aside), in order, none twice, with at most one line cut short at the end;
- after ``--resume`` (the fault removed), the same lines as the uninterrupted run;
- no worker process left running once the command is gone.

Faults: ``kill`` (SIGKILL after a random delay, resumed each time; half the runs with 2
workers); ``file-size limit`` (``RLIMIT_FSIZE`` in the child, EFBIG); ``full disk`` and
``read-only filesystem`` (a small tmpfs, and one mounted read-only: root only, skipped with
``--no-mount``; Linux refuses to remount a filesystem read-only while a file on it is open
for writing, so a batch cannot meet EROFS half way); ``read-only folder`` (mode 0555; a
root child drops CAP_DAC_OVERRIDE so the mode applies); ``worker killed`` (a worker of 2
killed each time a line was written since the last kill, at most every 0.3 s); ``scan
truncated`` (the last scan cut to half its bytes once the first line is out). Then
(``--no-ray`` leaves them out) faults_ray's: the same faults with Ray as
the executor, and an output made read-only while the batch runs. Prints a markdown table.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import platform
import random
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
from pointclm.batch import without_timings
from pointclm.datasets import load_shape
from pointclm.io import write_ply

from benchmarks.common.report import pointclm_env

SEED = 3
ENV = pointclm_env()


def make_data(root: Path, n: int) -> tuple[Path, Path]:
    model = load_shape("bunny", 600)
    d = float(np.linalg.norm(np.ptp(model, axis=0)))
    write_ply(root / "model.ply", model)
    scans = root / "scans"
    scans.mkdir()
    rng = np.random.default_rng(7)
    for i in range(n):
        parts = []
        for j in range(2):
            q, r = np.linalg.qr(rng.normal(size=(3, 3)))
            q *= np.sign(np.diag(r))
            q *= np.linalg.det(q)  # a reflection turned into a rotation
            parts.append(model @ q.T + [(2 * j - 1) * d, 0.3 * i * d, 0])
        write_ply(scans / f"s{i:03d}.ply", np.vstack(parts))
    return root / "model.ply", scans


def argv(model: Path, scans: Path, out: Path, *extra: str) -> list[str]:
    return [
        sys.executable,
        "-m",
        "pointclm",
        "batch",
        str(model),
        str(scans),
        "--out",
        str(out),
        "--seed",
        str(SEED),
        "--quiet",
        *extra,
    ]


def read_out(path: Path) -> tuple[list[dict[str, Any]], bool]:
    """The whole lines (timings dropped) and whether a last line was cut short."""
    if not path.exists():
        return [], False
    raw = path.read_bytes()
    good = raw.rfind(b"\n") + 1
    lines = [without_timings(json.loads(x)) for x in raw[:good].splitlines()]
    return lines, good < len(raw)


def check_prefix(path: Path, reference: list[dict[str, Any]]) -> tuple[int, bool]:
    """Asserts that the whole lines of `path` are the reference's first ones; returns their
    number and whether a torn line follows."""
    lines, torn = read_out(path)
    assert lines == reference[: len(lines)], f"{path}: not a prefix of the uninterrupted run"
    return len(lines), torn


def children(pid: int) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(entry.name))
    return found


def wait_gone(pids: list[int], timeout: float = 5.0) -> int:
    """How many of `pids` still run after `timeout` seconds (killed then: orphans)."""
    deadline = time.monotonic() + timeout
    alive = list(pids)
    while alive and time.monotonic() < deadline:
        alive = [p for p in alive if Path(f"/proc/{p}").exists() and not _zombie(p)]
        time.sleep(0.05)
    for p in alive:
        print(f"orphan {p}: {_cmdline(p)[:120]!r}", file=sys.stderr)
        os.kill(p, signal.SIGKILL)
    return len(alive)


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


def run(cmd: list[str], preexec: Any = None, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        cmd, env=ENV, capture_output=True, text=True, timeout=timeout, preexec_fn=preexec
    )


def message(proc: subprocess.CompletedProcess) -> str:
    lines = [x for x in proc.stderr.splitlines() if x.startswith("pointclm")]
    return lines[-1] if lines else proc.stderr.strip()[-200:]


def resumed_equal(model: Path, scans: Path, out: Path, reference: list[dict[str, Any]]) -> bool:
    r = run(argv(model, scans, out, "--resume"))
    assert r.returncode == 0, r.stderr
    return read_out(out) == (reference, False)


def fault_kills(model, scans, tmp, reference, kills, full_time) -> dict[str, Any]:
    rng = random.Random(0)
    out = tmp / "kills.jsonl"
    torn = finished = orphans = rounds = 0
    killed = 0
    while killed < kills:
        workers = "2" if killed % 2 else "1"
        proc = subprocess.Popen(
            argv(model, scans, out, "--resume", "--workers", workers),
            env=ENV,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        time.sleep(rng.uniform(0.0, full_time))
        kids = children(proc.pid)
        if proc.poll() is None:
            proc.kill()
            killed += 1
        else:
            finished += 1
        proc.wait()
        orphans += wait_gone(kids)
        n, cut = check_prefix(out, reference)
        torn += cut
        if n == len(reference):  # done: start again from nothing to keep killing mid-way
            assert read_out(out) == (reference, False)
            out.unlink()
            rounds += 1
    same = resumed_equal(model, scans, out, reference)
    return {
        "fault": f"SIGKILL at a random moment, then --resume ({kills} kills)",
        "exit": f"-9 x{killed}",
        "torn": torn,
        "orphans": orphans,
        "same": same,
        "message": f"{rounds} whole batches completed across the kills; {finished} runs "
        "ended before their kill",
    }


def _fsize(limit: int) -> Any:
    return lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))


def fault_fsize(model, scans, tmp, reference, size) -> list[dict[str, Any]]:
    rows = []
    for workers in ("1", "2"):
        out = tmp / f"fsize{workers}.jsonl"
        r = run(argv(model, scans, out, "--workers", workers), preexec=_fsize(size // 3))
        n, cut = check_prefix(out, reference)
        rows.append(
            {
                "fault": f"file-size limit {size // 3} B, {workers} worker(s)",
                "exit": r.returncode,
                "torn": int(cut),
                "orphans": 0,
                "same": resumed_equal(model, scans, out, reference),
                "message": message(r),
            }
        )
    return rows


def _drop_dac() -> None:
    # Root writes through file modes; without CAP_DAC_OVERRIDE in the bounding set the
    # exec'd command is held to them like any user.
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (1, 2):  # CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH
        libc.prctl(24, cap, 0, 0, 0)  # PR_CAPBSET_DROP


def fault_read_only_folder(model, scans, tmp) -> dict[str, Any]:
    folder = tmp / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    r = run(
        argv(model, scans, folder / "x.jsonl"), preexec=_drop_dac if os.geteuid() == 0 else None
    )
    folder.chmod(0o755)
    return {
        "fault": "read-only folder (mode 0555)",
        "exit": r.returncode,
        "torn": 0,
        "orphans": 0,
        "same": not (folder / "x.jsonl").exists(),
        "message": message(r),
    }


def _mount(path: Path, options: str) -> bool:
    path.mkdir(exist_ok=True)
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(path)], capture_output=True
    )
    return r.returncode == 0


def fault_mounts(model, scans, tmp, reference, size) -> list[dict[str, Any]]:
    rows = []
    full = tmp / "full"
    if not _mount(full, f"size={max(4096, size // 3)}"):
        return rows
    try:
        out = full / "x.jsonl"
        r = run(argv(model, scans, out, "--workers", "2"))
        n, cut = check_prefix(out, reference)
        shutil.copy(out, tmp / "full.jsonl")
    finally:
        subprocess.run(["umount", str(full)], check=True)
    rows.append(
        {
            "fault": f"full disk (tmpfs of {max(4096, size // 3)} B), 2 workers",
            "exit": r.returncode,
            "torn": int(cut),
            "orphans": 0,
            "same": resumed_equal(model, scans, tmp / "full.jsonl", reference),
            "message": message(r),
        }
    )
    ro = tmp / "rofs"
    if _mount(ro, "ro,size=64k"):
        try:
            r = run(argv(model, scans, ro / "x.jsonl"))
        finally:
            subprocess.run(["umount", str(ro)], check=True)
        rows.append(
            {
                "fault": "read-only filesystem (tmpfs mounted ro)",
                "exit": r.returncode,
                "torn": 0,
                "orphans": 0,
                "same": True,
                "message": message(r),
            }
        )
    return rows


def fault_worker_kills(model, scans, tmp, reference, kills) -> dict[str, Any]:
    out = tmp / "workers.jsonl"
    proc = subprocess.Popen(
        argv(model, scans, out, "--workers", "2"),
        env=ENV,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    done = [0]

    def killer() -> None:
        lines = 0
        while done[0] < kills and proc.poll() is None:
            time.sleep(0.3)
            # Only once the batch moved on since the last kill: a worker killed before the
            # pool ever runs is a batch that cannot run at all (it stops after 3 tries).
            now = out.read_bytes().count(b"\n") if out.exists() else 0
            workers = [p for p in children(proc.pid) if b"spawn_main" in _cmdline(p)]
            if now > lines and workers:
                os.kill(random.choice(workers), signal.SIGKILL)
                done[0] += 1
                lines = now

    t = threading.Thread(target=killer)
    t.start()
    _, err = proc.communicate(timeout=600)
    t.join()
    lines, cut = read_out(out)
    crashed = [x for x in lines if x.get("error") == "WorkerCrashedError"]
    # Each death is charged to the scan its worker ran: none reaches three tries here.
    same = lines == reference
    return {
        "fault": f"a worker of 2 killed again and again ({done[0]} kills)",
        "exit": proc.returncode,
        "torn": int(cut),
        "orphans": 0,
        "same": same,
        "message": f"{len(crashed)} scans recorded as WorkerCrashedError (3 tries) "
        + err.strip()[-300:],
    }


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def fault_truncated(model, scans, tmp, reference) -> dict[str, Any]:
    copy = tmp / "trunc_scans"
    shutil.copytree(scans, copy)
    last = sorted(copy.iterdir())[-1]
    out = tmp / "trunc.jsonl"
    proc = subprocess.Popen(
        argv(model, copy, out),
        env=ENV,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    while proc.poll() is None and not (out.exists() and out.read_bytes().count(b"\n") >= 1):
        time.sleep(0.002)
    os.truncate(last, last.stat().st_size // 2)
    _, err = proc.communicate(timeout=300)
    lines, cut = read_out(out)
    others = [{**x, "scan": x["scan"].replace(str(copy), str(scans))} for x in lines[:-1]]
    same = others == reference[:-1] and lines[-1]["status"] == "error"
    return {
        "fault": "last scan truncated to half while the batch runs",
        "exit": proc.returncode,
        "torn": int(cut),
        "orphans": 0,
        "same": same,
        "message": f"its line: {lines[-1].get('error')}: {lines[-1].get('message')}",
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--kills", type=int, default=100)
    ap.add_argument("--scans", type=int, default=40)
    ap.add_argument("--worker-kills", type=int, default=10)
    ap.add_argument("--quick", action="store_true", help="10 kills, 20 scans")
    ap.add_argument("--no-mount", action="store_true", help="no tmpfs faults (root only)")
    ap.add_argument("--no-ray", action="store_true", help="without faults_ray's cases")
    ap.add_argument("--ray-kills", type=int, default=5, help="SIGKILLs of a Ray batch")
    args = ap.parse_args()
    if args.quick:
        args.kills, args.scans, args.worker_kills, args.ray_kills = 10, 20, 4, 2
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        model, scans = make_data(tmp, args.scans)
        t = time.perf_counter()
        r = run(argv(model, scans, tmp / "reference.jsonl"))
        full_time = time.perf_counter() - t
        assert r.returncode == 0, r.stderr
        reference, _ = read_out(tmp / "reference.jsonl")
        size = (tmp / "reference.jsonl").stat().st_size
        rows = [fault_kills(model, scans, tmp, reference, args.kills, full_time)]
        rows += fault_fsize(model, scans, tmp, reference, size)
        rows.append(fault_read_only_folder(model, scans, tmp))
        if not args.no_mount and os.geteuid() == 0:
            rows += fault_mounts(model, scans, tmp, reference, size)
        rows.append(fault_worker_kills(model, scans, tmp, reference, args.worker_kills))
        rows.append(fault_truncated(model, scans, tmp, reference))
        if not args.no_ray:
            from benchmarks.batch.faults_ray import ray_rows

            rows += ray_rows(model, scans, tmp, reference, args.ray_kills, args.worker_kills)
    print_table(f"{args.scans} scans, one run {full_time:.1f} s", rows, t0)


def print_table(what: str, rows: list[dict[str, Any]], t0: float) -> None:
    print(f"## pointclm batch under faults ({what})")
    print(
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
        f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, {time.perf_counter() - t0:.0f} s "
        "in all\n"
    )
    print("| fault | exit code | torn last lines | orphan workers | output right | message |")
    print("|---|---|---|---|---|---|")
    for row in rows:
        print(
            f"| {row['fault']} | {row['exit']} | {row['torn']} | {row['orphans']} | "
            f"{'yes' if row['same'] else 'NO'} | {row['message']} |"
        )


if __name__ == "__main__":
    main()

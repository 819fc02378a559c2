"""The faults of benchmarks/batch/faults.py with Ray as the executor, and an output that
becomes read-only while a batch runs (local pool and Ray); `faults` runs these
after its own, or alone:

    python -m benchmarks.batch.faults_ray [--scans 40] [--kills 5] [--worker-kills 4]

Ray cases (skipped, and said so, without ``pip install 'pointclm[ray]'``): a Ray worker
process (``ray::_scan_task``) killed each time a line was written since the last kill; a
read-only output folder; the command killed (SIGKILL) at a random moment once Ray is up,
then ``--resume`` on Ray, the output compared with the uninterrupted local run's. Mid-run
cases, per engine: the output file made read-only (mode 0444) once the first line is out,
and the ``--ply-dir`` folder made read-only (0555) then. A root child drops
CAP_DAC_OVERRIDE so the modes apply to it and to every process it starts (Ray's too).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.batch.faults import (  # noqa: E402
    ENV,
    _cmdline,
    _drop_dac,
    argv,
    check_prefix,
    make_data,
    message,
    read_out,
    run,
)

RAY = ["--engine", "ray", "--workers", "2"]
ENV["RAY_AUTH_MODE"] = "disabled"  # throwaway local clusters: no token, no warning about it


def has_ray() -> bool:
    return importlib.util.find_spec("ray") is not None


def descendants(pid: int) -> list[int]:
    """Every process below `pid` (Ray's raylet starts the workers: grandchildren)."""
    parents = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            fields = stat.rsplit(")", 1)[1].split()
            if fields[0] != "Z":
                parents[int(entry.name)] = int(fields[1])
    found, frontier = [], {pid}
    while frontier:
        frontier = {p for p, parent in parents.items() if parent in frontier}
        found += frontier
    return found


def alive(pids: list[int]) -> list[int]:
    out = []
    for p in pids:
        try:
            if Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z":
                out.append(p)
        except OSError:
            pass
    return out


def orphans(pids: list[int], timeout: float = 15.0) -> int:
    """How many of `pids` still run `timeout` s after their command ended (then killed)."""
    deadline = time.monotonic() + timeout
    left = alive(pids)
    while left and time.monotonic() < deadline:
        time.sleep(0.1)
        left = alive(left)
    for p in left:
        print(f"orphan {p}: {_cmdline(p)[:100]!r}", file=sys.stderr)
        os.kill(p, signal.SIGKILL)
    return len(left)


def _preexec() -> Any:
    return _drop_dac if os.geteuid() == 0 else None


def lines_written(out: Path) -> int:
    return out.read_bytes().count(b"\n") if out.exists() else 0


def ray_worker_kills(model, scans, tmp, reference, kills) -> dict[str, Any]:
    out = tmp / "ray_workers.jsonl"
    proc = subprocess.Popen(
        argv(model, scans, out, *RAY),
        env=ENV,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    done, seen = 0, 0
    while proc.poll() is None:
        now = lines_written(out)
        tasks = [p for p in descendants(proc.pid) if _cmdline(p).startswith(b"ray::_scan_task")]
        # Only once the batch moved on since the last kill: a scan killed every time fails.
        if done < kills and now > seen and tasks:
            os.kill(random.choice(tasks), signal.SIGKILL)
            done, seen = done + 1, now
        time.sleep(0.01)
    err = proc.stderr.read() if proc.stderr else ""
    lines, cut = read_out(out)
    failed = [x for x in lines if x["status"] == "error"]
    return {
        "fault": f"Ray: a worker killed again and again ({done} kills)",
        "exit": proc.returncode,
        "torn": int(cut),
        "orphans": 0,
        "same": lines == reference,
        "message": f"{len(failed)} scans failed (Ray retries a dead worker's task twice)"
        + (f"; {err.strip().splitlines()[-1][:200]}" if proc.returncode else ""),
    }


def ray_read_only_folder(model, scans, tmp) -> dict[str, Any]:
    folder = tmp / "ray_ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        r = run(argv(model, scans, folder / "x.jsonl", *RAY), preexec=_preexec())
    finally:
        folder.chmod(0o755)
    return {
        "fault": "Ray: read-only output folder (mode 0555)",
        "exit": r.returncode,
        "torn": 0,
        "orphans": 0,
        "same": not (folder / "x.jsonl").exists(),
        "message": message(r),
    }


AGENTS = (b"ray::DashboardAgent", b"ray::RuntimeEnvAgent")


def ray_kill_resume(model, scans, tmp, reference, kills, seconds) -> dict[str, Any]:
    """SIGKILL at a random moment of a Ray run (once its workers run), then --resume. Ray's
    GCS, raylet and workers go with the killed command; its two per-node agents notice the
    raylet gone only after about a minute, so they are timed apart."""
    rng = random.Random(0)
    out = tmp / "ray_kills.jsonl"
    torn = left = killed = finished = 0
    agents: list[int] = []
    while killed < kills and finished < 3 * kills:
        proc = subprocess.Popen(
            argv(model, scans, out, "--resume", *RAY),
            env=ENV,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        start = lines_written(out)
        while proc.poll() is None and lines_written(out) == start:
            time.sleep(0.01)  # Ray's start takes seconds: kill while scans are written
        time.sleep(rng.uniform(0.0, seconds))
        below = descendants(proc.pid)
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            killed += 1
        else:
            finished += 1
        proc.wait()
        agents += [p for p in below if _cmdline(p).startswith(AGENTS)]
        left += orphans([p for p in below if p not in agents])
        n, cut = check_prefix(out, reference)
        torn += cut
        if n == len(reference):  # done: start again from nothing to keep killing mid-way
            out.unlink()
    t0 = time.monotonic()
    r = run(argv(model, scans, out, "--resume", *RAY))
    agents_left = orphans(agents, timeout=180.0)
    gone = time.monotonic() - t0
    return {
        "fault": f"Ray: SIGKILL of the command ({killed} kills), then --resume on Ray",
        "exit": f"-9 x{killed}, then {r.returncode}",
        "torn": torn,
        "orphans": left + agents_left,
        "same": r.returncode == 0 and read_out(out) == (reference, False),
        "message": f"{finished} runs ended before their kill; "
        "Ray's GCS, raylet and workers gone within 15 s of each kill; its dashboard "
        f"and runtime-env agents ({len(agents)}) {'gone' if not agents_left else 'NOT gone'} "
        f"{gone:.0f} s after the last kill",
    }


def _without_ply(lines: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: v for k, v in x.items() if k != "ply"} for x in lines]


def mid_run_read_only(model, scans, tmp, reference, engine: list[str]) -> list[dict[str, Any]]:
    """The output file, then the --ply-dir folder, made read-only once the first line is out."""
    name = "Ray" if engine else "local pool of 2"
    engine = engine or ["--workers", "2"]
    rows = []
    out = tmp / f"ro_file_{name[:3]}.jsonl"
    proc = subprocess.Popen(
        argv(model, scans, out, *engine),
        env=ENV,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_preexec(),
    )
    while proc.poll() is None and lines_written(out) == 0:
        time.sleep(0.005)
    out.chmod(0o444)
    err = proc.communicate(timeout=600)[1]
    lines, cut = read_out(out)
    again = run(argv(model, scans, out, "--resume", *engine), preexec=_preexec())
    out.chmod(0o644)
    rows.append(
        {
            "fault": f"{name}: output file made read-only (0444) mid-run",
            "exit": f"{proc.returncode}; --resume then {again.returncode}",
            "torn": int(cut),
            "orphans": 0,
            "same": proc.returncode == 0 and lines == reference,
            "message": "the open file is written on to the end"
            + (err.strip()[-200:] if proc.returncode else "")
            + f"; a --resume then: {message(again)}",
        }
    )
    out, ply = tmp / f"ro_ply_{name[:3]}.jsonl", tmp / f"ply_{name[:3]}"
    proc = subprocess.Popen(
        argv(model, scans, out, *engine, "--ply-dir", str(ply)),
        env=ENV,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_preexec(),
    )
    while proc.poll() is None and lines_written(out) == 0:
        time.sleep(0.005)
    ply.chmod(0o555)
    err = proc.communicate(timeout=600)[1]
    lines, cut = read_out(out)
    prefix = _without_ply(lines) == reference[: len(lines)]
    ply.chmod(0o755)
    again = run(argv(model, scans, out, "--resume", *engine, "--ply-dir", str(ply)))
    whole, _ = read_out(out)
    rows.append(
        {
            "fault": f"{name}: --ply-dir folder made read-only (0555) mid-run, then --resume",
            "exit": f"{proc.returncode}; --resume {again.returncode}",
            "torn": int(cut),
            "orphans": 0,
            "same": prefix and again.returncode == 0 and _without_ply(whole) == reference,
            "message": f"{len(lines)} whole lines kept; "
            + ([x for x in err.splitlines() if x.startswith("pointclm")] or [err[-200:]])[-1],
        }
    )
    return rows


def ray_rows(model, scans, tmp, reference, kills: int, worker_kills: int) -> list[dict[str, Any]]:
    rows = mid_run_read_only(model, scans, tmp, reference, [])
    if not has_ray():
        rows.append(
            {
                "fault": "Ray cases",
                "exit": "-",
                "torn": 0,
                "orphans": 0,
                "same": True,
                "message": "skipped: ray is not installed (pip install 'pointclm[ray]')",
            }
        )
        return rows
    t = time.perf_counter()
    r = run(argv(model, scans, tmp / "ray_reference.jsonl", *RAY))
    seconds = time.perf_counter() - t
    assert r.returncode == 0, r.stderr
    same = read_out(tmp / "ray_reference.jsonl") == (reference, False)
    rows.append(
        {
            "fault": f"Ray, no fault ({seconds:.1f} s with Ray's start)",
            "exit": 0,
            "torn": 0,
            "orphans": 0,
            "same": same,
            "message": "the local run's lines",
        }
    )
    rows.append(ray_worker_kills(model, scans, tmp, reference, worker_kills))
    rows.append(ray_read_only_folder(model, scans, tmp))
    rows.append(ray_kill_resume(model, scans, tmp, reference, kills, 1.0))
    rows += mid_run_read_only(model, scans, tmp, reference, RAY)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scans", type=int, default=40)
    ap.add_argument("--kills", type=int, default=5)
    ap.add_argument("--worker-kills", type=int, default=4)
    args = ap.parse_args()
    from benchmarks.batch.faults import print_table

    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        model, scans = make_data(tmp, args.scans)
        r = run(argv(model, scans, tmp / "reference.jsonl"))
        assert r.returncode == 0, r.stderr
        reference, _ = read_out(tmp / "reference.jsonl")
        t0 = time.perf_counter()
        rows = ray_rows(model, scans, tmp, reference, args.kills, args.worker_kills)
    print_table(f"Ray and mid-run read-only, {args.scans} scans", rows, t0)


if __name__ == "__main__":
    main()

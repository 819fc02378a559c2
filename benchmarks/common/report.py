"""The header every benchmark report starts with, and where the committed reports live.

A report states when it ran (UTC), the command that made it, the hardware, the git commit and
the pointclm version, so that a figure can be traced and rerun.
"""

from __future__ import annotations

import datetime
import os
import platform
import shlex
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

#: The repository root: the suites run from there (``python -m benchmarks.<suite>.<name>``).
ROOT = Path(__file__).resolve().parents[2]
#: The committed reports, one folder per suite (``results/bins/bins.md``...).
RESULTS = ROOT / "benchmarks" / "results"


def utc_now() -> str:
    """``2026-11-29 09:30 UTC``."""
    return f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC"


def command(module: str, argv: Sequence[str] | None = None) -> str:
    """The command line that reruns `module` with `argv` (the process's own by default)."""
    args = list(sys.argv[1:] if argv is None else argv)
    return " ".join(["python -m", module, *map(shlex.quote, args)])


def hardware() -> str:
    """``x86_64, 2 cores``: the processor (or the architecture) and the logical cores."""
    return f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores"


def git_commit(dirty: bool = False) -> str:
    """The short commit of the checkout ("unknown" outside git); with `dirty`, says when the
    tracked files differ from it."""
    rev = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT
    ).stdout.strip()
    if not rev:
        return "unknown"
    if dirty:
        changed = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            cwd=ROOT,
        ).stdout.strip()
        rev += " + uncommitted changes" if changed else ""
    return rev


def load_average() -> str:
    """The 1, 5 and 15 minute load averages: how busy a shared machine was."""
    return ", ".join(f"{x:.2f}" for x in os.getloadavg())


def module_command(module: str) -> list[str]:
    """The argv that runs `module` in a fresh interpreter; run it with ``cwd=ROOT``."""
    return [sys.executable, "-m", module]


def pointclm_env() -> dict[str, str]:
    """This process's environment with the folder its pointclm came from first on PYTHONPATH,
    so that a child process (``python -m pointclm batch``...) runs the same build."""
    import pointclm

    folder = str(Path(pointclm.__file__).resolve().parents[1])
    path = os.pathsep.join(p for p in (folder, os.environ.get("PYTHONPATH", "")) if p)
    return {**os.environ, "PYTHONPATH": path}


def write_report(path: str | os.PathLike[str] | None, text: str) -> None:
    """Print a report, and write it to `path` (its folder made when missing) when given."""
    if path is None:
        print(text)
        return
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(text)

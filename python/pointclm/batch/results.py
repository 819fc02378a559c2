"""The batch's output: one JSON line per scan, in the order of the scan list, each flushed
and synced to disk as soon as it can be written, and read back on ``resume``.

Lines keep the input order (a result that completes early waits for those before it), so a
batch killed and resumed writes the same file as one that ran through, timings aside.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import IO, Any

from ..errors import InputError
from ..io.files import check_output_path

__all__ = ["OrderedWriter", "open_results"]


def _existing_records(path: Path) -> tuple[list[dict[str, Any]], int]:
    """The records already in `path`, and the length of the file up to the last whole one."""
    raw = path.read_bytes()
    # Each line is written with its newline in one call: a last line without one was cut
    # short by a kill, and its scan runs again.
    good = raw.rfind(b"\n") + 1
    records = []
    for n, line in enumerate(raw[:good].split(b"\n")[:-1], start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except ValueError:
            raise InputError(
                f"--resume: line {n} of {path} is not JSON; not a batch output?"
            ) from None
        if not isinstance(record, dict) or not isinstance(record.get("scan"), str):
            raise InputError(f"--resume: line {n} of {path} names no scan; not a batch output?")
        records.append(record)
    return records, good


def open_results(
    out: str | os.PathLike[str], resume: bool, identity: dict[str, Any]
) -> tuple[IO[str], set[str]]:
    """`out` opened for appending, and the scans it already holds (with `resume`). Without
    `resume` an existing non-empty file is an error rather than lost or mixed into; with it,
    a line whose `identity` fields (model, network, options) differ from this run's too."""
    path = check_output_path(out, "out")
    if not path.exists() or path.stat().st_size == 0:
        return path.open("w", encoding="utf-8"), set()
    if not resume:
        raise InputError(
            f"out {path} already holds results: pass --resume (resume=True) to skip the scans "
            "it holds and add the rest, or choose another path"
        )
    records, good = _existing_records(path)
    for record in records:
        for key, value in identity.items():
            if record.get(key) != value:
                raise InputError(
                    f"--resume: {path} holds results made with a different {key} "
                    f"({record['scan']}: "
                    f"{json.dumps(record.get(key))}; this run: {json.dumps(value)}); resume "
                    "with the same model and options, or choose another output path"
                )
    fh = path.open("r+", encoding="utf-8")
    fh.truncate(good)
    fh.seek(good)
    return fh, {r["scan"] for r in records}


class OrderedWriter:
    """Writes records by their position in the scan list: each as soon as every one before it
    is written, flushed and fsync'd, so a killed batch loses at most the scans in flight."""

    def __init__(self, fh: IO[str], positions: list[int]) -> None:
        self._fh = fh
        self._order = positions  # the positions to write, ascending
        self._next = 0
        self._waiting: dict[int, dict[str, Any]] = {}

    def add(self, position: int, record: dict[str, Any]) -> None:
        self._waiting[position] = record
        wrote = False
        while self._next < len(self._order) and self._order[self._next] in self._waiting:
            line = json.dumps(self._waiting.pop(self._order[self._next]), allow_nan=False)
            self._fh.write(line + "\n")
            self._next += 1
            wrote = True
        if wrote:
            self._fh.flush()
            os.fsync(self._fh.fileno())

    @property
    def pending(self) -> int:
        """Records received that wait for an earlier one."""
        return len(self._waiting)

    def close(self) -> None:
        self._fh.close()

"""The batch's output: one JSON line per scan, in the order of the scan list, each flushed
and synced to disk as soon as it can be written, and read back on ``resume``.

Lines keep the input order (a result that completes early waits for those before it), so a
batch killed and resumed writes the same file as one that ran through, timings aside.
"""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path
from typing import IO, Any

from ..errors import InputError
from ..io.files import check_output_path

__all__ = ["OrderedWriter", "OutputWriteError", "open_results"]

_WHY = {
    errno.ENOSPC: "the disk is full",
    errno.EDQUOT: "the disk quota is used up",
    errno.EFBIG: "the file would exceed the file-size limit (ulimit -f)",
    errno.EROFS: "the filesystem is read-only",
    errno.EACCES: "permission denied",
    errno.EPERM: "permission denied",
}


class OutputWriteError(OSError):
    """A batch's output (its JSON lines, a picture, a cloud) could not be written: a full
    disk, a file-size limit, a read-only filesystem, no permission. The batch stops, since
    every later scan would fail the same way; the lines already written are whole (a line
    cut short is dropped by `resume`), so resuming once the cause is fixed adds the rest.
    ``errno``, ``strerror`` and ``filename`` are the failed write's."""

    def __reduce__(self) -> tuple[Any, ...]:
        # Raised in worker processes and sent back: rebuilt from the three fields.
        return (type(self), (self.errno, self.strerror, self.filename))

    def __str__(self) -> str:
        why = _WHY.get(self.errno or 0, self.strerror or "input/output error")
        return (
            f"could not write {self.filename}: {why} ([Errno {self.errno}] {self.strerror}); "
            "the batch stopped, keeping the whole lines written so far: fix that, then run "
            "it again with --resume (resume=True) to add the rest"
        )


def output_error(error: OSError, path: str | os.PathLike[str]) -> OutputWriteError:
    """`error`, raised while writing `path`, as an :class:`OutputWriteError`."""
    return OutputWriteError(error.errno, error.strerror or str(error), os.fspath(path))


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
) -> tuple[IO[bytes], set[str]]:
    """`out` opened for appending (unbuffered: every byte handed over is the OS's), and the
    scans it already holds (with `resume`). Without `resume` an existing non-empty file is an
    error rather than lost or mixed into; with it, a line whose `identity` fields (model,
    network, options) differ from this run's too."""
    path = check_output_path(out, "out")
    if not path.exists() or path.stat().st_size == 0:
        try:
            return path.open("wb", buffering=0), set()
        except OSError as e:
            raise output_error(e, path) from None
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
    try:
        fh = path.open("r+b", buffering=0)
    except OSError as e:
        raise output_error(e, path) from None
    try:
        fh.truncate(good)  # the line a kill cut short goes; its scan runs again
    except OSError as e:
        fh.close()
        raise output_error(e, path) from None
    fh.seek(good)
    return fh, {r["scan"] for r in records}


class OrderedWriter:
    """Writes records by their position in the scan list: each as soon as every one before it
    is written, then synced to disk, so a killed batch loses at most the scans in flight.

    Written straight to the file descriptor, without a buffer in this process: after a failed
    write (a full disk) nothing is left over to be written later, so the file ends where the
    failure left it, with whole lines and at most one cut short."""

    def __init__(self, fh: IO[bytes], positions: list[int]) -> None:
        self._fh = fh
        self._order = positions  # the positions to write, ascending
        self._next = 0
        self._waiting: dict[int, dict[str, Any]] = {}
        self._failed: OutputWriteError | None = None

    def add(self, position: int, record: dict[str, Any]) -> None:
        """Takes the record of the scan at `position` and writes it with those it held back.
        Raises :class:`OutputWriteError` if the file cannot take them (and again on every
        later call)."""
        if self._failed is not None:
            raise self._failed
        self._waiting[position] = record
        lines = []
        while self._next < len(self._order) and self._order[self._next] in self._waiting:
            line = json.dumps(self._waiting.pop(self._order[self._next]), allow_nan=False)
            lines.append(line + "\n")
            self._next += 1
        if lines:
            self._write("".join(lines).encode("utf-8"))

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        try:
            while view:
                # A raw write may take only part (a signal, a nearly full disk): go on from there.
                taken = self._fh.write(view)
                if not taken:
                    raise OSError(errno.EIO, "the file took no bytes")
                view = view[taken:]
            os.fsync(self._fh.fileno())
        except OSError as e:
            self._failed = output_error(e, self._fh.name)
            raise self._failed from None

    @property
    def pending(self) -> int:
        """Records received that wait for an earlier one."""
        return len(self._waiting)

    def close(self) -> None:
        self._fh.close()

"""Shared machinery of the hardening tests (hostile files, property-based arguments).

- :func:`bounded` runs a call under a per-case time limit (SIGALRM), a memory cap
  (``RLIMIT_AS``: the process's current size plus a margin) and ``tracemalloc``, so a hang
  fails the case instead of the suite, and a memory bomb fails it instead of the machine.
- :func:`expect_clean` asserts the outcome the library promises: a result, or a
  ``ValueError`` (any subclass), ``FileNotFoundError`` or ``MemoryError``; anything else
  (TypeError, OverflowError, IndexError, a Rust panic) fails the case.
- :data:`CASES` counts the generated cases per property; with ``POINTCLM_CASE_COUNTS=FILE``
  each module adds its counts to that JSON file (what ``benchmarks/results/batch/hardening.md``
  reports).
"""

from __future__ import annotations

import contextlib
import json
import os
import resource
import signal
import tracemalloc
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

CASES: Counter[str] = Counter()

#: Default limits of one case.
CASE_SECONDS = 10.0
CASE_EXTRA_MEMORY = 1 << 30


class Hang(BaseException):  # noqa: N818 - BaseException: no `except Exception` may hide it
    """A case ran past its time limit."""


@dataclass
class Usage:
    peak_bytes: int = 0


def _vm_size() -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    return 0  # pragma: no cover - Linux only


def _on_alarm(signum: int, frame: Any) -> None:
    raise Hang("case exceeded its time limit")


@contextlib.contextmanager
def bounded(
    seconds: float = CASE_SECONDS, extra_memory: int = CASE_EXTRA_MEMORY
) -> Iterator[Usage]:
    """Time limit, address-space cap and traced peak for the body (main thread only)."""
    usage = Usage()
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = _vm_size() + extra_memory
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    old = signal.signal(signal.SIGALRM, _on_alarm)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    tracemalloc.start()
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield usage
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        usage.peak_bytes = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
        signal.signal(signal.SIGALRM, old)


ALLOWED = (ValueError, FileNotFoundError, MemoryError)


def expect_clean(call: Callable[[], Any], allow_memory_error: bool = True) -> Any:
    """The call's result, or the allowed exception it raised (returned, not raised)."""
    try:
        return call()
    except Hang:
        raise
    except ALLOWED as e:
        if isinstance(e, MemoryError) and not allow_memory_error:
            pytest.fail(f"MemoryError on a small input (a memory bomb): {e}")
        return e
    except BaseException as e:  # noqa: BLE001 - PanicException is a BaseException
        if isinstance(e, KeyboardInterrupt):
            raise
        pytest.fail(f"expected a result or ValueError, got {type(e).__name__}: {e}")


def snapshot(value: Any) -> Any:
    """Deep copies of the arrays in ``value`` (to check that a call leaves inputs alone)."""
    if isinstance(value, np.ndarray):
        return value.copy()
    if isinstance(value, dict):
        return {k: snapshot(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(snapshot(v) for v in value) if not hasattr(value, "_fields") else value
    return value


def assert_unchanged(before: Any, after: Any) -> None:
    if isinstance(before, np.ndarray):
        assert isinstance(after, np.ndarray)
        assert before.dtype == after.dtype and before.shape == after.shape
        assert np.array_equal(before, after, equal_nan=before.dtype.kind in "fc"), (
            "an input array was modified"
        )
    elif isinstance(before, dict):
        for k in before:
            assert_unchanged(before[k], after[k])
    elif isinstance(before, list | tuple) and not hasattr(before, "_fields"):
        for b, a in zip(before, after, strict=True):
            assert_unchanged(b, a)


def write_counts(module: str) -> None:
    """Add this module's case counts to the file named by POINTCLM_CASE_COUNTS."""
    path = os.environ.get("POINTCLM_CASE_COUNTS")
    if not path:
        return
    mine = {k: v for k, v in CASES.items() if k.startswith(module + ":")}
    try:
        with open(path) as fh:
            data = json.load(fh)
    except (OSError, ValueError):
        data = {}
    data.update(mine)
    with open(path, "w") as fh:
        json.dump(dict(sorted(data.items())), fh, indent=2)

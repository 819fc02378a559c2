"""Long use and many threads, in short (benchmarks/batch/soak.py is the long version): repeated
calls leak no memory, file descriptors or threads; 8 threads calling register, register_batch and
register_point_clouds at once with mixed ``num_threads`` get the serial results, finish, and
never hold more threads than the pool cache's budget plus the pools of the calls running."""

from __future__ import annotations

import gc
import os
import random
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pointclm
import pytest
from pointclm.batch import registration_record, without_timings
from pointclm.datasets import load_shape, make_scene

pytestmark = pytest.mark.skipif(
    not Path("/proc/self/statm").exists(), reason="reads memory and threads from Linux's /proc"
)

CORES = os.cpu_count() or 1
#: Threads the core's pool cache keeps at most (rust/pointclm-py/src/pools.rs).
CACHE_BUDGET = max(2 * CORES, 64)
THREAD_COUNTS = (None, 1, 2, 3, 5, 8, 16, 64, 200)


def _rss() -> int:
    return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def _threads() -> int:
    return len(os.listdir("/proc/self/task"))


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q * np.linalg.det(q)  # a reflection turned into a rotation


@pytest.fixture(scope="module")
def inputs() -> dict[str, Any]:
    rng = np.random.default_rng(0)
    corrs = [make_scene(i, n_keep=n).correspondences for i, n in enumerate((100, 400, 1000))]
    model = load_shape("bunny", 300)
    d = float(np.linalg.norm(np.ptp(model, axis=0)))
    scans = [
        (model, np.vstack([model @ _rotation(rng).T + [(2 * j - 1) * d, 0, 0] for j in (0, 1)]))
        for _ in range(2)
    ]
    return {"corrs": corrs, "scans": scans}


def _mixed_calls(inputs: dict[str, Any], calls: int) -> None:
    """`calls` register calls (some learned, some refused, mixed thread counts) and a
    register_point_clouds call every 25."""
    rng = random.Random(0)
    for i in range(calls):
        n = rng.choice((None, 1, 2, 3, 4))
        if i % 25 == 24:
            model, scan = inputs["scans"][i % 2]
            pointclm.register_point_clouds(model, scan, seed=1, normals=bool(i % 2), num_threads=n)
        elif i % 50 == 13:
            with pytest.raises(ValueError, match="finite"):
                pointclm.register(np.full((50, 6), np.nan), num_threads=n)
        else:
            model = "default" if i % 10 == 3 else None
            pointclm.register(inputs["corrs"][i % 3], seed=i % 5, num_threads=n, model=model)


def test_repeated_calls_leak_no_memory_descriptors_or_threads(inputs: dict[str, Any]) -> None:
    # Warm-up: the pools, the network, and the allocator's per-thread arenas, which take a
    # few hundred calls with mixed thread counts to settle (then about +-2 % from one 200
    # calls to the next; a leak grows with every 200).
    for _ in range(2):
        _mixed_calls(inputs, 200)
    gc.collect()
    rss, fds, threads = _rss(), _fds(), _threads()
    for _ in range(2):
        _mixed_calls(inputs, 200)
    gc.collect()
    grown = (_rss() - rss) / rss
    assert grown < 0.05, f"resident memory grew {100 * grown:.1f} % over 400 calls"
    assert _fds() == fds
    # The cached pools change with the thread counts used last; never past the budget.
    assert _threads() <= threads + CACHE_BUDGET


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if hasattr(a, "labels"):
        return np.array_equal(a.labels, b.labels) and np.array_equal(
            a.transformations, b.transformations
        )
    return without_timings(registration_record(a, a.diagnosis)) == without_timings(
        registration_record(b, b.diagnosis)
    )


def test_eight_threads_at_once_get_the_serial_results_within_the_thread_bound(
    inputs: dict[str, Any],
) -> None:
    corrs, scans = inputs["corrs"], inputs["scans"]
    jobs: list[tuple[str, Any]] = [
        ("register", corrs[2]),
        ("register_batch", corrs),
        ("register_point_clouds", scans[0]),
        ("register", corrs[1]),
        ("register_point_clouds", scans[1]),
    ]

    def call(kind: str, arg: Any, num_threads: int | None) -> Any:
        if kind == "register_point_clouds":
            return pointclm.register_point_clouds(*arg, seed=4, num_threads=num_threads)
        return getattr(pointclm, kind)(arg, seed=4, num_threads=num_threads)

    serial = [call(kind, arg, 1) for kind, arg in jobs]
    before = _threads()
    lock = threading.Lock()
    in_flight: dict[int, int] = {}
    seen = {"peak": 0, "over": 0}
    stop = threading.Event()
    wrong: list[str] = []

    def sample() -> None:
        while not stop.is_set():
            with lock:
                now, flight = _threads(), sum(in_flight.values())
            # Python threads (those before, 8 callers, this one), the cache, the pools and
            # helper threads of the calls in flight; sampled under the lock so that no call
            # starts or ends between the two reads.
            seen["peak"] = max(seen["peak"], now)
            seen["over"] = max(seen["over"], now - (before + 9 + CACHE_BUDGET + flight))
            time.sleep(0.001)

    def caller(w: int) -> None:
        rng = random.Random(w)
        for k in rng.sample(range(len(jobs)), len(jobs)):
            n = rng.choice(THREAD_COUNTS)
            kind, arg = jobs[k]
            with lock:
                in_flight[w] = (n or CORES) + (kind == "register_point_clouds")
            got = call(kind, arg, n)
            with lock:
                in_flight[w] = 0
            if not _same(got, serial[k]):
                wrong.append(f"{kind} with num_threads={n}")

    watch = threading.Thread(target=sample, daemon=True)
    watch.start()
    callers = [threading.Thread(target=caller, args=(w,), daemon=True) for w in range(8)]
    for t in callers:
        t.start()
    for t in callers:
        t.join(timeout=300)
    stop.set()
    watch.join()
    assert not any(t.is_alive() for t in callers), "a caller did not finish: deadlock?"
    assert not wrong
    assert seen["over"] <= 0, f"{seen['over']} threads over the bound (peak {seen['peak']})"
    assert _threads() <= before + CACHE_BUDGET

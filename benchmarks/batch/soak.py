"""pointclm called for a long time and from many threads: memory, file descriptors and threads
after thousands of calls, and 8 threads calling at once with mixed ``num_threads``.

    python -m benchmarks.batch.soak [--quick] [soak] [concurrency]

- soak: 10,000 ``pointclm.register`` calls (``--quick``: 1,000) on synthetic scenes of 50 to
  2,000 correspondences (one call in 20 with the learned ``model="default"``, one in 100 on
  input it refuses, ``num_threads`` drawn from None, 1, 2, 3, 4, 8), interleaved with 200
  (20) ``pointclm.register_point_clouds`` calls on small scans (two posed copies of the
  bundled bunny at 300 to 600 points, every other one with ``normals=True``). Resident
  memory (``/proc/self/statm``), open file descriptors (``/proc/self/fd``) and live threads
  (``/proc/self/task``) are read after a warm-up of the first 20 % of the calls and at the
  end: memory must grow by less than 5 %, the descriptors not at all, and the threads stay
  within the pool cache's budget.
- concurrency: 8 Python threads, each running 24 (``--quick``: 8) calls of ``register``,
  ``register_batch`` and ``register_point_clouds`` in its own order, each with a
  ``num_threads`` drawn from None, 1, 2, 3, 5, 8, 16, 64, 200; every result compared with the
  same call made serially beforehand (same seed, ``num_threads=1``); each thread joined
  with a timeout (a deadlock fails); the live threads sampled every 2 ms, their peak
  compared with the bound the pool cache guarantees (see ``rust/pointclm-py/src/pools.rs``):
  the Python threads, plus ``max(2 x cores, 64)`` cached pool threads, plus the pools of the
  calls in flight (each call's ``num_threads``, the default pool's size for None), plus one
  helper thread per ``register_point_clouds`` call in flight.
"""

from __future__ import annotations

import argparse
import gc
import os
import platform
import random
import threading
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import pointclm
from pointclm.batch import registration_record, without_timings
from pointclm.datasets import load_shape, make_scene

PAGE = os.sysconf("SC_PAGE_SIZE")
CORES = os.cpu_count() or 1
SOAK_THREADS = (None, 1, 2, 3, 4, 8)
MIXED_THREADS = (None, 1, 2, 3, 5, 8, 16, 64, 200)
#: Threads the core's pool cache keeps at most (rust/pointclm-py/src/pools.rs).
CACHE_BUDGET = max(2 * CORES, 64)


def rss_mib() -> float:
    return int(Path("/proc/self/statm").read_text().split()[1]) * PAGE / 2**20


def fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def threads() -> int:
    return len(os.listdir("/proc/self/task"))


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q * np.linalg.det(q)  # a reflection turned into a rotation


def scans(count: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """(model, scan) pairs: the bunny at 300 to 600 points, two posed copies in the scan."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        model = load_shape("bunny", int(rng.choice([300, 400, 600])), i)
        d = float(np.linalg.norm(np.ptp(model, axis=0)))
        copies = [model @ _rotation(rng).T + [(2 * j - 1) * d, 0, 0] for j in range(2)]
        out.append((model, np.vstack(copies)))
    return out


def correspondences(count: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    sizes = rng.choice([50, 200, 500, 1000, 2000], size=count)
    return [make_scene(i, n_keep=int(n)).correspondences for i, n in enumerate(sizes)]


def same_result(a: Any, b: Any) -> bool:
    if isinstance(a, list):
        return len(a) == len(b) and all(same_result(x, y) for x, y in zip(a, b, strict=True))
    if hasattr(a, "labels"):
        return np.array_equal(a.labels, b.labels) and np.array_equal(
            a.transformations, b.transformations
        )
    return without_timings(registration_record(a, a.diagnosis)) == without_timings(
        registration_record(b, b.diagnosis)
    )


def soak(n_register: int, n_clouds: int) -> list[str]:
    """The calls interleaved (a register_point_clouds call every n_register / n_clouds
    register calls); measured after the first 20 % (the warm-up) and at the end."""
    rng = random.Random(0)
    corrs = correspondences(40)
    pairs = scans(10)
    bad = np.full((50, 6), np.nan)  # non-finite coordinates: an InputError every time
    total = n_register + n_clouds
    every = total // n_clouds
    warm_up = total // 5
    marks: dict[str, tuple[float, int, int]] = {"start": (rss_mib(), fds(), threads())}
    samples: list[float] = []
    errors = registers = clouds = 0
    t0 = time.perf_counter()
    for i in range(total):
        if i == warm_up:
            gc.collect()
            marks[f"after the warm-up ({i:,} calls)"] = (rss_mib(), fds(), threads())
        if i % (total // 10) == 0:
            samples.append(rss_mib())
        n = rng.choice(SOAK_THREADS)
        if i % every == every - 1 and clouds < n_clouds:
            model, scan = pairs[clouds % len(pairs)]
            pointclm.register_point_clouds(
                model, scan, seed=clouds % 3, normals=bool(clouds % 2), num_threads=n
            )
            clouds += 1
            continue
        kw: dict[str, Any] = {"seed": i % 7, "num_threads": n}
        if registers % 20 == 7:
            kw["model"] = "default"
        try:
            pointclm.register(bad if registers % 100 == 42 else rng.choice(corrs), **kw)
        except ValueError:
            errors += 1
        registers += 1
    elapsed = time.perf_counter() - t0
    gc.collect()
    marks["end"] = (rss_mib(), fds(), threads())
    samples.append(marks["end"][0])
    warm = list(marks.values())[1]
    growth = 100 * (marks["end"][0] - warm[0]) / warm[0]
    out = [
        f"## Soak: {registers:,} register and {clouds} register_point_clouds calls, "
        f"interleaved, in {elapsed:.0f} s ({errors} refused bad inputs)",
        "",
        "| when | resident MiB | open fds | threads |",
        "|---|---|---|---|",
        *[f"| {k} | {v[0]:.1f} | {v[1]} | {v[2]} |" for k, v in marks.items()],
        "",
        f"Resident memory after the warm-up to the end: {growth:+.2f} % (limit 5 %). Every "
        f"{total // 10:,} calls (MiB): " + ", ".join(f"{s:.0f}" for s in samples) + ". "
        f"Threads at the end: at most the caller plus the pool cache's {CACHE_BUDGET}.",
    ]
    assert growth < 5 and marks["end"][1] == warm[1], out
    assert marks["end"][2] <= 1 + CACHE_BUDGET, out
    return out


def concurrency(calls_per_thread: int) -> list[str]:
    corrs = correspondences(12, seed=1)
    pairs = scans(4, seed=1)
    jobs: list[tuple[str, Any]] = []
    for k in range(calls_per_thread):
        kind = ("register", "register_batch", "register_point_clouds")[k % 3]
        arg = (
            corrs[k % len(corrs)]
            if kind == "register"
            else [corrs[(k + j) % len(corrs)] for j in range(3)]
            if kind == "register_batch"
            else pairs[k % len(pairs)]
        )
        jobs.append((kind, arg))

    def call(kind: str, arg: Any, seed: int, num_threads: int | None) -> Any:
        if kind == "register_point_clouds":
            return pointclm.register_point_clouds(*arg, seed=seed, num_threads=num_threads)
        return getattr(pointclm, kind)(arg, seed=seed, num_threads=num_threads)

    t0 = time.perf_counter()
    serial = [call(kind, arg, 5, 1) for kind, arg in jobs]
    t_serial = time.perf_counter() - t0
    base = threads()
    peak, bound_peak = [base], [0]
    in_flight: dict[int, int] = {}
    lock = threading.Lock()
    stop = threading.Event()
    mismatches: list[str] = []

    def sampler() -> None:
        while not stop.is_set():
            now = threads()
            with lock:
                flight = sum(in_flight.values())
            peak[0] = max(peak[0], now)
            bound_peak[0] = max(bound_peak[0], flight)
            time.sleep(0.002)

    def worker(w: int) -> None:
        rng = random.Random(w)
        order = list(range(len(jobs)))
        rng.shuffle(order)
        for k in order:
            n = rng.choice(MIXED_THREADS)
            kind, arg = jobs[k]
            with lock:
                # The call's own pool (the default one is the machine's size), and the
                # helper thread register_point_clouds keeps beside it.
                in_flight[w] = (n or CORES) + (kind == "register_point_clouds")
            got = call(kind, arg, 5, n)
            with lock:
                in_flight[w] = 0
            if not same_result(got, serial[k]):
                mismatches.append(f"thread {w}: {kind} #{k} with num_threads={n}")

    watch = threading.Thread(target=sampler, daemon=True)
    watch.start()
    t0 = time.perf_counter()
    callers = [threading.Thread(target=worker, args=(w,), daemon=True) for w in range(8)]
    for t in callers:
        t.start()
    for t in callers:
        t.join(timeout=600)
    t_conc = time.perf_counter() - t0
    hung = sum(t.is_alive() for t in callers)
    stop.set()
    watch.join()
    after = threads()
    python_threads = base + 8 + 1  # main and what ran before, the 8 callers, the sampler
    bound = python_threads + CACHE_BUDGET + bound_peak[0]
    out = [
        f"## Concurrency: 8 threads x {calls_per_thread} calls of register, register_batch "
        f"(3 scenes) and register_point_clouds, num_threads from {MIXED_THREADS}",
        "",
        f"- serial ({len(jobs)} calls, num_threads=1): {t_serial:.1f} s; concurrent "
        f"({8 * len(jobs)} calls): {t_conc:.1f} s; threads still running after the timeout: "
        f"{hung}",
        f"- results different from the serial call: {len(mismatches)} of {8 * len(jobs)}",
        f"- live threads: {base} before, peak {peak[0]}, {after} after; the bound "
        f"(Python threads {python_threads} + cache {CACHE_BUDGET} + largest sum of the pools "
        f"of calls in flight {bound_peak[0]}) is {bound}",
    ]
    assert not hung and not mismatches and peak[0] <= bound, out + mismatches
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("parts", nargs="*", default=["soak", "concurrency"])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    lines = [
        f"{platform.processor() or platform.machine()}, {CORES} CPUs, Python "
        f"{platform.python_version()}, {datetime.now(timezone.utc):%Y-%m-%d}",
        "",
    ]
    if "soak" in args.parts:
        lines += soak(1_000 if args.quick else 10_000, 20 if args.quick else 200) + [""]
    if "concurrency" in args.parts:
        lines += concurrency(8 if args.quick else 24)
    print("\n".join(lines))


if __name__ == "__main__":
    main()

"""What unusual loads cost: a large unused ``.npz`` member, many thread counts, and the learned
embedding on many consistent correspondences.

    python -m benchmarks.batch.load_limits [npz] [threads] [learned]

- npz: an archive of 1,000 points and a 1 GB float64 member of zeros (about 1 MB on disk),
  named ``extra`` (not used), ``normals`` and ``colors`` (refused: not the points' shape);
  each read by ``pointclm.io.read_point_cloud`` in a fresh process, whose peak resident
  memory is printed beside that of the same process before the read.
- threads: ``pointclm.register`` on 200 correspondences with ``num_threads`` = 1, 2, ..., 200
  in turn, in a fresh process; the threads alive (``/proc/self/task``) before the loop and
  as soon as it returns.
- learned: ``pointclm.register(..., model="default")`` on N uniform random correspondences
  in the synthetic scenes' extent (most pairs length-consistent, so the network's dense
  attention would run); the time until it returns or refuses, and the message.

Every case runs in its own process so that one does not inherit another's memory or threads.
"""

from __future__ import annotations

import io
import subprocess
import sys
import tempfile
import textwrap
import zipfile
from pathlib import Path

import numpy as np


def _run(code: str, timeout: float = 600) -> str:
    r = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    if r.returncode != 0:
        raise RuntimeError(r.stderr)
    return r.stdout.strip()


def _archive(path: Path, name: str, nbytes: int) -> None:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        buf = io.BytesIO()
        np.save(buf, np.random.default_rng(0).uniform(size=(1000, 3)))
        z.writestr("points.npy", buf.getvalue())
        with z.open(f"{name}.npy", "w", force_zip64=True) as fh:
            header = io.BytesIO()
            np.lib.format.write_array_header_1_0(
                header, {"descr": "<f8", "fortran_order": False, "shape": (nbytes // 8,)}
            )
            fh.write(header.getvalue())
            chunk = bytes(8 << 20)
            for _ in range(nbytes // len(chunk)):
                fh.write(chunk)


def npz() -> None:
    print("## npz: 1,000 points and a 1 GB member of zeros")
    print("| member | file | peak RSS before read | peak RSS after read | time | result |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("extra", "normals", "colors"):
            path = Path(tmp) / f"{name}.npz"
            _archive(path, name, 1 << 30)
            out = _run(f"""
                import resource, time
                from pointclm.io import read_point_cloud
                before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
                t = time.perf_counter()
                try:
                    result = f"{{len(read_point_cloud({str(path)!r}))}} points"
                except ValueError as e:
                    result = "ValueError: " + str(e).split(": ", 1)[1]
                dt = time.perf_counter() - t
                after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
                print(before // 1024, after // 1024, f"{{dt:.2f}}", result, sep="|")
            """)
            before, after, dt, result = out.split("|", 3)
            size = path.stat().st_size / 1e6
            print(f"| `{name}` | {size:.1f} MB | {before} MB | {after} MB | {dt} s | {result} |")


def threads() -> None:
    print("## threads: register with num_threads = 1..200 in turn")
    out = _run("""
        import os, time, numpy as np, pointclm
        scene = np.random.default_rng(0).uniform(size=(200, 6))
        before = len(os.listdir("/proc/self/task"))
        t = time.perf_counter()
        for n in range(1, 201):
            pointclm.register(scene, num_threads=n)
        dt = time.perf_counter() - t
        print(before, len(os.listdir("/proc/self/task")), f"{dt:.1f}")
    """)
    before, after, dt = out.split()
    print(f"threads alive before: {before}, right after the 200 calls: {after} ({dt} s in all)")


def learned(sizes: tuple[int, ...] = (8_000, 32_768, 50_000)) -> None:
    print("## learned: register(model='default') on N random correspondences")
    print("| N | time | result |")
    print("|---|---|---|")
    for n in sizes:
        out = _run(f"""
            import time, numpy as np, pointclm
            rng = np.random.default_rng(0)
            c = rng.uniform(-0.5, 0.5, size=({n}, 6))
            t = time.perf_counter()
            try:
                r = pointclm.register(c, model="default")
                result = f"{{len(r.instances)}} instances"
            except ValueError as e:
                result = "ValueError: " + str(e)
            print(f"{{time.perf_counter() - t:.2f}}|{{result}}")
        """)
        dt, result = out.split("|", 1)
        print(f"| {n:,} | {dt} s | {result} |")


if __name__ == "__main__":
    cases = {"npz": npz, "threads": threads, "learned": learned}
    for name in sys.argv[1:] or list(cases):
        cases[name]()

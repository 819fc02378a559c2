"""What Open3D input costs: the check every array now passes through, reading Open3D clouds,
and a registration from Open3D objects against the same one from arrays.

    python -m benchmarks.interop.conversions [--points 1000000] [--repeats 5]

Prints a Markdown table (best of `--repeats`). Needs open3d (``pip install ".[test]"``).
"""

from __future__ import annotations

import argparse
import platform
import timeit
from collections.abc import Callable
from datetime import datetime, timezone
from typing import Any

import numpy as np
import pointclm
from pointclm.interop.open3d import from_open3d, open3d_points
from pointclm.preprocessing import as_points


def best(fn: Callable[[], Any], repeats: int, number: int = 1) -> float:
    # Microsecond calls are timed in batches of `number`: one call is below the clock's noise.
    """Seconds of one call of `fn`, the fastest of `repeats` runs of `number` calls."""
    return min(timeit.repeat(fn, number=number, repeat=repeats)) / number


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000, help="points of the read clouds")
    ap.add_argument("--repeats", type=int, default=5, help="runs; the fastest counts")
    args = ap.parse_args()
    import open3d as o3d

    rng = np.random.default_rng(0)
    small = rng.normal(size=(100, 3))
    big = rng.normal(size=(args.points, 3))
    legacy = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(big))
    legacy.normals = o3d.utility.Vector3dVector(big)
    tensor = o3d.t.geometry.PointCloud(o3d.core.Tensor(big.astype(np.float32)))
    n, r = f"{args.points:,} pts", args.repeats
    rows = [
        ("Open3D check of a non-Open3D argument", best(lambda: open3d_points(small), 5, 100_000)),
        (
            "as_points of a (100, 3) array, check included",
            best(lambda: as_points(small, "p"), 5, 10_000),
        ),
        (f"from_open3d, legacy cloud with normals, {n}", best(lambda: from_open3d(legacy), r)),
        (f"from_open3d, tensor cloud (float32), {n}", best(lambda: from_open3d(tensor), r)),
    ]
    rows += _registrations(o3d, args.repeats)
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    print(f"{stamp}, {platform.machine()}, numpy {np.__version__}, open3d {o3d.__version__}\n")
    print("| what | time |\n|---|---|")
    for name, seconds in rows:
        shown = f"{seconds * 1e6:.2f} us" if seconds < 1e-3 else f"{seconds * 1e3:.1f} ms"
        print(f"| {name} | {shown} |")


def _registrations(o3d: Any, repeats: int) -> list[tuple[str, float]]:
    """`register_point_clouds` on two copies of the bundled bunny, from arrays and from Open3D
    clouds (the poses must agree bit for bit)."""
    from pointclm.datasets import load_shape

    model = load_shape("bunny", 3000)
    turned = model @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).T
    scan = np.vstack([model, turned + [4.0, 0.0, 0.0]])
    clouds = [o3d.geometry.PointCloud(o3d.utility.Vector3dVector(a)) for a in (model, scan)]
    poses = []

    def run(inputs: tuple[Any, Any]) -> Callable[[], None]:
        return lambda: poses.append(pointclm.register_point_clouds(*inputs).transformations)

    arrays = best(run((model, scan)), repeats)
    objects = best(run((clouds[0], clouds[1])), repeats)
    if not all(np.array_equal(poses[0], p) for p in poses):
        raise SystemExit("the poses from Open3D clouds differ from those from arrays")
    return [
        ("register_point_clouds, two bunnies, arrays", arrays),
        ("register_point_clouds, two bunnies, Open3D clouds (same poses)", objects),
    ]


if __name__ == "__main__":
    main()

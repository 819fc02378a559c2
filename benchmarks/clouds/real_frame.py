"""`register_point_clouds` on a real depth frame: PCL's correspondence-grouping tutorial scene
(a Kinect frame of a table with a milk carton among other objects, in the sensor's frame) and
its carton model, which was cut from the frame, so the carton's true pose is the identity.

The model is moved by `--motions` random rigid motions (rotation uniform, translation about a
metre; seeds 0, 1, ...), so the answer is each motion's inverse; every motion is registered
without a viewpoint and with the sensor's position (the origin), and once more without a
viewpoint with the frame itself moved by another random rigid motion (seeds 100, 101, ...), as
a scan exported to a world frame comes: the sensor is then not at the origin (the frame, a
metre or two away, still looks like one view from the origin, which is guessed and confirmed:
a known limit). A pose is right within 5 degrees and 2 cm. Reports, per setting: motions where
the carton was found, right poses first, wrong poses in all, and the median time.

    python -m benchmarks.clouds.real_frame [--motions 12] [--data-dir ../shared/data]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pointclm
from pointclm.io.reader import load_points
from scipy.spatial.transform import Rotation

from benchmarks.clouds.scenes import data_folder


def _right(found: np.ndarray, truth: np.ndarray) -> bool:
    d = np.linalg.inv(truth) @ found
    angle = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
    return bool(angle < 5.0 and np.linalg.norm(d[:3, 3]) < 0.02)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--motions", type=int, default=12)
    ap.add_argument("--data-dir", default=None, help="default: $POINTCLM_DATA_DIR or ../shared")
    args = ap.parse_args()
    data = Path(data_folder(args.data_dir))
    model = load_points(data / "pcl/milk.pcd")
    scan = load_points(data / "pcl/milk_cartoon_all_small_clorox.pcd")
    print(f"model {len(model)} points, frame {len(scan)} points, {args.motions} motions")
    print("\n| viewpoint | carton found | right pose first | wrong poses | median s |")
    print("|---|---|---|---|---|")
    for viewpoint, world in ((None, False), ((0.0, 0.0, 0.0), False), (None, True)):
        found = first = wrong = 0
        times = []
        for seed in range(args.motions):
            m = np.eye(4)
            m[:3, :3] = Rotation.random(random_state=seed).as_matrix()
            m[:3, 3] = np.random.default_rng(seed).normal(size=3)
            frame = np.eye(4)  # the frame's own motion into a world frame
            if world:
                frame[:3, :3] = Rotation.random(random_state=100 + seed).as_matrix()
                frame[:3, 3] = np.random.default_rng(100 + seed).normal(size=3)
            truth = frame @ np.linalg.inv(m)
            t = time.perf_counter()
            moved = model @ m[:3, :3].T + m[:3, 3]
            seen = scan @ frame[:3, :3].T + frame[:3, 3]
            r = pointclm.register_point_clouds(moved, seen, viewpoint=viewpoint)
            times.append(time.perf_counter() - t)
            right = [_right(np.asarray(p), truth) for p in r.transformations]
            found += any(right)
            first += bool(right) and right[0]
            wrong += len(right) - sum(right)
        label = "the sensor's (origin)" if viewpoint is not None else "none"
        label += ", frame moved to a world frame" if world else ""
        print(
            f"| {label} | {found} / {args.motions} | {first} / {args.motions} | {wrong} | "
            f"{np.median(times):.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()

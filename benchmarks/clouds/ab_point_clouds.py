"""Two builds of pointclm compared on `point_cloud_speed`'s scenes: same poses, and time.

    python -m benchmarks.clouds.ab_point_clouds BUILD_A BUILD_B [--rounds 4] [--no-viewpoint]
        [--scenes-per-model 2] [--threads 2] [--cache DIR]

BUILD_A and BUILD_B are checkouts of the repository, each with its extension built
(``python/pointclm/_core.abi3.so``). Why interleaved rounds: on a shared machine the load
moves by 10-20 % between minutes, more than most speed-ups, so each round runs every scene
once with each build in turn (alternating which goes first), and the summary takes each
scene's fastest call per build. A fresh interpreter per build and round keeps the two
extensions apart. Prints the per-round medians, the median over scenes of each scene's
fastest call, and whether every pose (to 1e-9) is the same.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from benchmarks.common.report import ROOT

_ONE_ROUND = r"""
import json, sys, time
import numpy as np
import pointclm
from benchmarks.clouds.point_cloud_speed import speed_scenes
per, threads, cache, blind = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4] == "1"
scenes = speed_scenes(per, cache)
def call(sc):
    view = None if blind else sc.viewpoint
    return pointclm.register_point_clouds(
        sc.source_points, sc.target_points, sc.voxel_size, viewpoint=view, num_threads=threads
    )
call(scenes[0])  # warm-up
times, poses = [], []
for sc in scenes:
    t = time.perf_counter()
    r = call(sc)
    times.append(time.perf_counter() - t)
    poses.append(np.asarray(r.transformations).round(9).tolist())
print(json.dumps([times, poses]))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("builds", nargs=2, help="two repository checkouts, each built")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--no-viewpoint", action="store_true", help="call without the sensor")
    ap.add_argument("--scenes-per-model", type=int, default=2)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--cache", default="out/realistic_scenes")
    args = ap.parse_args()
    times: dict[str, list[np.ndarray]] = {b: [] for b in args.builds}
    poses: dict[str, list] = {}
    for r in range(args.rounds):
        for build in args.builds if r % 2 == 0 else args.builds[::-1]:
            env = dict(os.environ, PYTHONPATH=str(Path(build) / "python"))
            argv = [str(args.scenes_per_model), str(args.threads), args.cache]
            argv.append("1" if args.no_viewpoint else "0")
            out = subprocess.run(
                [sys.executable, "-c", _ONE_ROUND, *argv],
                env=env,
                cwd=ROOT,
                capture_output=True,
                text=True,
                check=True,
            )
            t, p = json.loads(out.stdout)
            times[build].append(np.asarray(t))
            poses.setdefault(build, p)
    for build in args.builds:
        rounds = [round(float(np.median(t)), 3) for t in times[build]]
        fastest = float(np.median(np.min(np.stack(times[build]), axis=0)))
        print(f"{build}: medians per round {rounds}, each scene's fastest {fastest:.3f} s (median)")
    a, b = (poses[x] for x in args.builds)
    differ = [i for i in range(len(a)) if a[i] != b[i]]
    print(f"same poses in every scene: {not differ}" + (f" (differ: {differ})" if differ else ""))


if __name__ == "__main__":
    main()

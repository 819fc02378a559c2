"""Time of `register_point_clouds` per scene and per stage.

    python -m benchmarks.clouds.point_cloud_speed [--scenes-per-model 2] [--threads 2] [--runs 2]
        [--cache DIR] [--out FILE]

Scenes: the held-out models' realistic benchmark scenes (``realistic_models``'s
``benchmark_seeds``; a scan of about 23k points after downsampling, a model of about 1.8k),
with their sensor position. Each run calls ``register_point_clouds(..., viewpoint=,
num_threads=)`` once per scene, after one warm-up call; the table gives the median over the
scenes of the wall time and of each stage of ``result.timings`` (stage medians do not add up
to the wall median). ``--runs`` repeats the whole loop, so that a load spike on a shared
machine shows as a run apart.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from benchmarks.clouds.scenes import benchmark_seeds, load_scenes, scene_params
from benchmarks.common import report


def speed_scenes(per_model: int, cache: str | Path) -> list:
    """The held-out models' benchmark scenes timed here, `per_model` each (built into `cache`
    the first time)."""
    from pointclm.datasets.scenes import HELDOUT_MODELS, default_data_dir

    data_dir = default_data_dir()
    if data_dir is None:
        raise SystemExit("the data folder is missing: set POINTCLM_DATA_DIR")
    jobs = [
        (m, s, scene_params(m, 1000, str(data_dir)))
        for m in HELDOUT_MODELS
        for s in benchmark_seeds(m, per_model)
    ]
    return load_scenes(jobs, Path(cache), os.cpu_count() or 1, progress=False)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes-per-model", type=int, default=2)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--cache", default="out/realistic_scenes")
    ap.add_argument("--out")
    ap.add_argument("--descriptor", default="auto", help="auto, fpfh, fpfh+learned, ...")
    args = ap.parse_args()

    import pointclm

    scenes = speed_scenes(args.scenes_per_model, args.cache)

    def call(sc):
        return pointclm.register_point_clouds(
            sc.source_points,
            sc.target_points,
            sc.voxel_size,
            viewpoint=sc.viewpoint,
            num_threads=args.threads,
            descriptor=args.descriptor,
        )

    call(scenes[0])
    rows = []
    for run in range(args.runs):
        walls, stages = [], {}
        for sc in scenes:
            t = time.perf_counter()
            result = call(sc)
            walls.append(time.perf_counter() - t)
            for k, v in result.timings.items():
                stages.setdefault(k, []).append(v)
        rows.append(
            (run, float(np.median(walls)), {k: float(np.median(v)) for k, v in stages.items()})
        )

    shown = [k for k, v in rows[0][2].items() if k != "total" and v >= 0.001]
    lines = [
        "# `register_point_clouds` time per scene",
        "",
        f"- Date: {report.utc_now()}. Command: `{report.command(__spec__.name)}`.",
        f"- Hardware: {report.hardware()}; pointclm {pointclm.__version__} "
        f"(git {report.git_commit()}), {args.threads} threads, "
        f"descriptor={args.descriptor!r}.",
        f"- {len(scenes)} held-out scenes; median scan "
        f"{int(np.median([len(s.target_points) for s in scenes]))} raw points.",
        "",
        "| run | median wall s | " + " | ".join(shown) + " |",
        "|---|---|" + "---|" * len(shown),
    ]
    for run, wall, st in rows:
        lines.append(
            f"| {run + 1} | {wall:.3f} | " + " | ".join(f"{st[k]:.3f}" for k in shown) + " |"
        )
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        Path(args.out).write_text(text)


if __name__ == "__main__":
    main()

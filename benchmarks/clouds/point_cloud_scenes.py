"""`register_point_clouds` end to end on the realistic scenes: clouds in, poses out.

    python -m benchmarks.clouds.point_cloud_scenes [--models heldout|validation]
        [--scenes-per-model 4] [--variant "peel=False" ...] [--cache DIR]

Each scene of ``realistic_models`` (N = 1000 parameters, the same seeds: benchmark seeds
for the held-out models, threshold-sweep seeds for the validation ones) is registered from its
clouds alone: ``register_point_clouds(scene.source_points, scene.target_points,
voxel_size=scene.voxel_size, viewpoint=scene.viewpoint, num_threads=1, **variant)``, so FPFH,
matching, the correspondence stage, peeling, ICP and visibility verification all run. A
variant is a comma-separated list of keyword arguments ("" is the defaults). Scored as the
realistic benchmark scores (RE < 15 deg, TE < the scene's bound, one prediction per copy):
per model and pooled, correct / predicted / copies, precision, recall, F1, median seconds.
``--sensor-frame`` registers each scan moved into its sensor's frame (the sensor at the
origin) with no viewpoint, as a depth camera's frames come, and moves the poses back to score.
"""

from __future__ import annotations

import argparse
import ast
import time
from pathlib import Path
from typing import Any

import numpy as np


def parse_variant(text: str) -> dict[str, Any]:
    """``"mutual=False,n_samples=None"`` -> keyword arguments (literals only)."""
    out: dict[str, Any] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        key, _, value = part.partition("=")
        out[key.strip()] = ast.literal_eval(value.strip())
    return out


def main() -> None:
    import pointclm
    from pointclm.metrics import score_scene

    from benchmarks.clouds.scenes import cloud_scenes, data_folder

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--models", default="heldout", choices=("heldout", "validation"))
    ap.add_argument("--scenes-per-model", type=int, default=4)
    ap.add_argument("--variant", action="append", default=None, help='e.g. "peel=False"')
    ap.add_argument("--cache", default="out/realistic_scenes")
    ap.add_argument("--data-dir", default=None, help="default: $POINTCLM_DATA_DIR or ../shared")
    ap.add_argument(
        "--sensor-frame",
        action="store_true",
        help="scans in their sensor's frame, no viewpoint given (a depth camera's output)",
    )
    args = ap.parse_args()
    data_dir = data_folder(args.data_dir)
    scenes = cloud_scenes(args.models, args.scenes_per_model, Path(args.cache), data_dir)
    models = list(dict.fromkeys(sc.model for sc in scenes))
    print(f"{len(scenes)} scenes of {', '.join(models)}", flush=True)
    for text in args.variant or ["", "peel=False"]:
        kw = parse_variant(text)
        per: dict[str, list[tuple[int, int, int]]] = {}
        times = []
        for sc in scenes:
            t = time.perf_counter()
            # The scan in its sensor's frame (moved so that the sensor is at the origin), no
            # viewpoint given; the poses are moved back to score.
            shift = np.asarray(sc.viewpoint) if args.sensor_frame else np.zeros(3)
            r = pointclm.register_point_clouds(
                sc.source_points,
                sc.target_points - shift,
                voxel_size=sc.voxel_size,
                num_threads=1,
                **{"viewpoint": None if args.sensor_frame else sc.viewpoint, **kw},
            )
            times.append(time.perf_counter() - t)
            poses = np.array(r.transformations).reshape(-1, 4, 4)
            poses[:, :3, 3] += shift
            s = score_scene(poses, sc.poses, 15.0, sc.max_translation)
            per.setdefault(sc.model, []).append((s.n_matched, s.n_pred, s.n_gt))
        print(f"\n### `{text or 'defaults'}`: median {np.median(times):.2f} s / scene\n")
        print("| model | correct / predicted / copies | precision | recall | F1 |")
        print("|---|---|---|---|---|")
        rows = [(m, np.sum(v, axis=0)) for m, v in per.items()]
        rows.append(("**pooled**", np.sum([r for _, r in rows], axis=0)))
        for name, (c, p, g) in rows:
            prec, rec = c / max(p, 1), c / max(g, 1)
            f1 = 2 * prec * rec / max(prec + rec, 1e-12)
            print(f"| {name} | {c} / {p} / {g} | {prec:.3f} | {rec:.3f} | {f1:.3f} |", flush=True)


if __name__ == "__main__":
    main()

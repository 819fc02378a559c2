"""Verification started from the truth: the share of visible copies that `refine_poses` keeps
when given their exact poses, and the rule that rejects each one it does not keep.

    python -m benchmarks.clouds.exact_poses [--seeds 3] [--min-visible 0.3] [--out FILE]

A right pose that verification rejects is lost whatever the correspondence stage proposes, so
this is the ceiling of recall on each kind of scene. Scenes: bins of 20-80 copies of procedural
boxes, fandisk and dragon under the bin's structured-light sensor (copies at least
``--min-visible`` visible), and realistic scenes of the held-out models, each with its sensor.
The clouds are described at the scene's voxel as `register_point_clouds` describes them
(normals and FPFH, the scan's normals towards the sensor; stray points are not dropped); the
poses are refined by ICP and verified with the default rules (`RefinementContext.refine` and
`.rejections`).
"""

from __future__ import annotations

import argparse
import datetime
import platform
from collections import Counter
from pathlib import Path

import numpy as np


def _bins(seeds: int, min_visible: float):
    from pointclm.datasets.bins import BinParams, make_bin_scene

    for model in ("box", "common3d/fandisk", "stanford/dragon"):
        for seed in range(seeds):
            sc = make_bin_scene(seed, BinParams(model=model))
            seen = sc.visible_fraction >= min_visible
            yield f"bin {model}", sc.model_points, sc.scan, sc.poses[seen], sc.sensor, sc.voxel_size


def _realistic(seeds: int):
    from pointclm.datasets.scenes import HELDOUT_MODELS, SceneParams, make_realistic_scene

    for model in HELDOUT_MODELS:
        for seed in range(seeds):
            sc = make_realistic_scene(seed, SceneParams(model=model))
            if sc.viewpoint is not None:
                clouds = (sc.source_points, sc.target_points)
                yield f"realistic {model}", *clouds, sc.poses, sc.viewpoint, sc.voxel_size


def judged(
    model: np.ndarray, scan: np.ndarray, poses: np.ndarray, sensor: np.ndarray, voxel: float
):
    """(kept, rejections) of the exact `poses` against the clouds described at `voxel`."""
    import pointclm.preprocessing as pp
    from pointclm.refinement import RefinementContext

    src = pp.describe(model, voxel, away_from=model.mean(0))
    tgt = pp.describe(scan, voxel, towards=sensor)
    context = RefinementContext(
        src.points, tgt.points, voxel, viewpoint=sensor, target_normals=tgt.normals
    )
    kept = context.refine(poses)
    return len(kept.origin), context.rejections(poses)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--min-visible", type=float, default=0.3)
    ap.add_argument("--out")
    args = ap.parse_args()
    cells: dict[str, list[int]] = {}
    rules: dict[str, Counter] = {}
    jobs = [*_bins(args.seeds, args.min_visible), *_realistic(args.seeds)]
    for name, model, scan, poses, sensor, voxel in jobs:
        kept, rejected = judged(model, scan, poses, sensor, voxel)
        tally = cells.setdefault(name, [0, 0])
        tally[0] += kept
        tally[1] += len(poses)
        rules.setdefault(name, Counter()).update(r.rule for r in rejected)
    lines = [
        f"# Exact poses kept by verification ({datetime.date.today()}, {platform.machine()})",
        "",
        "| scenes | copies | kept | keep rate | rejected by |",
        "|---|---|---|---|---|",
    ]
    for name, (kept, total) in cells.items():
        why = ", ".join(f"{rule} {n}" for rule, n in rules[name].most_common()) or "-"
        lines.append(f"| {name} | {total} | {kept} | {kept / max(total, 1):.3f} | {why} |")
    kept = sum(k for k, _ in cells.values())
    total = sum(t for _, t in cells.values())
    pooled = sum(rules.values(), Counter())
    why = ", ".join(f"{rule} {n}" for rule, n in pooled.most_common()) or "-"
    lines.append(f"| pooled | {total} | {kept} | {kept / max(total, 1):.3f} | {why} |")
    text = "\n".join(lines) + "\n"
    if args.out:
        Path(args.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()

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

A pose that would still fit slid along its face is not kept as a copy but returned apart, as an
ambiguity (``RefinedPoses.sliding``, ``PointCloudRegistration.ambiguous``): the caller gets it,
less sure, and the scan cannot say where along the face the copy lies. Such a pose is not lost:
the keep rate counts copies kept or returned as ambiguous; the copies-only rate is shown beside
it, and the rejections of ambiguous poses are named ``sliding (ambiguous)``.
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
    """(kept, returned as ambiguous, rejections) of the exact `poses` against the clouds
    described at `voxel`."""
    import pointclm.preprocessing as pp
    from pointclm.refinement import RefinementContext

    src = pp.describe(model, voxel, away_from=model.mean(0))
    tgt = pp.describe(scan, voxel, towards=sensor)
    context = RefinementContext(
        src.points, tgt.points, voxel, viewpoint=sensor, target_normals=tgt.normals
    )
    kept = context.refine(poses)
    sliding = set() if kept.sliding is None else set(kept.sliding.origin.tolist())
    rejected = [
        r._replace(rule="sliding (ambiguous)") if r.origin in sliding else r
        for r in context.rejections(poses)
    ]
    return len(kept.origin), len(sliding), rejected


def _row(name: str, tally: list[int], rules: Counter) -> str:
    """A table row: `tally` is (kept, ambiguous, copies)."""
    kept, ambiguous, total = tally
    why = ", ".join(f"{rule} {n}" for rule, n in rules.most_common()) or "-"
    rate, copies = (kept + ambiguous) / max(total, 1), kept / max(total, 1)
    return f"| {name} | {total} | {kept} | {ambiguous} | {rate:.3f} | {copies:.3f} | {why} |"


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
        kept, ambiguous, rejected = judged(model, scan, poses, sensor, voxel)
        tally = cells.setdefault(name, [0, 0, 0])
        tally[0] += kept
        tally[1] += ambiguous
        tally[2] += len(poses)
        rules.setdefault(name, Counter()).update(r.rule for r in rejected)
    lines = [
        f"# Exact poses kept by verification ({datetime.date.today()}, {platform.machine()})",
        "",
        "| scenes | copies | kept | ambiguous | keep rate | copies only | rejected by |",
        "|---|---|---|---|---|---|---|",
    ]
    pooled = [0, 0, 0]
    for name, tally in cells.items():
        pooled = [a + b for a, b in zip(pooled, tally, strict=True)]
        lines.append(_row(name, tally, rules[name]))
    lines.append(_row("pooled", pooled, sum(rules.values(), Counter())))
    text = "\n".join(lines) + "\n"
    if args.out:
        Path(args.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()

"""The loose-fit rule under noise that grows with range: does it drop far copies?

`register_point_clouds` drops, among three or more poses judged by the sensor, those whose
visible side fits the scan more than 1.3 times as loosely as the median pose's
(`pointclm.refinement.loose_poses`). A depth sensor's noise grows with range (as z^2 for
structured light and stereo), so copies far from it fit looser than near ones. This adds
Gaussian noise of ``a * (range / median range)^e`` model voxels to each scan point of the
realistic scenes (``point_cloud_scenes``'s) and registers each with its sensor position,
the rule on and off; it reports correct / predicted / copies and F1 for both, and the spread
of the copies' ranges (farthest / nearest centre). A larger ``e`` stands for a wider spread
of ranges than the scenes hold: their copies lie within 1.14-1.46 of each other's range, so
``e = 6`` gives far copies up to 10 times the noise of near ones, as z^2 noise over a
threefold range would.

    python -m benchmarks.clouds.range_noise [--models validation] [--scenes-per-model 3]
                                     [-a 0.2] [-e 6] [--cache DIR]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pointclm
import pointclm.point_clouds as pc
from pointclm.metrics import score_scene

from benchmarks.clouds.scenes import cloud_scenes, data_folder


def _never_loose(visible_rmse: object, *args: object, **kwargs: object) -> np.ndarray:
    return np.zeros(len(np.asarray(visible_rmse)), dtype=bool)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--models", default="validation")
    ap.add_argument("--scenes-per-model", type=int, default=3)
    ap.add_argument("-a", type=float, default=0.2, help="noise at the median range, voxels")
    ap.add_argument("-e", type=float, default=6.0, help="exponent of the range")
    ap.add_argument("--cache", default="out/realistic_scenes")
    args = ap.parse_args()
    scenes = cloud_scenes(args.models, args.scenes_per_model, Path(args.cache), data_folder(None))
    rule = pc.loose_poses
    totals = {"rule on": np.zeros(3, int), "rule off": np.zeros(3, int)}
    spreads = []
    try:
        for sc in scenes:
            eye = np.asarray(sc.viewpoint, dtype=np.float64)
            ranges = np.linalg.norm(sc.target_points - eye, axis=1)
            sigma = args.a * (ranges / np.median(ranges)) ** args.e * sc.voxel_size
            noise = np.random.default_rng(0).normal(size=sc.target_points.shape)
            scan = sc.target_points + noise * sigma[:, None]
            centres = np.linalg.norm(sc.poses[:, :3, 3] - eye, axis=1)
            spreads.append(centres.max() / centres.min())
            for name in totals:
                pc.loose_poses = rule if name == "rule on" else _never_loose  # type: ignore[assignment]
                reg = pointclm.register_point_clouds(sc.source_points, scan, viewpoint=sc.viewpoint)
                s = score_scene(reg.transformations, sc.poses, 15.0, sc.max_translation)
                totals[name] += [s.n_matched, s.n_pred, s.n_gt]
    finally:
        pc.loose_poses = rule
    print(f"{len(scenes)} scenes; noise {args.a} voxel x (range / median)^{args.e:g}")
    print(f"copies' range spread (farthest / nearest): {min(spreads):.2f}-{max(spreads):.2f}")
    print("| rule | correct / predicted / copies | F1 |")
    print("|---|---|---|")
    for name, (hit, pred, gt) in totals.items():
        f1 = 2 * hit / max(pred + gt, 1)
        print(f"| {name} | {hit} / {pred} / {gt} | {f1:.3f} |")


if __name__ == "__main__":
    main()

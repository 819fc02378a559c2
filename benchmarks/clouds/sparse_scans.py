"""`register_point_clouds` on sparser or noisier sensors: the realistic scenes with their scans
thinned (``--fractions``) or with Gaussian noise added (``--noise``, in model voxels).

Each scene of ``realistic_models`` (as ``point_cloud_scenes`` builds them: benchmark
seeds for the held-out models, threshold seeds for the validation ones) keeps a random share
of its scan points (``--fractions``; seed 0), as a sensor of lower resolution would see it,
and is registered with the default voxel (``voxel_size`` not given) and the sensor's position
(``--no-viewpoint``: without it, the scan in the scene's frame).
Reports per share: correct / predicted / copies, precision, recall and F1 pooled over the
models (RE < 15 deg, TE < the scene's bound), and the median scan spacing in model voxels
(the model's diagonal / 40). A scan that leaves too few matches gives an empty result: no pose.

    python -m benchmarks.clouds.sparse_scans [--models heldout|validation] [--scenes-per-model 2]
                                      [--fractions 1,0.3,0.1,0.03] [--noise 0.25,0.5]
                                      [--outliers 0.05,0.2] [--cache DIR]

``--noise s1,s2,...`` adds, after the fractions' rows, one row per standard deviation (in
model voxels, the model's diagonal / 40; seed 0) of noise added to every full scan's points.
``--outliers o1,o2,...`` adds one row per share of stray points (flying pixels, multipath)
added to every full scan: that many times its point count, uniform in its bounding box
(seed 0).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pointclm
from pointclm.metrics import score_scene
from pointclm.point_clouds import VOXELS_PER_DIAGONAL

from benchmarks.clouds.scenes import cloud_scenes, data_folder


def _spacing(points: np.ndarray) -> float:
    """Median distance to the nearest other point (as `preprocessing.point_spacing`, which
    older builds compared here lack)."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(points).query(points[:: max(1, len(points) // 5000)], k=2)
    return float(np.median(d[:, 1]))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--models", default="heldout", choices=("heldout", "validation"))
    ap.add_argument("--scenes-per-model", type=int, default=2)
    ap.add_argument("--fractions", default="1,0.3,0.1,0.03")
    ap.add_argument("--noise", default="", help="noise rows: standard deviations in voxels")
    ap.add_argument("--outliers", default="", help="stray-point rows: shares of the scan")
    ap.add_argument("--cache", default="out/realistic_scenes")
    ap.add_argument("--data-dir", default=None, help="default: $POINTCLM_DATA_DIR or ../shared")
    ap.add_argument(
        "--no-viewpoint",
        action="store_true",
        help="register without the sensor's position (the scan stays in the scene's frame)",
    )
    args = ap.parse_args()
    data_dir = data_folder(args.data_dir)
    scenes = cloud_scenes(args.models, args.scenes_per_model, Path(args.cache), data_dir)
    models = list(dict.fromkeys(sc.model for sc in scenes))
    print(f"{len(scenes)} scenes of {', '.join(models)}\n")
    print("| scan | correct / predicted / copies | precision | recall | F1 | spacing |")
    print("|---|---|---|---|---|---|")
    rows = [(float(f), 0.0, 0.0) for f in args.fractions.split(",")]
    rows += [(1.0, float(n), 0.0) for n in args.noise.split(",") if n]
    rows += [(1.0, 0.0, float(o)) for o in args.outliers.split(",") if o]
    for frac, noise, outliers in rows:
        total, spacing = np.zeros(3, dtype=int), []
        for sc in scenes:
            model = sc.source_points
            voxel = float(np.linalg.norm(model.max(0) - model.min(0))) / VOXELS_PER_DIAGONAL
            scan = sc.target_points
            if frac < 1.0:
                scan = scan[np.random.default_rng(0).random(len(scan)) < frac]
            if noise > 0.0:
                scan = scan + np.random.default_rng(0).normal(scale=noise * voxel, size=scan.shape)
            if outliers > 0.0:
                stray = np.random.default_rng(0).uniform(
                    scan.min(0), scan.max(0), size=(round(outliers * len(scan)), 3)
                )
                scan = np.concatenate([scan, stray])
            spacing.append(_spacing(scan) / voxel)
            poses = pointclm.register_point_clouds(
                model, scan, viewpoint=None if args.no_viewpoint else sc.viewpoint
            ).transformations
            s = score_scene(poses, sc.poses, 15.0, sc.max_translation)
            total += [s.n_matched, s.n_pred, s.n_gt]
        c, p, g = (int(v) for v in total)
        prec, rec = c / max(p, 1), c / max(g, 1)
        f1 = 2 * prec * rec / max(prec + rec, 1e-12)
        label = (
            f"noise {noise:g} voxel"
            if noise
            else f"{outliers:.0%} stray points"
            if outliers
            else f"{frac:.0%} of the points"
        )
        print(
            f"| {label} | {c} / {p} / {g} | {prec:.3f} | {rec:.3f} | {f1:.3f} | "
            f"{np.median(spacing):.2f} voxel |",
            flush=True,
        )


if __name__ == "__main__":
    main()

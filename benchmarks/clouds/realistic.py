"""The realistic benchmark: pointclm vs sequential RANSAC on the same FPFH correspondences.

    pip install open3d-cpu          # only for the RANSAC baseline
    python -m benchmarks.clouds.realistic [--scenes 100] [--model default] [--out FILE]

Scenes: ``pointclm.datasets.scenes.make_realistic_scene(seed)`` for seeds 0..n-1 (Stanford
bunny, 2-8 instances, partial views from a virtual range sensor, real range scans for about
half of the instances, clutter, noise; FPFH matches, mutual, top 10,000, at most 1000 drawn).
An instance is registered when RE < 15 deg and TE < 10 % of the model's diagonal.

Methods, all on the same correspondences, in the same run:
- pointclm, training-free: ``register_point_clouds``' defaults scaled to the voxel
  (``Config()``'s thresholds for raw poses, ``REFINED_THRESHOLDS`` for refined ones);
- the same with the thresholds ``benchmarks/clouds/realistic_thresholds.py`` picks for it on the
  validation models' scenes that picked the networks' (``VALIDATION_PICK``);
- pointclm with each learned embedding of ``--model`` (its recommended point-cloud thresholds,
  raw or refined; the Rust network, so no torch needed);
- an upper bound, not a method: an "oracle" embedding made from the true labels, what a
  perfect network would feed the same pipeline (``ORACLE_CONFIG`` thresholds);
- each of the above again with its poses refined and verified on the clouds
  (``pointclm.refine_poses``, as ``register_point_clouds`` does by default: ICP, then poses
  explaining under 30 % of the model or under 0.8 times the best pose's share are dropped,
  and duplicates), registered with the thresholds for refined poses; RANSAC's poses get the
  same treatment;
- sequential RANSAC (Open3D ``registration_ransac_based_on_correspondence``, 3-point samples,
  inlier threshold 2 voxels (the scenes' inlier definition; pointclm's 6-voxel threshold lets
  wrong poses gather as many inliers as right ones here), 20,000 iterations per
  fit, since at 1-5 % inliers per instance a few hundred samples never draw three inliers):
  fit, remove the inliers, refit, until a fit has fewer than ``min_cluster_size`` inliers
  (pointclm's smallest accepted instance) or 10 fits.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchmarks.common import report
from benchmarks.common.peers import sequential_ransac

#: The training-free sweep's best on the 80 realistic scenes of the validation models
#: (armadillo, bed) that picked each network's thresholds: the two compared on the same
#: footing. Keyed by whether the poses are refined on the clouds (``realistic_thresholds.py
#: --bank VAL`` for False, ``realistic_thresholds.py --refine`` for True).
VALIDATION_PICK = {
    False: {"tau_s": 0.85, "tau_n": 5, "min_cluster_size": 10},
    True: {"tau_s": 0.7, "tau_n": 1, "min_cluster_size": 5},
}


#: Thresholds for the oracle row, picked on the validation models (armadillo, bed): with
#: perfect grouping, small instances need small counts.
# No a-contrario test: it judges whether a cluster could be chance, which true labels settle;
# with it the oracle would drop copies holding a handful of matches and stop being a bound.
ORACLE_CONFIG = {"tau_n": 2, "min_cluster_size": 3, "max_nfa": None}


#: Suffix of the rows whose poses went through `pointclm.refine_poses` (ICP on the clouds and
#: verification), as `register_point_clouds` does by default.
REFINED = " + refinement on the clouds"


def oracle_features(labels: np.ndarray, seed: int) -> np.ndarray:
    """An upper bound, not a method: features from the ground-truth labels (one direction per
    instance, random directions for outliers), what a perfect embedding would give."""
    rng = np.random.default_rng(seed)
    f = rng.normal(size=(len(labels), 16))
    for k in range(int(labels.max(initial=-1)) + 1):
        f[labels == k] = rng.normal(size=16) + 0.05 * rng.normal(size=((labels == k).sum(), 16))
    return f / np.linalg.norm(f, axis=1, keepdims=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=100)
    ap.add_argument(
        "--model", default="default", help="learned embedding(s), comma-separated ('' to skip)"
    )
    ap.add_argument("--skip-ransac", action="store_true", help="leave the slow baseline out")
    ap.add_argument("--out", default="benchmarks/results/clouds/realistic.md")
    args = ap.parse_args()

    import pointclm
    from pointclm.datasets.scenes import make_realistic_scene
    from pointclm.evaluation import register_scaled
    from pointclm.metrics import Summary, score_scene, summarize
    from pointclm.point_clouds import scaled_config

    pick = {k: pointclm.Config(**v) for k, v in VALIDATION_PICK.items()}
    t_start = time.perf_counter()
    try:
        import open3d as o3d

        o3d_version = o3d.__version__
    except ImportError:
        o3d_version = None
    models = [m for m in args.model.split(",") if m]
    methods = [
        "pointclm, training-free",
        "pointclm, training-free, thresholds picked on the validation models",
    ]
    methods += [f"pointclm, learned embedding ({m!r})" for m in models]
    methods.append("upper bound: oracle embedding from the true labels")
    if o3d_version and not args.skip_ransac:
        methods.append(f"sequential RANSAC (Open3D {o3d_version})")
    computed, methods = methods, [row for m in methods for row in (m, m + REFINED)]
    scores: dict[str, list] = {m: [] for m in methods}
    secs: dict[str, list] = {m: [] for m in methods}
    ratios, build, stats = [], [], []
    for seed in range(args.scenes):
        t0 = time.perf_counter()
        sc = make_realistic_scene(seed)
        build.append(sc.timings)
        ratios.extend(sc.inlier_ratios.tolist())
        stats.append((len(sc.target_points), len(sc.correspondences), sc.n_instances))
        te = sc.max_translation
        ransac = None
        for m in computed:
            for refine in (False, True):
                t = time.perf_counter()
                if m.startswith("sequential RANSAC"):
                    # One fit serves both rows; its time counts in both.
                    if ransac is None:
                        ransac = sequential_ransac(
                            sc.correspondences,
                            2.0 * sc.voxel_size,
                            scaled_config(sc.voxel_size).min_cluster_size,
                            20_000,
                        )
                        ransac_s = time.perf_counter() - t
                    else:
                        t -= ransac_s
                    poses = ransac
                elif m.startswith("upper bound"):
                    cfg = scaled_config(sc.voxel_size, pointclm.Config(**ORACLE_CONFIG))
                    feats = oracle_features(sc.labels, seed)
                    r = pointclm.register(sc.correspondences, feats, cfg, 0, num_threads=1)
                    poses = r.transformations
                else:
                    config = pick[refine] if "validation" in m else None
                    model = m.split("(")[1][1:-2] if "learned" in m else None
                    poses = register_scaled(
                        sc.correspondences, sc.voxel_size, config, 0, 1, model, refine
                    ).transformations
                poses = np.asarray(poses).reshape(-1, 4, 4)
                if refine:
                    poses = pointclm.refine_poses(
                        sc.source_points, sc.target_points, poses, sc.voxel_size, num_threads=1
                    ).transformations
                row = m + REFINED if refine else m
                secs[row].append(time.perf_counter() - t)
                scores[row].append(score_scene(poses, sc.poses, 15.0, te))
        print(f"scene {seed}: built in {time.perf_counter() - t0:.2f} s", flush=True)

    hist, edges = np.histogram(np.asarray(ratios) * 100, bins=[0, 1, 2, 5, 10, 20, 100])
    lines = [
        f"- Date: {report.utc_now()}. Command: `{report.command(__spec__.name)}`.",
        f"- Hardware: {report.hardware()}; "
        "pointclm with 1 thread, Open3D with its default threads. "
        f"pointclm {pointclm.__version__} (git {report.git_commit()}).",
        f"- Scenes: seeds 0..{args.scenes - 1}; median {int(np.median([s[0] for s in stats]))} "
        f"scene points, {int(np.median([s[1] for s in stats]))} correspondences, "
        f"{np.mean([s[2] for s in stats]):.1f} instances per scene. RE < 15 deg, TE < 10 % "
        "of the model's diagonal.",
        "",
        "| method | MR | MP | MF (paper) | strict F1 | median ms | p90 ms |",
        "|---|---|---|---|---|---|---|",
    ]
    for m in methods:
        s = summarize(scores[m])
        d = s.as_dict()
        lines.append(
            f"| {m} | {100 * d['mean_recall']:.2f} | {100 * d['mean_precision']:.2f} | "
            f"{100 * d['mean_f1']:.2f} | {100 * d['strict_f1']:.2f} | "
            f"{1e3 * np.median(secs[m]):.1f} | {1e3 * np.percentile(secs[m], 90):.1f} |"
        )
    lines += [
        "",
        "Per-instance inlier ratio (share of a scene's correspondences that are inliers of that "
        "instance; paper appendix Fig. 6):",
        "",
        "| inlier ratio % | "
        + " | ".join(f"{a:g}-{b:g}" for a, b in zip(edges[:-1], edges[1:], strict=True))
        + " |",
        "|---|" + "---|" * len(hist),
        "| instances | " + " | ".join(str(int(h)) for h in hist) + " |",
        "",
        "Scene building, median ms per stage: "
        + ", ".join(f"{k} {1e3 * np.median([b[k] for b in build]):.0f}" for k in build[0])
        + ".",
        f"\nThe whole run took {(time.perf_counter() - t_start) / 60:.1f} min.",
    ]
    _ = Summary
    text = "\n".join(lines)
    print(text)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()

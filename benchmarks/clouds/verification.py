"""Pose verification on the clouds: which rule keeps true poses and rejects wrong ones.

For each realistic scene (one sensor, copies hiding each other) this feeds `refine_poses`
both the TRUE poses and the correspondence stage's candidate poses (training-free, refined
thresholds), every pose kept and scored, and records per pose the statistics each rule
reads: fitness (share of the model explained), and with the sensor's position the visible
fitness, contradiction and seen share. A candidate counts as right when, after ICP, it lies
within 15 degrees and 10 % of the diagonal of a true pose. Then, per scene, the end result
with the default rules with and without the viewpoint (MF, precision, recall, refinement
time). Thresholds may only be picked on the validation models (the default list here).

    PYTHONPATH=python python -m benchmarks.clouds.verification --scenes 6 --out rows.json
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import pointclm
from pointclm.config import Config
from pointclm.datasets.procedural import PROCEDURAL_SHAPES
from pointclm.datasets.scenes import SceneParams, make_realistic_scene
from pointclm.metrics import pose_match_matrix, score_scene, summarize
from pointclm.point_clouds import REFINED_THRESHOLDS, scaled_config

VALIDATION = (
    "stanford/dragon",
    "stanford/happy",
    "stanford/armadillo",
    "modelnet/bathtub",
    "modelnet/bed",
    *PROCEDURAL_SHAPES,
)
KEEP_ALL = {
    "min_fitness": 0.0,
    "min_relative_fitness": 0.0,
    "min_visible_fitness": 0.0,
    "max_contradiction": 1.0,
    "min_seen": 0.0,
    "max_shared": 1.0,
}


def pose_rows(scene, poses: np.ndarray, kind: str) -> list[dict]:
    """Per pose (after ICP): the statistics of both rules, and whether it is right."""
    if len(poses) == 0:
        return []
    r = pointclm.refine_poses(
        scene.source_points,
        scene.target_points,
        poses,
        scene.voxel_size,
        viewpoint=scene.viewpoint,
        **KEEP_ALL,
    )
    right = pose_match_matrix(r.transformations, scene.poses, 15.0, scene.max_translation)
    rows = []
    for i in np.argsort(r.origin):
        rows.append(
            {
                "model": scene.model,
                "seed": scene.seed,
                "kind": kind,
                "right": bool(right[i].any()),
                "fitness": float(r.fitness[i]),
                "visible_fitness": float(r.visible_fitness[i]),
                "contradiction": float(r.contradiction[i]),
                "seen": float(r.seen[i]),
                "by_visibility": r.by_visibility,
            }
        )
    return rows


def run_scene(model: str, seed: int) -> tuple[list[dict], dict]:
    scene = make_realistic_scene(seed, SceneParams(model=model))
    cfg = scaled_config(scene.voxel_size, Config(**REFINED_THRESHOLDS))
    result = pointclm.register(scene.correspondences, None, cfg, seed)
    cands = np.asarray(result.transformations).reshape(-1, 4, 4)
    rows = pose_rows(scene, scene.poses, "true") + pose_rows(scene, cands, "candidate")
    out = {"model": model, "seed": seed, "n_true": scene.n_instances}
    for name, view in [("fraction_of_best", None), ("visibility", scene.viewpoint)]:
        t0 = time.perf_counter()
        r = pointclm.refine_poses(
            scene.source_points, scene.target_points, cands, scene.voxel_size, viewpoint=view
        )
        out[f"{name}_seconds"] = time.perf_counter() - t0
        s = score_scene(r.transformations, scene.poses, 15.0, scene.max_translation)
        out[name] = {"n_pred": len(r.origin), "n_matched": s.n_matched, "by_vis": r.by_visibility}
        out[f"{name}_score"] = s
    origin = pointclm.refine_poses(
        scene.source_points, scene.target_points, cands[:1], scene.voxel_size, viewpoint=(0, 0, 0)
    )
    out["origin_viewpoint_trusted"] = origin.by_visibility
    return rows, out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=4, help="scenes per model")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--models", nargs="*", default=list(VALIDATION))
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    rows: list[dict] = []
    scenes: list[dict] = []
    for model in args.models:
        for seed in range(args.seed, args.seed + args.scenes):
            r, s = run_scene(model, seed)
            rows += r
            scenes.append(s)
            print(model, seed, {k: v for k, v in s.items() if not k.endswith("_score")}, flush=True)
    for name in ("fraction_of_best", "visibility"):
        summ = summarize([s[f"{name}_score"] for s in scenes])
        secs = np.array([s[f"{name}_seconds"] for s in scenes])
        print(f"{name}: {summ}  refinement median {np.median(secs):.3f} s, mean {secs.mean():.3f}")
    if args.out:
        for s in scenes:
            for name in ("fraction_of_best", "visibility"):
                s.pop(f"{name}_score")
        with open(args.out, "w") as f:
            json.dump({"rows": rows, "scenes": scenes}, f)


if __name__ == "__main__":
    main()

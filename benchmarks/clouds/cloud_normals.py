"""Correspondences from clouds: top-k matching and the normal term, measured scene by scene.

    python -m benchmarks.clouds.cloud_normals --models stanford/dragon stanford/happy --scenes 10

For each realistic scene (``pointclm.datasets.scenes.make_realistic_scene``, seeds from
``--seed``, apart from the threshold-picking banks' seeds) the script keeps the two described
clouds the scene was built from (points, normals, FPFH: the same as ``register_point_clouds``
computes) and rebuilds the correspondences for every matching variant (``--variants``, each
``k,mutual,n_samples``). A correspondence is true if its scene point lies on copy ``m`` and
the true pose of ``m`` maps its model point within 2 voxels of it (the scenes' own rule).

Reported per variant, with and without normals given to the pipeline:
- true matches per copy (median over copies) and the share of copies with at least 3;
- precision and recall of the correspondences kept by pruning (``register(...).kept``);
- MF of the poses, raw (``refine=False``'s thresholds) and refined and verified on the clouds
  (``REFINED_THRESHOLDS``, ``refine_poses``), as ``register_point_clouds`` does;
- median pruning seconds.
Only validation models may pick a default from these figures (see BENCHMARKS.md).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import pointclm.preprocessing as pp
from pointclm import register
from pointclm.datasets import scenes as sc
from pointclm.metrics import score_scene, summarize
from pointclm.point_clouds import cloud_config
from pointclm.refinement import refine_poses


@dataclass
class Captured:
    scene: Any
    source: pp.DescribedCloud
    target: pp.DescribedCloud


def build(seed: int, model: str) -> Captured:
    """The scene and the two described clouds it was matched from."""
    seen: list[pp.DescribedCloud] = []
    original = pp.describe

    def spy(*args: Any, **kwargs: Any) -> pp.DescribedCloud:
        out = original(*args, **kwargs)
        seen.append(out)
        return out

    pp.describe = spy  # type: ignore[assignment]
    try:
        scene = sc.make_realistic_scene(seed, sc.SceneParams(model=model))
    finally:
        pp.describe = original  # type: ignore[assignment]
    target, source = seen  # the scene describes the scan first, then the model
    return Captured(scene, source, target)


def true_labels(cap: Captured, m: pp.Matches) -> np.ndarray:
    s = cap.scene
    owner = s.target_ids[m.target]
    labels = np.full(len(m), -1)
    x = cap.source.points[m.source]
    y = cap.target.points[m.target]
    for k, pose in enumerate(s.poses):
        mine = owner == k
        err = np.linalg.norm(x[mine] @ pose[:3, :3].T + pose[:3, 3] - y[mine], axis=1)
        labels[np.flatnonzero(mine)[err < 2.0 * s.voxel_size]] = k
    return labels


def flip_share(cap: Captured, m: pp.Matches, labels: np.ndarray) -> float:
    """Share of true matches whose two normals disagree in sign under the true pose."""
    flips, total = 0, 0
    for k, pose in enumerate(cap.scene.poses):
        mine = labels == k
        ns = cap.source.normals[m.source[mine]] @ pose[:3, :3].T
        nt = cap.target.normals[m.target[mine]]
        flips += int(((ns * nt).sum(1) < 0).sum())
        total += int(mine.sum())
    return flips / max(total, 1)


def run_variant(
    cap: Captured, k: int, mutual: bool, n_samples: int | None, normals: bool, seed: int
) -> dict[str, Any]:
    s = cap.scene
    m = pp.match_features(
        cap.source.descriptors,
        cap.target.descriptors,
        mutual=mutual,
        n_samples=n_samples,
        seed=s.seed,
        k=k,
    )
    corr = m.correspondences(cap.source.points, cap.target.points)
    labels = true_labels(cap, m)
    per_copy = np.bincount(labels[labels >= 0], minlength=len(s.poses))
    nrm = m.normals(cap.source.normals, cap.target.normals) if normals else None
    out: dict[str, Any] = {
        "per_copy": per_copy,
        "inlier_share": float((labels >= 0).mean()),
        "flips": flip_share(cap, m, labels),
    }
    for refine in (False, True):
        cfg = cloud_config(s.voxel_size, None, refine)
        r = register(corr, None, cfg, seed, normals=nrm, num_threads=1)
        kept = np.asarray(r.kept, dtype=np.int64)
        true_kept = int((labels[kept] >= 0).sum())
        poses = np.asarray(r.transformations).reshape(-1, 4, 4)
        if refine:
            poses = refine_poses(
                cap.source.points, cap.target.points, poses, s.voxel_size, num_threads=1
            ).transformations
        tag = "ref" if refine else "raw"
        out[f"score_{tag}"] = score_scene(
            poses, s.poses, max_translation=getattr(s, "max_translation", 0.1 * s.diameter)
        )
        out[f"kept_p_{tag}"] = true_kept / max(len(kept), 1)
        out[f"kept_r_{tag}"] = true_kept / max(int((labels >= 0).sum()), 1)
        out[f"prune_s_{tag}"] = float(dict(r.timings)["pruning"])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=["stanford/dragon"])
    ap.add_argument("--scenes", type=int, default=5)
    ap.add_argument("--seed", type=int, default=70_000)
    ap.add_argument(
        "--variants",
        nargs="+",
        default=["1,1,1000", "1,0,1000", "3,0,1000", "3,0,2000"],
        help="k,mutual,n_samples (n_samples 0: all)",
    )
    ap.add_argument("--normals", default="0,1", help="normal settings to run: 0, 1 or 0,1")
    args = ap.parse_args()
    settings = [bool(int(v)) for v in args.normals.split(",")]
    for model in args.models:
        t0 = time.perf_counter()
        caps = [build(args.seed + i, model) for i in range(args.scenes)]
        print(
            f"\n== {model}: {args.scenes} scenes (seeds {args.seed}..), built in "
            f"{time.perf_counter() - t0:.0f} s"
        )
        print(
            f"{'variant':<22} {'med/copy':>8} {'>=3':>5} {'inl%':>5} {'flip%':>5} "
            f"{'keptP':>5} {'keptR':>5} {'MFraw':>6} {'keptP':>5} {'keptR':>5} {'MFref':>6} "
            f"{'prune_ms':>8}"
        )
        for v in args.variants:
            k, mu, ns = (int(x) for x in v.split(","))
            for normals in settings:
                rows = [run_variant(c, k, bool(mu), ns or None, normals, 0) for c in caps]
                per_copy = np.concatenate([r["per_copy"] for r in rows])
                mf = {t: summarize([r[f"score_{t}"] for r in rows]).mean_f1 for t in ("raw", "ref")}

                def mean(key: str, rows: list[dict[str, Any]] = rows) -> float:
                    return float(np.mean([r[key] for r in rows]))

                name = f"k={k} mutual={mu} n={ns or 'all'}" + (" +n" if normals else "")
                print(
                    f"{name:<22} {np.median(per_copy):8.1f} {100 * (per_copy >= 3).mean():5.0f} "
                    f"{100 * mean('inlier_share'):5.1f} {100 * mean('flips'):5.1f} "
                    f"{100 * mean('kept_p_raw'):5.1f} {100 * mean('kept_r_raw'):5.1f} "
                    f"{100 * mf['raw']:6.2f} {100 * mean('kept_p_ref'):5.1f} "
                    f"{100 * mean('kept_r_ref'):5.1f} {100 * mf['ref']:6.2f} "
                    f"{1000 * np.median([r['prune_s_raw'] for r in rows]):8.1f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()

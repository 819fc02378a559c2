"""Pipeline thresholds for realistic scenes, chosen on validation models only.

Realistic scenes (range-sensor views, FPFH matches) hold a handful of inliers per instance,
where the synthetic protocol holds dozens: the count thresholds (tau_n, min_cluster_size) that
suit one do not suit the other. This sweeps them on realistic scenes of the validation models
(stanford/armadillo, modelnet/bed; never trained on, never the benchmark's bunny), for the
training-free pipeline and for each network, and prints the best of each: the source of a
network's ``recommended_point_cloud_config``. The training-free pipeline learns nothing, so
any scenes but the benchmark's may choose its thresholds (add the training bank); its pick
did not carry over to the bunny (BENCHMARKS.md), so ``register_point_clouds`` keeps
``Config()``'s.

    python benchmarks/realistic_thresholds.py --bank VAL_BANK.npz [--model default ...]
    python benchmarks/realistic_thresholds.py --build 40 --data-dir ../shared/data

Needs torch for the networks.
"""

from __future__ import annotations

import argparse
import itertools
import json

import numpy as np
import pointclm
from pointclm.point_clouds import embed_scaled, scaled_config
from pointclm.training.realistic import SceneBank, score_bank

TAU_S = (0.7, 0.8, 0.85, 0.9, 0.95)
TAU_N = (1, 2, 3, 5, 10)
MIN_CLUSTER = (3, 4, 5, 7, 10)


def sweep(bank: SceneBank, model: str | None, grid: list[dict]) -> list[tuple[dict, dict]]:
    feats = [
        None
        if model is None
        else embed_scaled(c.astype(np.float64), model, scaled_config(float(v)), None)
        for c, v in zip(bank.correspondences, bank.voxels, strict=True)
    ]
    return [(params, score_bank(bank, feats, pointclm.Config(**params))) for params in grid]


def _concat(banks: list[SceneBank], every: int) -> SceneBank:
    pick = [(b, i) for b in banks for i in range(0, len(b), every)]
    models = sorted({m for b in banks for m in b.models})
    return SceneBank(
        [b.correspondences[i] for b, i in pick],
        [b.labels[i] for b, i in pick],
        np.array([b.voxels[i] for b, i in pick]),
        np.array([b.diameters[i] for b, i in pick]),
        [b.poses[i] for b, i in pick],
        models,
        np.array([models.index(b.models[b.model_of[i]]) for b, i in pick]),
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument(
        "--bank",
        action="append",
        default=[],
        help="saved SceneBank(s); repeatable. For the training-free pipeline any scenes but the "
        "benchmark's qualify (it learns nothing); for a network, only models it never saw",
    )
    ap.add_argument("--every", type=int, default=1, help="take every k-th scene of each bank")
    ap.add_argument("--build", type=int, default=40, help="scenes per validation model")
    ap.add_argument("--data-dir", default="../shared/data")
    ap.add_argument("--model", action="append", default=[], help="network(s); repeatable")
    ap.add_argument("--out", help="write the full sweep as JSON")
    args = ap.parse_args()
    if args.bank:
        bank = _concat([SceneBank.load(b) for b in args.bank], args.every)
    else:
        from pointclm.training.config import VAL_SHAPES

        bank = SceneBank.build(VAL_SHAPES, args.build, 1, args.data_dir, progress=True)
    print(f"{len(bank)} validation scenes of {', '.join(bank.models)}")
    grid = [
        {"tau_s": s, "tau_n": n, "min_cluster_size": m}
        for s, n, m in itertools.product(TAU_S, TAU_N, MIN_CLUSTER)
    ]
    report = {}
    for model in [None, *args.model]:
        res = sweep(bank, model, grid)
        name = model or "training-free"
        res.sort(key=lambda r: (r[1]["mean_f1"], r[1]["strict_f1"]), reverse=True)
        report[name] = res
        print(f"\n{name}: best 5 of {len(res)}")
        for params, m in res[:5]:
            print(
                f"  {json.dumps(params):55s} MR {100 * m['mean_recall']:.2f} "
                f"MP {100 * m['mean_precision']:.2f} MF {100 * m['mean_f1']:.2f} "
                f"strict F1 {100 * m['strict_f1']:.2f}"
            )
        base = pointclm.Config()
        default = [
            m
            for p, m in res
            if (p["tau_s"], p["tau_n"], p["min_cluster_size"])
            == (base.tau_s, base.tau_n, base.min_cluster_size)
        ]
        print(f"  (Config() thresholds: MF {100 * default[0]['mean_f1']:.2f})")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()

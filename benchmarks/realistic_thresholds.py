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
    python benchmarks/realistic_thresholds.py --refine --build 40 --train 40 --model default

``--refine`` scores what ``register_point_clouds`` returns by default: the poses refined and
verified on the clouds (`pointclm.refine_poses`). The scenes then keep their clouds, so they
are built in the run (``--cache DIR`` keeps them). ``--train N`` adds N scenes of each training
model (dragon, happy, bathtub) to the training-free sweep only: a network is scored on models
it never saw.

Needs torch for the networks.
"""

from __future__ import annotations

import argparse
import itertools
import json

import numpy as np
import pointclm
from pointclm.metrics import score_scene, summarize
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


def build_cloud_scenes(models: tuple[str, ...], n: int, base: int, data_dir: str) -> list:
    """`n` realistic scenes of each model, clouds kept, with the bank's seeds and clutter."""
    from concurrent.futures import ProcessPoolExecutor

    from pointclm.training.realistic import bank_scene, scene_seed

    jobs = [(m, scene_seed(base, i, k)) for i, m in enumerate(models) for k in range(n)]
    names, seeds = zip(*jobs, strict=True)
    with ProcessPoolExecutor() as pool:
        return list(pool.map(bank_scene, names, seeds, itertools.repeat(data_dir), chunksize=2))


class _RefinedScorer:
    """Scores configs with the poses refined on the clouds. ICP of one pose does not depend
    on the other poses, so each distinct raw pose is refined once per scene and only the
    verification (which does) runs per config: the same result as `refine_poses` on the raw
    poses, at a fraction of the cost."""

    def __init__(self, scenes: list) -> None:
        self.scenes = scenes
        self.icp: list[dict[bytes, np.ndarray]] = [{} for _ in scenes]

    def refined(self, i: int, poses: np.ndarray) -> np.ndarray:
        sc, cache = self.scenes[i], self.icp[i]
        new = [p for p in poses if p.tobytes() not in cache]
        if new:
            r = pointclm.refine_poses(
                sc.source_points,
                sc.target_points,
                np.array(new),
                sc.voxel_size,
                min_fitness=0.0,
                min_relative_fitness=0.0,
                max_shared=1.0,
            )
            for k, pose in zip(r.origin, r.transformations, strict=True):
                cache[new[k].tobytes()] = pose
        icped = np.array([cache[p.tobytes()] for p in poses]).reshape(-1, 4, 4)
        return pointclm.refine_poses(
            sc.source_points, sc.target_points, icped, sc.voxel_size, icp=False
        ).transformations

    def sweep(self, model: str | None, grid: list[dict], scenes: range) -> list[tuple[dict, dict]]:
        feats = {
            i: None
            if model is None
            else embed_scaled(
                self.scenes[i].correspondences,
                model,
                scaled_config(self.scenes[i].voxel_size),
                None,
            )
            for i in scenes
        }
        out = []
        for params in grid:
            scores = []
            for i in scenes:
                sc = self.scenes[i]
                cfg = scaled_config(sc.voxel_size, pointclm.Config(**params))
                raw = pointclm.register(sc.correspondences, feats[i], cfg, seed=0)
                poses = self.refined(i, np.asarray(raw.transformations).reshape(-1, 4, 4))
                scores.append(score_scene(poses, sc.poses, 15.0, sc.max_translation))
            out.append((params, summarize(scores).as_dict()))
        return out


def _cloud_scenes(args: argparse.Namespace) -> tuple[list, list]:
    """(validation scenes, training-model scenes), from ``--cache`` when there."""
    import pickle
    from pathlib import Path

    from pointclm.training.config import REALISTIC_MODELS, VAL_SHAPES

    out = []
    for models, n, base, name in (
        (VAL_SHAPES, args.build, 1, "val"),
        (REALISTIC_MODELS, args.train, 0, "train"),
    ):
        path = Path(args.cache or ".", f"clouds_{name}_{n}.pkl")
        if n == 0:
            out.append([])
        elif args.cache and path.exists():
            out.append(pickle.loads(path.read_bytes()))
        else:
            out.append(build_cloud_scenes(models, n, base, args.data_dir))
            if args.cache:
                path.write_bytes(pickle.dumps(out[-1]))
    return out[0], out[1]


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


def _report(res: list[tuple[dict, dict]]) -> list[tuple[dict, dict]]:
    """Sort by MF (strict F1 breaks ties), print the best 5 and ``Config()``'s."""
    res.sort(key=lambda r: (r[1]["mean_f1"], r[1]["strict_f1"]), reverse=True)
    print(f"  best 5 of {len(res)}")
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
    print(f"  (Config() thresholds: MF {100 * default[0]['mean_f1']:.2f})", flush=True)
    return res


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
    ap.add_argument("--refine", action="store_true", help="score refined, verified poses")
    ap.add_argument("--train", type=int, default=0, help="--refine: scenes per training model")
    ap.add_argument("--cache", help="--refine: folder keeping the built scenes (pickles)")
    args = ap.parse_args()
    grid = [
        {"tau_s": s, "tau_n": n, "min_cluster_size": m}
        for s, n, m in itertools.product(TAU_S, TAU_N, MIN_CLUSTER)
    ]
    if args.refine:
        val, train = _cloud_scenes(args)
        scorer = _RefinedScorer(val + train)
        on_val, on_all = range(len(val)), range(len(val) + len(train))
        runs = [("training-free", None, on_val)]
        if train:
            runs.append(("training-free, training and validation models", None, on_all))
        runs += [(m, m, on_val) for m in args.model]
        report = {}
        for name, model, scenes in runs:
            print(f"\n{name}, refined on the clouds: {len(scenes)} scenes", flush=True)
            report[name] = _report(scorer.sweep(model, grid, scenes))
        if args.out:
            with open(args.out, "w") as f:
                json.dump(report, f, indent=1)
        return
    if args.bank:
        bank = _concat([SceneBank.load(b) for b in args.bank], args.every)
    else:
        from pointclm.training.config import VAL_SHAPES

        bank = SceneBank.build(VAL_SHAPES, args.build, 1, args.data_dir, progress=True)
    print(f"{len(bank)} validation scenes of {', '.join(bank.models)}")
    report = {}
    for model in [None, *args.model]:
        name = model or "training-free"
        print(f"\n{name}")
        report[name] = _report(sweep(bank, model, grid))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()

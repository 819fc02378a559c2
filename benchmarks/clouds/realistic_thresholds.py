"""Pipeline thresholds for realistic scenes, chosen on the VALIDATION models only.

Realistic scenes (range-sensor views, FPFH matches) hold a handful of inliers per instance,
where the synthetic protocol holds dozens: the count thresholds (tau_n, min_cluster_size) that
suit one do not suit the other. This sweeps them on realistic scenes of the validation models
(``pointclm.datasets.scenes.VALIDATION_MODELS``: dragon, happy, armadillo, bathtub, bed and
the procedural shapes) and prints the best: for the training-free pipeline's correspondence
stage alone, with ``--refine`` also for its poses refined and verified on the clouds (what
``register_point_clouds`` returns), and for each network of ``--model``. The held-out models
(``HELDOUT_MODELS``: the bunny and the common3d meshes) are refused: they only report.

    python -m benchmarks.clouds.realistic_thresholds [--scenes-per-model 10] [--refine]
        [--model default]
    python -m benchmarks.clouds.realistic_thresholds --bank VAL_BANK.npz [--model default ...]

**Seeds.** Model ``m``'s sweep scenes are ``make_realistic_scene(seed)`` for the seeds
``realistic_models.threshold_seeds(m, n)`` (2,000,000 + 1000 x the model's slot + k), built
as the benchmark builds its own (``realistic_models.scene_params``, same ``--n``) and cached
beside them (``--cache``, npz).
They share no seed with the benchmark's scenes (1,000,000 + ...) or the training banks.

A network is scored only on the validation models it never trained on (not in
``training.config.TRAIN_SHAPES`` or ``REALISTIC_MODELS``: armadillo and bed, nor among the
procedural shapes its config drew). ``--procedural K`` adds ``K`` random procedural shapes
(``procedural_family_names(K, 7)``, ``--scenes-per-shape`` scenes each): shapes no
threshold or network was chosen on, asymmetric by construction, and as many as wanted.
``--bank``
sweeps a saved ``SceneBank`` instead (correspondences only, no ``--refine``), e.g. a
network's validation bank. Needs torch for the networks.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pointclm
from pointclm.datasets.procedural import is_procedural, procedural_family_names
from pointclm.embedding import Embedding, resolve
from pointclm.evaluation import scene_cues
from pointclm.metrics import score_scene, summarize
from pointclm.point_clouds import REFINED_THRESHOLDS, scaled_config
from pointclm.training.realistic import SceneBank, bank_cues, score_bank

from benchmarks.clouds.scenes import data_folder, load_scenes, scene_params, threshold_seeds

TAU_S = (0.7, 0.8, 0.85, 0.9, 0.95)
TAU_N = (1, 2, 3, 5, 10)
MIN_CLUSTER = (3, 4, 5, 7, 10)
#: Seed of ``--procedural``'s shapes; training draws its own with ``TrainConfig.seed`` (0), and
#: a network is scored only on the shapes its config did not draw.
PROCEDURAL_VALIDATION_SEED = 7


def validation_jobs(
    models: list[str],
    scenes_per_model: int,
    procedural: int,
    scenes_per_shape: int,
    n: int,
    data_dir: str,
    procedural_seed: int = PROCEDURAL_VALIDATION_SEED,
) -> list[tuple[str, int, Any]]:
    """The `load_scenes` jobs of the threshold sweep: `scenes_per_model` scenes of each of
    `models`, and `scenes_per_shape` of each of `procedural` random procedural shapes."""
    return [
        (m, s, scene_params(m, n, data_dir))
        for m in models
        for s in threshold_seeds(m, scenes_per_model)
    ] + [
        (m, s, scene_params(m, n, data_dir))
        for m in procedural_family_names(procedural, procedural_seed)
        for s in threshold_seeds(m, scenes_per_shape)
    ]


def bank_sweep(bank: SceneBank, emb: Embedding | None, grid: list[dict]) -> list[tuple[dict, dict]]:
    feats: list[np.ndarray | None] = []
    normals: list[np.ndarray | None] = []
    for i, (c, v) in enumerate(zip(bank.correspondences, bank.voxels, strict=True)):
        if emb is None:
            feats.append(None)
            normals.append(None)
            continue
        n, sims = bank_cues(bank, i, emb.inputs)
        cfg = scaled_config(float(v))
        feats.append(emb.embed(c.astype(np.float64), cfg.sigma_d, normals=n, similarity=sims))
        normals.append(emb.pipeline_normals(n))
    return [
        (params, score_bank(bank, feats, pointclm.Config(**params), normals)) for params in grid
    ]


class Scorer:
    """Scores configs on scenes with their clouds, raw or refined. ICP of one pose does not
    depend on the other poses, so each distinct raw pose is refined once per scene and only
    the verification (which does) runs per config: the same result as `refine_poses` on the
    raw poses, at a fraction of the cost."""

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
                max_slid_fitness=1.0,
                min_relative_fitness=0.0,
                max_shared=1.0,
            )
            for k, pose in zip(r.origin, r.transformations, strict=True):
                cache[new[k].tobytes()] = pose
        icped = np.array([cache[p.tobytes()] for p in poses]).reshape(-1, 4, 4)
        return pointclm.refine_poses(
            sc.source_points, sc.target_points, icped, sc.voxel_size, icp=False
        ).transformations

    def sweep(
        self, feats: dict[int, Any] | None, grid: list[dict], scenes: list[int], refine: bool
    ) -> list[tuple[dict, dict]]:
        """Scores of each config of `grid` on `scenes`, with each scene's (embedding,
        pipeline normals) in `feats` (:func:`features`); None: training-free."""
        out = []
        for params in grid:
            scores = []
            for i in scenes:
                sc = self.scenes[i]
                cfg = scaled_config(sc.voxel_size, pointclm.Config(**params))
                f, normals = (None, None) if feats is None else feats[i]
                raw = pointclm.register(sc.correspondences, f, cfg, seed=0, normals=normals)
                poses = np.asarray(raw.transformations).reshape(-1, 4, 4)
                if refine:
                    poses = self.refined(i, poses)
                scores.append(score_scene(poses, sc.poses, 15.0, sc.max_translation))
            out.append((params, summarize(scores).as_dict()))
        return out


def features(scene: Any, emb: Embedding | None) -> tuple[np.ndarray | None, np.ndarray | None]:
    """A scene's embedding with the cues its network takes, and the normals the pipeline
    gets with it (as `register_point_clouds` runs such a network); (None, None) without one."""
    if emb is None:
        return None, None
    normals, sims = scene_cues(scene)
    cfg = scaled_config(scene.voxel_size)
    f = emb.embed(scene.correspondences, cfg.sigma_d, normals=normals, similarity=sims)
    return f, emb.pipeline_normals(normals)


def trained_on(model: str, fallback: tuple[str, ...]) -> set[str]:
    """The models a network saw in training, from the config its weights carry: its
    realistic models, and its synthetic shapes unless it trained on realistic scenes alone
    (`fallback` for weights without one)."""
    from pointclm.model import load_metadata

    cfg = load_metadata(pointclm.model.weights_path(model)).get("train_config")
    if not isinstance(cfg, dict):
        return set(fallback)
    trained = set(cfg.get("realistic_models", ()))
    if float(cfg.get("realistic_fraction", 0.0)) < 1.0:
        trained |= set(cfg.get("train_shapes", ()))
    shapes = int(cfg.get("procedural_shapes", 0) or 0)
    return trained | set(procedural_family_names(shapes, int(cfg.get("seed", 0))))


def _concat(banks: list[SceneBank], every: int) -> SceneBank:
    pick = [(b, i) for b in banks for i in range(0, len(b), every)]
    models = sorted({m for b in banks for m in b.models})
    cues = all(b.normals is not None and b.similarities is not None for b in banks)
    return SceneBank(
        [b.correspondences[i] for b, i in pick],
        [b.labels[i] for b, i in pick],
        np.array([b.voxels[i] for b, i in pick]),
        np.array([b.diameters[i] for b, i in pick]),
        [b.poses[i] for b, i in pick],
        models,
        np.array([models.index(b.models[b.model_of[i]]) for b, i in pick]),
        [b.normals[i] for b, i in pick] if cues else None,  # type: ignore[index]
        [b.similarities[i] for b, i in pick] if cues else None,  # type: ignore[index]
    )


def _key(p: dict) -> tuple:
    return (p["tau_s"], p["tau_n"], p["min_cluster_size"])


def _report(res: list[tuple[dict, dict]], refine: bool) -> list[tuple[dict, dict]]:
    """Sort by MF (strict F1 breaks ties), print the best 5 and the current defaults'."""
    res.sort(key=lambda r: (r[1]["mean_f1"], r[1]["strict_f1"]), reverse=True)
    print(f"  best 5 of {len(res)}")
    for params, m in res[:5]:
        print(
            f"  {json.dumps(params):55s} MR {100 * m['mean_recall']:.2f} "
            f"MP {100 * m['mean_precision']:.2f} MF {100 * m['mean_f1']:.2f} "
            f"strict F1 {100 * m['strict_f1']:.2f}"
        )
    base = pointclm.Config()
    defaults = {"Config()": (base.tau_s, base.tau_n, base.min_cluster_size)}
    if refine:
        defaults["REFINED_THRESHOLDS"] = _key(REFINED_THRESHOLDS)
    for name, key in defaults.items():
        hit = [m for p, m in res if _key(p) == key]
        if hit:
            print(f"  ({name} thresholds: MF {100 * hit[0]['mean_f1']:.2f})", flush=True)
    return res


def main() -> None:
    from pointclm.datasets.scenes import HELDOUT_MODELS, VALIDATION_MODELS
    from pointclm.training.config import REALISTIC_MODELS, TRAIN_SHAPES

    ap = argparse.ArgumentParser()
    ap.add_argument(
        "--models", default=",".join(VALIDATION_MODELS), help="validation models to sweep on"
    )
    ap.add_argument("--scenes-per-model", type=int, default=10)
    ap.add_argument(
        "--procedural",
        type=int,
        default=0,
        help="also sweep on this many random procedural shapes (seed --procedural-seed)",
    )
    ap.add_argument("--procedural-seed", type=int, default=PROCEDURAL_VALIDATION_SEED)
    ap.add_argument("--scenes-per-shape", type=int, default=2, help="of --procedural")
    ap.add_argument("--n", type=int, default=1000, help="correspondences per scene")
    ap.add_argument("--refine", action="store_true", help="also score refined, verified poses")
    ap.add_argument("--model", action="append", default=[], help="network(s); repeatable")
    ap.add_argument("--backend", default="rust", choices=["rust", "torch"], help="of --model")
    ap.add_argument("--cache", default="out/realistic_scenes", help="built scenes (npz)")
    ap.add_argument("--data-dir", default=None)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--out", help="write the full sweep as JSON")
    ap.add_argument("--bank", action="append", default=[], help="sweep saved SceneBank(s)")
    ap.add_argument("--every", type=int, default=1, help="--bank: every k-th scene")
    args = ap.parse_args()
    nets = {m: resolve(m, args.backend) for m in args.model}  # each loaded once
    grid = [
        {"tau_s": s, "tau_n": n, "min_cluster_size": m}
        for s, n, m in itertools.product(TAU_S, TAU_N, MIN_CLUSTER)
    ]
    report = {}
    if args.bank:
        bank = _concat([SceneBank.load(b) for b in args.bank], args.every)
        leak = sorted(set(bank.models) & {*HELDOUT_MODELS, "bunny"})
        if leak:
            raise SystemExit(f"held-out models never pick thresholds: {', '.join(leak)}")
        print(f"{len(bank)} scenes of {', '.join(bank.models)}")
        for model in [None, *args.model]:
            name = model or "training-free"
            print(f"\n{name}")
            report[name] = _report(bank_sweep(bank, nets.get(model), grid), False)
    else:
        models = [m.strip() for m in args.models.split(",") if m.strip()]
        bad = [m for m in models if m not in VALIDATION_MODELS and not is_procedural(m)]
        if bad:
            raise SystemExit(
                f"not validation models: {', '.join(bad)} (held-out models never pick "
                f"thresholds); choose from {', '.join(VALIDATION_MODELS)}"
            )
        jobs = validation_jobs(
            models,
            args.scenes_per_model,
            args.procedural,
            args.scenes_per_shape,
            args.n,
            data_folder(args.data_dir),
            args.procedural_seed,
        )
        scenes = load_scenes(jobs, Path(args.cache), args.workers)
        scorer = Scorer(scenes)
        every = list(range(len(scenes)))
        runs = [("training-free", None, every)]
        for m in args.model:
            trained = trained_on(m, (*TRAIN_SHAPES, *REALISTIC_MODELS))
            runs.append((m, m, [i for i, sc in enumerate(scenes) if sc.model not in trained]))
        for name, model, idx in runs:
            names = sorted({scenes[i].model for i in idx})
            # one embedding per scene for every config, raw and refined
            feats = {i: features(scenes[i], None if model is None else nets[model]) for i in idx}
            for refine in (False, True) if args.refine else (False,):
                label = (
                    f"{name}{', refined on the clouds' if refine else ', correspondences alone'}"
                )
                print(f"\n{label}: {len(idx)} scenes of {', '.join(names)}", flush=True)
                report[label] = _report(scorer.sweep(feats, grid, idx, refine), refine)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()

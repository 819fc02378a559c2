"""How much a learned stage could add to the correspondence stage on realistic scenes.

The target set for the learned embedding is +3 MF over the training-free pipeline on FPFH
correspondences alone. This measures what perfect or learned knowledge of each row would buy
that stage, on VALIDATION scenes built as ``realistic_thresholds`` builds its own (the five
validation data models, 20 scenes each, and 30 random procedural shapes, 2 scenes each;
held-out models are refused). Every row registers raw poses (no clouds) and is scored by MF,
the paper's definition (RE < 15 deg, TE < 10 % of the diagonal):

- the training-free pipeline at its defaults (``register_point_clouds``' raw thresholds), and
  at the best thresholds of the grid every other row may also pick from (so that no row gains
  by its thresholds alone);
- the same rows less a random share of the true outliers (an oracle), at the defaults;
- only the true inliers, at the defaults and at the best thresholds of a small grid, with and
  without the a-contrario test (``max_nfa``);
- a learned per-row inlier score: gradient-boosted trees (scikit-learn) on the similarity of
  each match and its spatial- and normal-consistency degrees, trained on half the scenes and
  applied to the other half (two folds by scene); the share of rows kept and the thresholds
  are picked on the training fold with out-of-fold scores;
- the oracle embedding of ``realistic`` (one direction per true instance): perfect
  grouping, the ceiling of any embedding;
- with ``--model``, each network (Rust forward pass) against training-free on the scenes of
  the models it never trained on, on all rows and on the rows the learned score ranks first.

    python -m benchmarks.clouds.realistic_ceilings [--scenes-per-model 20] [--procedural 30]
        [--out benchmarks/results/clouds/realistic_ceilings.md]
"""

from __future__ import annotations

import argparse
import itertools
import os
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
import pointclm
from pointclm.datasets.procedural import is_procedural
from pointclm.evaluation import register_scaled, scene_cues
from pointclm.metrics import SceneScore, score_scene, summarize

from benchmarks.clouds.methods import oracle
from benchmarks.clouds.realistic_thresholds import validation_jobs
from benchmarks.clouds.scenes import data_folder, load_scenes

#: Thresholds an oracle or a learned score may pick from (the sweep's counts).
GRID = [
    {"tau_s": s, "tau_n": n, "min_cluster_size": m}
    for s, n, m in itertools.product((0.7, 0.8, 0.9), (1, 2, 3, 5), (3, 4, 5))
]
#: Shares of rows, highest learned score first, a learned score may keep.
KEEP = (0.1, 0.2, 0.3, 0.5, 1.0)
#: Consistency tolerances of the row features, in voxels.
TOLERANCES = (1.0, 2.0, 3.0)
#: The column of `row_features` the pipeline's own pruning comes closest to: the share of rows
#: length- and normal-consistent within the first tolerance (after similarity and its rank,
#: each tolerance adds length, length and normal, second order).
DEGREE_COLUMN = 3


def row_features(scene: Any) -> np.ndarray:
    """Per-row inputs of the learned inlier score: descriptor similarity and its rank, and for
    each tolerance the share of rows length-consistent with this one, also normal-consistent
    (angles between the normals within 20 degrees), and the second-order count of the latter
    (SC^2, Chen et al. 2022)."""
    c, v = scene.correspondences, scene.voxel_size
    normals, sims = scene_cues(scene)
    d_model = np.linalg.norm(c[:, None, :3] - c[None, :, :3], axis=2)
    d_scene = np.linalg.norm(c[:, None, 3:] - c[None, :, 3:], axis=2)
    err = np.abs(d_model - d_scene) / v
    ang_model = np.arccos(np.clip(normals[:, :3] @ normals[:, :3].T, -1, 1))
    ang_scene = np.arccos(np.clip(normals[:, 3:] @ normals[:, 3:].T, -1, 1))
    normal_ok = np.abs(ang_model - ang_scene) < np.radians(20.0)
    apart = d_model > 2 * v  # a row is not evidence for itself or its neighbours
    n = len(c)
    cols = [sims, np.argsort(np.argsort(-sims)) / n]
    for tol in TOLERANCES:
        length = (err < tol) & apart
        both = (length & normal_ok).astype(np.float32)
        cols += [length.sum(1) / n, both.sum(1) / n, ((both @ both) * both).sum(1) / n**2]
    return np.stack(cols, 1)


def _register(
    scene: Any, rows: np.ndarray, base: pointclm.Config | None, net: Any = None
) -> np.ndarray:
    if len(rows) < 3:
        return np.zeros((0, 4, 4))
    normals, sims = scene_cues(scene)
    r = register_scaled(
        scene.correspondences[rows], scene.voxel_size, base, 0, 1, net, False,
        (normals[rows], sims[rows]),
    )  # fmt: skip
    return np.asarray(r.transformations, dtype=np.float64).reshape(-1, 4, 4)


def _score(scene: Any, poses: np.ndarray) -> SceneScore:
    return score_scene(poses, scene.poses, 15.0, scene.max_translation)


def _scores(
    scenes: list[Any], rows: list[np.ndarray], base: dict | None, net: Any = None
) -> list[SceneScore]:
    """Each scene registered on its `rows` alone, at `base` thresholds (None: defaults), with
    network `net`'s embedding if given."""
    cfg = None if base is None else pointclm.Config(**base)
    return [_score(s, _register(s, r, cfg, net)) for s, r in zip(scenes, rows, strict=True)]


def _mf(scores: list[SceneScore]) -> float:
    return 100 * summarize(scores).mean_f1


def _best_config(
    scenes: list[Any], rows: list[np.ndarray], net: Any = None, grid: list[dict] = GRID
) -> tuple[dict[str, Any], list[SceneScore]]:
    runs = [(cfg, _scores(scenes, rows, cfg, net)) for cfg in grid]
    return max(runs, key=lambda run: _mf(run[1]))


def _kept(score: np.ndarray, share: float) -> np.ndarray:
    return np.sort(np.argsort(-score, kind="stable")[: max(3, int(round(share * len(score))))])


def learned_rows(
    scenes: list[Any], feats: list[np.ndarray], labels: list[np.ndarray], seed: int = 0
) -> tuple[list[SceneScore], list[np.ndarray], list[str], float]:
    """Two folds by scene: fit on one, pick the kept share and thresholds on its out-of-fold
    scores, apply to the other. Returns each scene's score and its rows' scores (from the fold
    that did not see it), the choices and the test AUC."""
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.metrics import roc_auc_score

    def fit(idx: list[int]) -> Any:
        x = np.concatenate([feats[i] for i in idx])
        y = np.concatenate([labels[i] for i in idx])
        return HistGradientBoostingClassifier(max_iter=200, random_state=seed).fit(x, y)

    def proba(model: Any, i: int) -> np.ndarray:
        return model.predict_proba(feats[i])[:, 1]

    out: list[Any] = [None] * len(scenes)
    held: list[Any] = [None] * len(scenes)
    choices, truth, pred = [], [], []
    for fold in (0, 1):
        train = [i for i in range(len(scenes)) if i % 2 == fold]
        test = [i for i in range(len(scenes)) if i % 2 != fold]
        # honest scores on the training fold: each half scored by a model of the other half
        oof: dict[int, np.ndarray] = {}
        for inner in (0, 1):
            a = [i for k, i in enumerate(train) if k % 2 == inner]
            b = [i for k, i in enumerate(train) if k % 2 != inner]
            m = fit(a)
            oof.update({i: proba(m, i) for i in b})
        mine = [scenes[i] for i in train]
        share, cfg, _ = max(
            ((k, *_best_config(mine, [_kept(oof[i], k) for i in train])) for k in KEEP),
            key=lambda t: _mf(t[2]),
        )
        choices.append(f"fold {fold}: keep {share:.0%}, {cfg}")
        model = fit(train)
        for i in test:
            p = proba(model, i)
            truth.append(labels[i])
            pred.append(p)
            held[i] = p
            (out[i],) = _scores([scenes[i]], [_kept(p, share)], cfg)
    auc = float(roc_auc_score(np.concatenate(truth), np.concatenate(pred)))
    return out, held, choices, auc


def network_rows(
    model: str, scenes: list[Any], everything: list[np.ndarray], held: list[np.ndarray]
) -> list[str]:
    """A network against training-free on the scenes of models it never trained on, each at
    its best grid thresholds, on all rows and on the rows the learned score ranks first."""
    from pointclm.embedding import resolve
    from pointclm.training.config import REALISTIC_MODELS, TRAIN_SHAPES

    from benchmarks.clouds.realistic_thresholds import trained_on

    net = resolve(model)
    trained = trained_on(model, (*TRAIN_SHAPES, *REALISTIC_MODELS))
    idx = [i for i, s in enumerate(scenes) if s.model not in trained]
    mine = [scenes[i] for i in idx]
    out = [
        f"Network `{model}` on the {len(idx)} scenes of models it did not train on "
        "(best grid thresholds each):",
        "",
        "| rows | training-free | network |",
        "|---|---|---|",
    ]
    for share in (1.0, 0.5, 0.3):
        rows = [everything[i] if share == 1 else _kept(held[i], share) for i in idx]
        cells = [_mf(_best_config(mine, rows, embedding)[1]) for embedding in (None, net)]
        label = "all" if share == 1 else f"the learned score's first {share:.0%}"
        out.append(f"| {label} | {cells[0]:.1f} | {cells[1]:.1f} |")
    return [*out, ""]


def _group(scene: Any) -> str:
    return "procedural" if is_procedural(scene.model) else scene.model


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument(
        "--models",
        default="stanford/dragon,stanford/happy,stanford/armadillo,modelnet/bathtub,modelnet/bed",
    )
    ap.add_argument("--scenes-per-model", type=int, default=20)
    ap.add_argument("--procedural", type=int, default=30)
    ap.add_argument("--scenes-per-shape", type=int, default=2)
    ap.add_argument("--n", type=int, default=1000, help="correspondences per scene")
    ap.add_argument("--cache", default="out/realistic_scenes", help="built scenes (npz)")
    ap.add_argument("--data-dir", default=None)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--model", action="append", default=[], help="network(s) to compare")
    ap.add_argument("--out", help="write the table as markdown")
    args = ap.parse_args()
    from pointclm.datasets.scenes import VALIDATION_MODELS

    models = [m.strip() for m in args.models.split(",") if m.strip()]
    bad = [m for m in models if m not in VALIDATION_MODELS]
    if bad:
        raise SystemExit(f"not validation models: {', '.join(bad)}")
    t0 = time.perf_counter()
    jobs = validation_jobs(
        models, args.scenes_per_model, args.procedural, args.scenes_per_shape, args.n,
        data_folder(args.data_dir),
    )  # fmt: skip
    scenes = load_scenes(jobs, Path(args.cache), args.workers)
    labels = [(s.labels >= 0).astype(int) for s in scenes]
    inliers = [np.flatnonzero(y) for y in labels]
    everything = [np.arange(len(s.labels)) for s in scenes]
    rng = np.random.default_rng(0)

    def less_outliers(share: float) -> list[np.ndarray]:
        out = []
        for y in labels:
            bad_rows = np.flatnonzero(y == 0)
            drop = rng.choice(bad_rows, int(share * len(bad_rows)), replace=False)
            out.append(np.setdiff1d(np.arange(len(y)), drop))
        return out

    rows: dict[str, list[SceneScore]] = {}
    rows["training-free, defaults"] = _scores(scenes, everything, None)
    cfg, scores = _best_config(scenes, everything)
    rows[f"training-free, best grid thresholds {cfg}"] = scores
    for share in (0.5, 0.9):
        rows[f"oracle: {share:.0%} of the outliers removed, defaults"] = _scores(
            scenes, less_outliers(share), None
        )
    rows["oracle: only the true inliers, defaults"] = _scores(scenes, inliers, None)
    cfg, scores = _best_config(scenes, inliers)
    rows[f"oracle: only the true inliers, best grid thresholds {cfg}"] = scores
    # without outliers the a-contrario test (which guards against them) only costs copies
    free = [{**g, "max_nfa": None} for g in GRID]
    cfg, scores = _best_config(scenes, inliers, grid=free)
    rows[f"oracle: only the true inliers, best grid thresholds {cfg}"] = scores
    feats = [row_features(s) for s in scenes]
    learned, held, choices, auc = learned_rows(scenes, feats, labels)
    rows["learned inlier score (2 folds), kept share and thresholds picked per fold"] = learned
    rows["oracle embedding (true instances), ORACLE_CONFIG"] = [
        _score(s, oracle(False)(s)) for s in scenes
    ]
    from sklearn.metrics import roc_auc_score

    y_all = np.concatenate(labels)
    degree = np.concatenate([f[:, DEGREE_COLUMN] for f in feats])
    groups = sorted({_group(s) for s in scenes}, key=lambda g: (g == "procedural", g))
    head = ["row", *groups, "pooled"]
    lines = [
        f"Validation scenes: {len(scenes)} ({', '.join(groups)}); "
        f"{100 * y_all.mean():.1f} % of the rows are inliers.",
        "",
        "| " + " | ".join(head) + " |",
        "|---|" + "---|" * (len(head) - 1),
    ]  # fmt: skip
    per_copy = {
        g: np.concatenate(
            [
                np.bincount(s.labels[s.labels >= 0], minlength=s.n_instances)
                for s in scenes
                if _group(s) == g
            ]
        )
        for g in groups
    }
    lines.append(
        "| true inliers per copy, median (share of copies with 3 or more) | "
        + " | ".join(f"{np.median(c):.0f} ({np.mean(c >= 3):.0%})" for c in per_copy.values())
        + f" | {np.median(np.concatenate(list(per_copy.values()))):.0f} |"
    )
    for name, scores in rows.items():
        cells = [
            f"{_mf([sc for sc, s in zip(scores, scenes, strict=True) if _group(s) == g]):.1f}"
            for g in groups
        ]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | **{_mf(scores):.1f}** |")
    lines += [
        "",
        f"Learned inlier score: test AUC {auc:.3f} (the 1-voxel normal-consistent degree alone: "
        f"{roc_auc_score(y_all, degree):.3f}); picks: {'; '.join(choices)}.",
        "",
    ]
    for model in args.model:
        lines += network_rows(model, scenes, everything, held)
    lines += [
        f"{platform.machine()}, {os.cpu_count()} cores, {time.strftime('%Y-%m-%d')}, "
        f"{time.perf_counter() - t0:.0f} s. MF in %, paper definition.",
    ]
    text = "\n".join(lines)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()

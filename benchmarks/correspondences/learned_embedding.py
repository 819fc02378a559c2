"""Learned embedding vs training-free, on data the networks never trained on.

1. Validation sweep (the shapes held out from training: stanford/armadillo, modelnet/bed) of
   the pruning thresholds tau_s x tau_n with each shipped network; this is where the
   `recommended_config` in the weights' JSON comes from.
2. Test: the synthetic protocol on the bunny (never trained on), training-free vs each
   network with its recommended thresholds, with the network's forward time and the whole
   pipeline's time per scene on this CPU.

    python -m benchmarks.correspondences.learned_embedding [--scenes 500] [--val-scenes 96]
        [--threads 2]

Needs torch and the training meshes' shape bank (written by `pointclm train`; rebuilt from
`--data-dir ../shared/data` if missing).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pointclm
import torch
from pointclm.datasets import make_scenes
from pointclm.metrics import Summary, score_scene, summarize
from pointclm.model import load_metadata, load_model
from pointclm.training.config import TrainConfig
from pointclm.training.data import ShapeBank
from pointclm.training.loop import validation_scenes


def features_of(model, scenes):
    out, seconds = [], []
    with torch.no_grad():
        for s in scenes:
            t = time.perf_counter()
            x = torch.tensor(s.correspondences, dtype=torch.float32)[None]
            out.append(model(x)[0].double().numpy())
            seconds.append(time.perf_counter() - t)
    return out, np.asarray(seconds)


def score(scenes, feats, config):
    return summarize(
        score_scene(pointclm.register(s.correspondences, f, config).transformations, s.poses)
        for s, f in zip(scenes, feats, strict=True)
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=500)
    ap.add_argument("--val-scenes", type=int, default=96)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--data-dir", default="../shared/data")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    cfg = TrainConfig.preset("compact-gpu", val_scenes=args.val_scenes, data_dir=args.data_dir)
    bank = ShapeBank.build([*cfg.val_shapes], args.data_dir, cfg.seed)
    val = validation_scenes(cfg, bank)
    test = list(make_scenes(args.scenes, seed=0))
    header = f"| {'':<28} | " + " | ".join(("MR", "MP", "MF", "strict F1")) + " |"

    def row(name: str, s: Summary, extra: str = "") -> str:
        v = (s.mean_recall, s.mean_precision, s.mean_f1, s.strict_f1)
        return f"| {name:<28} | " + " | ".join(f"{100 * x:.2f}" for x in v) + f" |{extra}"

    print(f"## Validation sweep ({len(val)} scenes of {', '.join(cfg.val_shapes)})\n")
    print(header)
    print("|" + "---|" * 5)
    print(row("training-free", score(val, [None] * len(val), pointclm.Config())))
    for name in ("default", "paper"):
        feats, _ = features_of(load_model(name), val)
        for tau_s in (0.75, 0.8, 0.85, 0.9):
            for tau_n in (5, 10):
                c = pointclm.Config(tau_s=tau_s, tau_n=tau_n)
                print(row(f"{name} tau_s={tau_s} tau_n={tau_n}", score(val, feats, c)))

    print(f"\n## Test: synthetic protocol, bunny, {len(test)} scenes, {args.threads} threads\n")
    print(header[:-1] + "| forward ms | pipeline ms |")
    print("|" + "---|" * 7)
    t_free = []
    for s in test:
        t = time.perf_counter()
        pointclm.register(s.correspondences)
        t_free.append(time.perf_counter() - t)
    print(
        row(
            "training-free",
            score(test, [None] * len(test), pointclm.Config()),
            f" - | {1e3 * np.median(t_free):.1f} |",
        )
    )
    for name in ("default", "paper"):
        model = load_model(name)
        config = pointclm.Config(**load_metadata(name)["recommended_config"])
        feats, fwd = features_of(model, test)
        total = []
        for s, f in zip(test, feats, strict=True):
            t = time.perf_counter()
            pointclm.register(s.correspondences, f, config)
            total.append(time.perf_counter() - t)
        arch = model.config
        label = f"{name} ({arch.depth}x{arch.width})"
        pipeline_ms = 1e3 * np.median(fwd + np.asarray(total))
        print(
            row(
                label,
                score(test, feats, config),
                f" {1e3 * np.median(fwd):.1f} | {pipeline_ms:.1f} |",
            )
        )


if __name__ == "__main__":
    main()

"""The paper's ablations, with our code on the synthetic benchmark (bunny, never trained on).

- Table 3: with / without the embedding, with / without pruning.
- Table 4: 5 / 50 / 500 RANSAC iterations.
- Table 5: hardest vs random negatives (two networks trained alike but for the negatives),
  with the mean cosine similarity of positives and of each anchor's top-1 / top-10 hardest
  negatives.
- Tables 8 and 10: tau_S and tau_N sweeps.

    python -m benchmarks.correspondences.ablations [--scenes 200] [--model default]
        [--negatives-pair HARDEST.safetensors RANDOM.safetensors]

Reported for information: the defaults were chosen on validation shapes, not from these tables.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pointclm
import torch
from pointclm.datasets import make_scenes
from pointclm.metrics import score_scene, summarize
from pointclm.model import load_metadata, load_model


def embed_all(model, scenes):
    with torch.no_grad():
        return [
            model(torch.tensor(s.correspondences, dtype=torch.float32)[None])[0].double().numpy()
            for s in scenes
        ]


def row(name, scenes, feats, config):
    t = time.perf_counter()
    scores = [
        score_scene(pointclm.register(s.correspondences, f, config).transformations, s.poses)
        for s, f in zip(scenes, feats, strict=True)
    ]
    ms = 1e3 * (time.perf_counter() - t) / len(scenes)
    m = summarize(scores)
    vals = (m.mean_recall, m.mean_precision, m.mean_f1, m.strict_f1)
    return f"| {name} | " + " | ".join(f"{100 * v:.2f}" for v in vals) + f" | {ms:.1f} |"


HEAD = "| | MR | MP | MF | strict F1 | ms/scene (no forward) |\n|---|---|---|---|---|---|"


def cosine_stats(feats, scenes):
    """Mean cosine of positive pairs and of each inlier's top-1 / top-10 hardest negatives."""
    pos, top1, top10 = [], [], []
    for f, s in zip(feats, scenes, strict=True):
        lab = s.labels
        cos = f @ f.T
        for i in np.flatnonzero(lab >= 0):
            same = (lab == lab[i]) & (np.arange(len(lab)) != i)
            neg = np.sort(cos[i, lab != lab[i]])[::-1]
            if same.any():
                pos.append(cos[i, same].mean())
            top1.append(neg[0])
            top10.append(neg[:10].mean())
    return np.mean(pos), np.mean(top1), np.mean(top10)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=200)
    ap.add_argument("--model", default="default")
    ap.add_argument("--negatives-pair", nargs=2, metavar=("HARDEST", "RANDOM"))
    ap.add_argument("--only-negatives", action="store_true", help="just Table 5")
    args = ap.parse_args()
    torch.set_num_threads(2)
    scenes = list(make_scenes(args.scenes, seed=0))
    model = load_model(args.model)
    rec = (
        load_metadata(args.model).get("recommended_config", {})
        if isinstance(args.model, str)
        else {}
    )
    feats = embed_all(model, scenes)
    none = [None] * len(scenes)
    base = pointclm.Config(**rec)
    if not args.only_negatives:
        tables_3_4_8_10(args, scenes, feats, none, rec, base)
    if args.negatives_pair:
        table_5(args.negatives_pair, scenes, base)


def tables_3_4_8_10(args, scenes, feats, none, rec, base) -> None:
    print(f"## Table 3: embedding and pruning ({len(scenes)} scenes; network {args.model!r})\n")
    print(HEAD)
    few = scenes[: max(1, len(scenes) // 4)]
    print(row("embedding + pruning", scenes, feats, base))
    print(row("no embedding (S = beta) + pruning", scenes, none, pointclm.Config()))
    print(
        row(
            f"embedding, no pruning ({len(few)} scenes)",
            few,
            feats[: len(few)],
            pointclm.Config(**rec, pruning="none"),
        )
    )
    print(
        row(
            f"no embedding, no pruning ({len(few)} scenes)",
            few,
            none[: len(few)],
            pointclm.Config(pruning="none"),
        )
    )

    print("\n## Table 4: RANSAC iterations (with the embedding)\n")
    print(HEAD)
    for it in (5, 50, 500):
        cfg = pointclm.Config(**{**rec, "ransac_iterations": it, "ransac_confidence": 1.0})
        print(row(f"{it} iterations", scenes, feats, cfg))

    print("\n## Tables 8 and 10: tau_S and tau_N (with the embedding)\n")
    print(HEAD)
    for tau_s in (0.75, 0.8, 0.85, 0.9, 0.95):
        print(row(f"tau_S = {tau_s}", scenes, feats, pointclm.Config(**{**rec, "tau_s": tau_s})))
    for tau_n in (3, 5, 10, 15, 20):
        print(row(f"tau_N = {tau_n}", scenes, feats, pointclm.Config(**{**rec, "tau_n": tau_n})))


def table_5(pair, scenes, base) -> None:
    """Two networks trained alike but for the negatives, scored with the same thresholds."""
    print("\n## Table 5: hardest vs random negatives\n")
    print(
        "| negatives | MR | MP | MF | strict F1 | ms/scene | cos positives | cos top-1 "
        "negative | cos top-10 negatives |\n|---|---|---|---|---|---|---|---|---|"
    )
    for name, path in zip(("hardest", "random"), pair, strict=True):
        f = embed_all(load_model(path), scenes)
        p, t1, t10 = cosine_stats(f, scenes)
        print(row(name, scenes, f, base) + f" {p:.3f} | {t1:.3f} | {t10:.3f} |")


if __name__ == "__main__":
    main()

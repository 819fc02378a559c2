"""The realistic benchmark over every model: pointclm vs sequential robust solvers on the same
correspondences, per model and pooled, at N = 1000 or 5000, and one timed N = 50,000 run.

    pip install ".[bench]"      # the peers, KISS-Matcher and Open3D (benchmarks/common/peers.py)
    python -m benchmarks.clouds.realistic_models                              # N = 1000, all models
    python -m benchmarks.clouds.realistic_models --n 5000 --scenes-per-model 4 --scale 0 \\
        --out benchmarks/results/clouds/realistic_models_n5000.md
    python -m benchmarks.clouds.realistic_models --quick                      # CI-sized

**Models and the split** (``pointclm.datasets.scenes``): the HEADLINE pools the HELD-OUT models
(``HELDOUT_MODELS``: the Stanford bunny with its real range scans, and the six common3d
meshes), which never pick a threshold. The VALIDATION models (``VALIDATION_MODELS``: dragon,
happy, armadillo, bathtub, bed and the procedural shapes) are where thresholds and defaults
are chosen (`benchmarks.clouds.realistic_thresholds`); they are reported apart, as in-sample
figures.
Pooled rows weight every scene alike (the same count per model).

**Seeds.** Model ``m``'s benchmark scenes are ``make_realistic_scene(seed)`` for the seeds
``benchmark_seeds(m, n)`` = 1,000,000 + 1000 x slot(m) + k, k = 0..n - 1, where slot(m) is
m's place in ``HELDOUT_MODELS + VALIDATION_MODELS`` (so models do not share layouts).
Disjoint from every other scene source: `benchmarks.clouds.realistic_thresholds` uses
``threshold_seeds`` = 2,000,000 + 1000 x slot + k; the training and training-time
validation banks use ``training.realistic.scene_seed`` (62-bit hashes; a test checks that
the banks' default seeds miss both ranges); the bunny benchmark (`benchmarks.clouds.realistic`)
and the tests use small seeds (0..99). The N = 5000 scenes are the same scenes (same seeds, same
layout) matched differently.

**Correspondences.** N = 1000: the scenes' default (FPFH, mutual nearest neighbours, top
10,000, at most 1000 drawn; a median of about 400 survive the mutual filter). N > 1000: the
mutual filter off and the top N matches by descriptor distance kept, none drawn away.
``--descriptor learned`` (or a descriptor file) matches by the learned descriptor instead, over
the same points and normals (``SceneParams.descriptor``).
An instance is registered when RE < 15 deg and TE < 10 % of the model's diagonal.

**Methods**, all on the same correspondences of a scene, pointclm on one thread:
- pointclm, training-free, correspondence stage alone: ``pointclm.register`` with the
  default config scaled to the voxel, no clouds (the headline row);
- the same with its poses refined and verified on the clouds (``refine_poses``, with the
  thresholds for refined poses, as ``register_point_clouds`` does);
- ``--model NAME``: a learned embedding, raw and refined (optional);
- an upper bound, not a method: an embedding from the true labels (the oracle of
  `benchmarks.clouds.realistic`);
- sequential KISS-Matcher and sequential Open3D RANSAC (`benchmarks.common.peers`): inlier
  radius 2 voxels (the scenes' inlier definition), stop below pointclm's ``min_cluster_size``
  inliers or at 10 poses. ``--quick`` leaves RANSAC out (seconds per scene), ``--no-ransac`` and
  ``--no-kiss`` leave either out. A peer that is not installed stops the run before any
  scene is built, naming the package; ``--skip-missing-peers`` leaves it out instead (said
  at the start, and its row is then absent from the report).
Times are per scene, wall clock, everything a method does (refinement included).

**N = 50,000** (``--scale``, default 50,000; 0 skips): realistic correspondences, not planted:
one bunny scene and one common3d scene, 8 copies and 3 clutter objects, voxel = diagonal /
80 so that the scan has enough points, the mutual filter off, the top N matches kept. Each is
registered training-free (correspondences alone) in a fresh child process, which reports the
time and the peak RSS (``ru_maxrss``; baseline after loading the scene), on 1 thread and on
all cores, under an 8 GB address-space limit.

**Cache.** Built scenes are kept as ``.npz`` (no pickle) under ``--cache`` (default
``out/realistic_scenes``), keyed by model, seed and scene parameters; delete the folder
when ``datasets/scenes.py`` or the FPFH code changes.

Results: a markdown report (``--out``, default ``out/realistic_models.md``, not committed;
``--out benchmarks/results/clouds/realistic_models.md`` replaces the committed one) with date,
command, hardware, git commit, and a JSON file beside it holding every scene's score and time
per method.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.clouds.methods import Method, make_methods, peers_to_run, run_methods
from benchmarks.clouds.scale import run_scale
from benchmarks.clouds.scenes import (
    BENCHMARK_SEED_BASE,
    benchmark_seeds,
    load_scenes,
    scene_params,
    threshold_seeds,
)
from benchmarks.common import report

QUICK_MODELS = ("stanford/bunny", "common3d/spot", "stanford/armadillo", "torus")
DEFAULT_OUT = "out/realistic_models.md"


def summary(rows: Sequence[dict[str, Any]]) -> dict[str, float]:
    """MR, MP, MF (paper), strict F1, predictions / GT (totals over the scenes), median and
    p90 ms of one method's records."""
    from pointclm.metrics import SceneScore, summarize

    fields = {f.name for f in dataclasses.fields(SceneScore)}
    s = summarize([SceneScore(**{k: v for k, v in r.items() if k in fields}) for r in rows])
    secs = np.array([r["seconds"] for r in rows])
    return {
        "MR": 100 * s.mean_recall,
        "MP": 100 * s.mean_precision,
        "MF": 100 * s.mean_f1,
        "strict F1": 100 * s.strict_f1,
        "pred/GT": sum(r["n_pred"] for r in rows) / max(sum(r["n_gt"] for r in rows), 1),
        "median ms": 1e3 * float(np.median(secs)),
        "p90 ms": 1e3 * float(np.percentile(secs, 90)),
        "scenes": len(rows),
    }


def _table(rows: Sequence[dict[str, Any]], methods: Sequence[Method]) -> list[str]:
    out = [
        "| method | MR | MP | MF (paper) | strict F1 | pred / GT | median ms | p90 ms |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for m in methods:
        mine = [r for r in rows if r["method"] == m.key]
        if not mine:
            continue
        s = summary(mine)
        out.append(
            f"| {m.label} | {s['MR']:.2f} | {s['MP']:.2f} | {s['MF']:.2f} | "
            f"{s['strict F1']:.2f} | {s['pred/GT']:.2f} | {s['median ms']:.1f} | "
            f"{s['p90 ms']:.1f} |"
        )
    return out


def _per_model(
    rows: Sequence[dict[str, Any]], methods: Sequence[Method], models: Sequence[str], stat: str
) -> list[str]:
    fmt = "{:.2f}" if stat == "pred/GT" else "{:.1f}"
    out = [
        "| model | " + " | ".join(m.key for m in methods) + " |",
        "|---|" + "---|" * len(methods),
    ]
    for model in models:
        cells = []
        for m in methods:
            mine = [r for r in rows if r["method"] == m.key and r["model"] == model]
            cells.append(fmt.format(summary(mine)[stat]) if mine else "-")
        out.append(f"| {model} | " + " | ".join(cells) + " |")
    return out


def scene_stats(scenes: Sequence[Any], models: Sequence[str]) -> list[str]:
    """Per model: correspondences, instances, inliers per instance, scene points, build time."""
    out = [
        "| model | split | scenes | median corr. | instances / scene | median inliers per "
        "instance | instances with < 3 inliers | median scene points | median build s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    from pointclm.datasets.scenes import HELDOUT_MODELS

    for model in models:
        mine = [s for s in scenes if s.model == model]
        if not mine:
            continue
        inl = np.concatenate(
            [np.bincount(s.labels[s.labels >= 0], minlength=s.n_instances) for s in mine]
        )
        out.append(
            f"| {model} | {'held-out' if model in HELDOUT_MODELS else 'validation'} | "
            f"{len(mine)} | {int(np.median([len(s.correspondences) for s in mine]))} | "
            f"{np.mean([s.n_instances for s in mine]):.1f} | {np.median(inl):.0f} | "
            f"{100 * np.mean(inl < 3):.0f} % | "
            f"{int(np.median([len(s.target_points) for s in mine]))} | "
            f"{np.median([s.timings.get('total', np.nan) for s in mine]):.2f} |"
        )
    return out


# --- main -----------------------------------------------------------------------------------


def _resolve_models(spec: str) -> list[str]:
    from pointclm.datasets.scenes import HELDOUT_MODELS, VALIDATION_MODELS

    groups = {
        "all": [*HELDOUT_MODELS, *VALIDATION_MODELS],
        "heldout": list(HELDOUT_MODELS),
        "validation": list(VALIDATION_MODELS),
    }
    out: list[str] = []
    for part in (p.strip() for p in spec.split(",") if p.strip()):
        for m in groups.get(part, [part]):
            if m not in HELDOUT_MODELS and m not in VALIDATION_MODELS:
                raise SystemExit(
                    f"unknown model {m!r}: use all, heldout, validation or names from "
                    f"{', '.join(groups['all'])}"
                )
            if m not in out:
                out.append(m)
    return out


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--models", default="all", help="all, heldout, validation, or names")
    ap.add_argument("--scenes-per-model", type=int, default=8)
    ap.add_argument("--n", type=int, default=1000, help="correspondences per scene (1000, 5000)")
    ap.add_argument("--model", action="append", default=[], help="learned embedding(s)")
    ap.add_argument("--backend", default="rust", choices=["rust", "torch"], help="of --model")
    ap.add_argument("--config", help="JSON thresholds: one more training-free row, raw poses")
    ap.add_argument("--refined-config", help="JSON thresholds: one more refined row")
    ap.add_argument("--scale", type=int, default=50_000, help="N of the timed run (0: skip)")
    ap.add_argument("--no-ransac", action="store_true", help="leave the slow RANSAC peer out")
    ap.add_argument("--no-kiss", action="store_true", help="leave the KISS-Matcher peer out")
    ap.add_argument(
        "--skip-missing-peers",
        action="store_true",
        help="leave out the peers that are not installed (default: stop, naming them)",
    )
    ap.add_argument(
        "--descriptor",
        default="fpfh",
        help="what the scenes are matched by: fpfh (default), learned, or a descriptor file",
    )
    ap.add_argument("--quick", action="store_true", help="CI-sized: 2 scenes of 4 models")
    ap.add_argument("--cache", default="out/realistic_scenes")
    ap.add_argument("--data-dir", default=None, help="default: $POINTCLM_DATA_DIR or ../shared")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument(
        "--out",
        default=DEFAULT_OUT,
        help=f"the report (default {DEFAULT_OUT}; benchmarks/results/ holds the committed ones)",
    )
    ap.add_argument(
        "--seeds",
        choices=("benchmark", "threshold"),
        default="benchmark",
        help="benchmark_seeds (the reported scenes) or threshold_seeds (the scenes defaults "
        "are chosen on; with --models validation, the validation set of BENCHMARKS.md)",
    )
    args = ap.parse_args(argv)

    from pointclm.datasets.scenes import HELDOUT_MODELS, VALIDATION_MODELS, default_data_dir

    if args.quick:
        args.models = ",".join(QUICK_MODELS) if args.models == "all" else args.models
        args.scenes_per_model = min(args.scenes_per_model, 2)
        args.scale, args.no_ransac = 0, True
    models = _resolve_models(args.models)
    kiss, ransac = peers_to_run(not args.no_kiss, not args.no_ransac, args.skip_missing_peers)
    data_dir = args.data_dir or (str(default_data_dir()) if default_data_dir() else None)
    if data_dir is None and any("/" in m for m in models):
        raise SystemExit("the data folder is missing: pass --data-dir or set POINTCLM_DATA_DIR")
    cache = Path(args.cache)
    load0 = os.getloadavg()[0]
    t_start = time.perf_counter()

    pick = threshold_seeds if args.seeds == "threshold" else benchmark_seeds
    seeds = {m: pick(m, args.scenes_per_model) for m in models}
    jobs = [
        (m, s, scene_params(m, args.n, data_dir, args.descriptor)) for m in models for s in seeds[m]
    ]
    scenes = load_scenes(jobs, cache, args.workers)
    configs = [
        (key, json.loads(text), refine)
        for key, text, refine in (
            ("pointclm-config", args.config, False),
            ("pointclm-config+refine", args.refined_config, True),
        )
        if text
    ]
    methods = make_methods(args.model, ransac, kiss, args.backend, configs)
    print(f"{len(scenes)} scenes, methods: {', '.join(m.key for m in methods)}", flush=True)
    rows = run_methods(scenes, methods)
    scale_lines = (
        run_scale(args.scale, cache, data_dir, args.workers, models=args.model)
        if args.scale
        else []
    )

    import pointclm

    held = [m for m in models if m in HELDOUT_MODELS]
    desc_name = "FPFH" if args.descriptor == "fpfh" else f"the {args.descriptor} descriptor"
    val = [m for m in models if m in VALIDATION_MODELS]
    cmd = report.command(__spec__.name, argv)
    minutes = (time.perf_counter() - t_start) / 60
    lines = [
        f"# Realistic benchmark over the models, N = {args.n}",
        "",
        f"- Date: {report.utc_now()}. Command: `{cmd}`.",
        f"- Hardware: {report.hardware()} "
        f"(load average {load0:.1f} at the start: times are wall clock on a shared machine). "
        "pointclm on 1 thread; KISS-Matcher and Open3D with their default threads.",
        f"- Code: pointclm {pointclm.__version__}, git {report.git_commit(dirty=True)}.",
        f"- Scenes: {args.scenes_per_model} per model, model i (in the order below) seeds "
        f"{BENCHMARK_SEED_BASE} + 1000 i + 0..{args.scenes_per_model - 1} "
        "(disjoint from threshold and training scenes); "
        + (
            f"{desc_name}, mutual nearest neighbours, top 10,000, at most {args.n} drawn"
            if args.n <= 1000
            else f"{desc_name}, no mutual filter, the top {args.n} matches"
        )
        + ". An instance is registered when RE < 15 deg and TE < 10 % of the model's diagonal. "
        "pred / GT: predicted instances over true instances, totals over the scenes.",
        f"- The whole run took {minutes:.1f} min (scenes from the cache where present).",
        "",
    ]
    if held:
        lines += [
            f"## Headline: pooled over the held-out models ({', '.join(held)})",
            "",
            "No threshold or default was chosen on these models.",
            "",
            *_table([r for r in rows if r["model"] in held], methods),
            "",
        ]
    if val:
        lines += [
            f"## Validation models, pooled ({', '.join(val)})",
            "",
            "In-sample: thresholds and defaults are picked on these models "
            "(`realistic_thresholds`, on other seeds), so these are not results.",
            "",
            *_table([r for r in rows if r["model"] in val], methods),
            "",
        ]
    order = held + val
    lines += [
        "## Per model",
        "",
        "Columns: " + "; ".join(f"`{m.key}` = {m.label}" for m in methods) + ".",
        "",
        "MF (paper):",
        "",
        *_per_model(rows, methods, order, "MF"),
        "",
        "Predictions / ground truth:",
        "",
        *_per_model(rows, methods, order, "pred/GT"),
        "",
        "Median ms per scene:",
        "",
        *_per_model(rows, methods, order, "median ms"),
        "",
        "Scenes:",
        "",
        *scene_stats(scenes, order),
        "",
    ]
    lines += scale_lines
    text = "\n".join(lines).rstrip() + "\n"
    print(text)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    meta = {"command": cmd, "methods": {m.key: m.label for m in methods}, "rows": rows}
    out.with_suffix(".json").write_text(json.dumps(meta, indent=0) + "\n")
    print(f"report written to {out} (and {out.with_suffix('.json').name} beside it)")


if __name__ == "__main__":
    main()

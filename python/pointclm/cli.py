"""`pointclm` command line: `demo` on built-in data, `eval` on a benchmark."""

from __future__ import annotations

import argparse
import functools
import json
import sys
from collections.abc import Sequence

import numpy as np

from . import __version__
from .config import Config
from .datasets import make_scenes
from .evaluation import evaluate
from .metrics import Summary, rotation_error_deg, score_scene, summarize
from .registration import register


def _config(args: argparse.Namespace) -> Config | None:
    kw = {}
    for name in ("pruning", "assignment", "ransac_iterations", "sigma_d", "inlier_threshold"):
        value = getattr(args, name, None)
        if value is not None:
            kw[name] = value
    # No flags and a model: let the network's recommended thresholds apply.
    if not kw and getattr(args, "model", None):
        return None
    return Config(**kw)


def _add_config_flags(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("method (defaults: pointclm.Config())")
    g.add_argument("--pruning", choices=["paper", "authors", "none"])
    g.add_argument("--assignment", choices=["kmeans", "discretize"])
    g.add_argument("--ransac-iterations", type=int, dest="ransac_iterations")
    g.add_argument("--sigma-d", type=float, dest="sigma_d")
    g.add_argument("--inlier-threshold", type=float, dest="inlier_threshold")
    p.add_argument("--seed", type=int, default=0, help="dataset and method seed (default 0)")
    p.add_argument("--num-threads", type=int, default=None, help="threads (default: all)")
    p.add_argument(
        "--model",
        help="learned embedding: default, paper or a weight file (run by the Rust core); "
        "omit for the training-free pipeline",
    )


def cmd_demo(args: argparse.Namespace) -> int:
    config = _config(args)
    method = (
        f"PointCLM with the {args.model!r} embedding" if args.model else ("training-free PointCLM")
    )
    print(f"pointclm {__version__}: {method} on the paper's synthetic protocol")
    print("source: 256 points of the Stanford bunny (bundled); target: 5-10 noisy copies among")
    print("98% outlier correspondences (1000 rows per scene)\n")
    scores = []
    for k, scene in enumerate(make_scenes(args.scenes, seed=args.seed)):
        result = register(
            scene.correspondences,
            config=config,
            seed=args.seed,
            num_threads=args.num_threads,
            model=args.model,
        )
        score = score_scene(result.transformations, scene.poses)
        scores.append(score)
        total_ms = 1e3 * sum(result.timings.values())
        print(
            f"scene {k}: {len(scene.poses)} copies, {int((scene.labels >= 0).sum())} inlier "
            f"correspondences -> found {len(result)} instances, "
            f"{score.n_matched} correct, {total_ms:.1f} ms"
        )
        for i, inst in enumerate(result.instances):
            T = inst.transformation
            errs = rotation_error_deg(T[None, :3, :3], scene.poses[:, :3, :3])
            dist = np.linalg.norm(scene.poses[:, :3, 3] - T[:3, 3], axis=1)
            best = int(np.argmin(dist))
            print(
                f"    [{i}] t = ({T[0, 3]:6.3f}, {T[1, 3]:6.3f}, {T[2, 3]:6.3f})  "
                f"inliers {len(inst):3d}  rmse {inst.inlier_rmse:.4f}  "
                f"vs nearest true pose: RE {errs[best]:5.2f} deg, TE {dist[best]:.4f}"
            )
    print()
    print(Summary.table_header())
    print(summarize(scores).as_row(f"pointclm ({args.model or 'training-free'})"))
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    if args.dataset != "synthetic":
        print(f"unknown dataset {args.dataset!r}", file=sys.stderr)
        return 2
    config = _config(args)
    shapes = args.shapes.split(",") if args.shapes else None
    scenes = make_scenes(
        args.scenes,
        seed=args.seed,
        shapes=shapes,
        n_outlier_blocks=args.outlier_blocks,
        data_dir=args.data_dir,
    )
    bar = functools.partial(
        tqdm, total=args.scenes, desc="scenes", unit="scene", disable=args.scenes < 20 or args.quiet
    )
    ev = evaluate(
        scenes, config, seed=args.seed, num_threads=args.num_threads, progress=bar, model=args.model
    )
    print(f"{Summary.table_header()} {'med ms':>7} {'p90 ms':>7}")
    name = f"pointclm ({args.model})" if args.model else "pointclm"
    print(f"{ev.summary.as_row(name)} {ev.median_ms:7.2f} {ev.p90_ms:7.2f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(
                {
                    "config": config.to_dict() if config else None,
                    "model": args.model,
                    "dataset": args.dataset,
                    "scenes": args.scenes,
                    "seed": args.seed,
                    **ev.as_dict(),
                },
                fh,
                indent=2,
            )
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    try:
        from .training import TrainConfig, train
    except ImportError as e:
        print(f"pointclm train needs torch: pip install 'pointclm[train]' ({e})", file=sys.stderr)
        return 2
    overrides = {
        k: v
        for k, v in (
            ("data_dir", args.data_dir),
            ("shape_bank", args.shape_bank),
            ("iterations", args.iterations),
            ("num_workers", args.num_workers),
        )
        if v is not None
    }
    if args.config:
        cfg = TrainConfig.from_file(args.config, **overrides)
    else:
        cfg = TrainConfig.preset(args.preset, **overrides)
    result = train(
        cfg,
        args.out,
        device=args.device,
        resume=args.resume,
        max_minutes=args.max_minutes,
        progress=not args.quiet,
    )
    best = result["best"] or {}
    print(
        json.dumps(
            {
                "iteration": result["iteration"],
                "finished": result["finished"],
                "seconds": round(result["seconds"], 1),
                "best_iteration": best.get("iteration"),
                "best_validation": best.get("metrics"),
            },
            indent=2,
        )
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="pointclm", description=__doc__)
    p.add_argument("--version", action="version", version=f"pointclm {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser("demo", help="register a few synthetic scenes built from bundled data")
    d.add_argument("--scenes", type=int, default=3, help="number of scenes (default 3)")
    _add_config_flags(d)
    d.set_defaults(func=cmd_demo)

    e = sub.add_parser("eval", help="score the method on a benchmark (MR, MP, MF, strict F1)")
    e.add_argument("--dataset", default="synthetic", choices=["synthetic"])
    e.add_argument("--scenes", type=int, default=500, help="number of scenes (default 500)")
    e.add_argument("--shapes", help="comma-separated shape names or mesh paths (default bunny)")
    e.add_argument("--data-dir", help="folder with meshes (e.g. ../shared/data)")
    e.add_argument(
        "--outlier-blocks",
        type=int,
        default=40,
        help="outlier blocks of 256 rows: 40 = 98%% outliers (test), 10 = training",
    )
    e.add_argument("--json", help="also write the figures to this JSON file")
    e.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_config_flags(e)
    e.set_defaults(func=cmd_eval)

    t = sub.add_parser("train", help="train the correspondence embedding (needs torch)")
    t.add_argument("--config", help='JSON file of TrainConfig fields ("preset" to start from)')
    t.add_argument("--preset", default="cpu", help="cpu (default), compact-gpu, paper, smoke")
    t.add_argument("--out", required=True, help="output folder (weights, checkpoints, log)")
    t.add_argument("--device", default="cpu", help="cpu or cuda")
    t.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    t.add_argument("--max-minutes", type=float, help="stop after a checkpoint past this time")
    t.add_argument("--iterations", type=int)
    t.add_argument("--num-workers", type=int, dest="num_workers")
    t.add_argument("--data-dir", help="folder with the training meshes (e.g. ../shared/data)")
    t.add_argument("--shape-bank", help="a shape_bank.npz from an earlier run (no meshes needed)")
    t.add_argument("--quiet", action="store_true")
    t.set_defaults(func=cmd_train)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    for name in ("scenes",):
        if getattr(args, name, 1) < 1:
            print(f"pointclm: --{name} must be >= 1", file=sys.stderr)
            return 2
    try:
        return int(args.func(args))
    except ValueError as e:
        print(f"pointclm: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

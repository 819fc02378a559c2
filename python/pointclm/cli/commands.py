"""`pointclm demo`, `eval`, `train` and `batch`."""

from __future__ import annotations

import argparse
import functools
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..datasets import make_scenes
from ..evaluation import evaluate
from ..io.files import check_output_path
from ..metrics import Summary, rotation_error_deg, score_scene, summarize
from ..registration import default_config, register
from .args import (
    _add_config_flags,
    _check_folder_creatable,
    _config_overrides,
    _finite_float,
    _int_at_least,
    _write_json,
    flag_names,
)
from .bop import _add_bop_flags, _check_bop_args, _write_batch_bop
from .register import _add_method_flags, _method_options


def cmd_demo(args: argparse.Namespace) -> int:
    overrides = _config_overrides(args)
    # The flags over `register`'s own default (the network's recommended thresholds, else
    # Config()); no flags: None, that default itself.
    config = default_config(args.model, overrides) if overrides else None
    method = (
        f"PointCLM with the {args.model!r} embedding" if args.model else ("training-free PointCLM")
    )
    print(f"pointclm {__version__}: {method} on the paper's synthetic protocol")
    print("source: 256 points of the Stanford bunny (bundled); target: 5-10 noisy copies, each")
    print("holding about 2% of the 1000 correspondences per scene (80-90% of them wrong)\n")
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
    _demo_scene(args, overrides)
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    overrides = _config_overrides(args)
    if args.json:
        check_output_path(args.json, "--json")
    if args.data_dir is not None and not Path(args.data_dir).is_dir():
        raise ValueError(f"--data-dir {args.data_dir} is not a folder")
    shapes = args.shapes.split(",") if args.shapes else None
    scenes: Any
    if args.dataset == "scenes":
        from ..datasets.scenes import SceneParams, make_realistic_scene

        params = SceneParams(
            model=shapes[0] if shapes else "stanford/bunny", data_dir=args.data_dir
        )
        # Built lazily so the progress bar covers scene building (FPFH) too.
        scenes = (make_realistic_scene(args.seed + i, params) for i in range(args.scenes))
    else:
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
        scenes,
        seed=args.seed,
        num_threads=args.num_threads,
        progress=bar,
        model=args.model,
        refine=not args.no_refine,
        config_overrides=overrides or None,
    )
    print(f"{Summary.table_header()} {'med ms':>7} {'p90 ms':>7}")
    name = f"pointclm ({args.model})" if args.model else "pointclm"
    print(f"{ev.summary.as_row(name)} {ev.median_ms:7.2f} {ev.p90_ms:7.2f}")
    if args.json:
        _write_json(
            args.json,
            {
                # The flags given, and the config they gave (synthetic units; on realistic
                # scenes scaled to each scene's voxel).
                "config_overrides": overrides,
                "config": ev.config.to_dict() if ev.config else None,
                "model": args.model,
                "dataset": args.dataset,
                "scenes": args.scenes,
                "seed": args.seed,
                **ev.as_dict(),
            },
        )
    return 0


def _demo_scene(args: argparse.Namespace, overrides: dict[str, Any]) -> None:
    """One realistic scene from bundled data only: the coarse bunny among procedural clutter,
    seen by a virtual range sensor, registered from FPFH matches."""
    from ..datasets.scenes import SceneParams, make_realistic_scene

    scene = make_realistic_scene(args.seed, SceneParams(model="bunny", data_dir=None))
    # Registered, refined and scored as `pointclm eval` does a realistic scene (the method
    # flags over its defaults for refined poses).
    ev = evaluate(
        [scene],
        seed=args.seed,
        num_threads=args.num_threads,
        model=args.model,
        config_overrides=overrides or None,
    )
    score = ev.scores[0]
    print(
        f"\nrealistic scene: {scene.n_instances} bunnies among clutter, seen by a range sensor "
        f"({len(scene.target_points)} scene points), {len(scene.correspondences)} FPFH matches "
        f"({100 * (scene.labels >= 0).mean():.1f}% inliers)"
    )
    print(
        f"  found {score.n_pred} instances, {score.n_matched} correct "
        f"(RE < 15 deg, TE < 10% of the model size); "
        f"scene building {1e3 * scene.timings['total']:.0f} ms, "
        f"registration and refinement on the clouds {ev.median_ms:.0f} ms"
    )


def cmd_train(args: argparse.Namespace) -> int:
    try:
        from ..training import TrainConfig, train
    except ImportError as e:
        print(f"pointclm train needs torch: pip install 'pointclm[train]' ({e})", file=sys.stderr)
        return 2
    _check_folder_creatable(args.out, "--out")
    if args.config is not None and not Path(args.config).is_file():
        raise FileNotFoundError(2, "no such training config file", args.config)
    if args.max_minutes is not None and args.max_minutes < 0:
        raise ValueError(f"--max-minutes must be >= 0, got {args.max_minutes}")
    overrides = {
        k: v
        for k, v in (
            ("data_dir", args.data_dir),
            ("shape_bank", args.shape_bank),
            ("iterations", args.iterations),
            ("num_workers", args.num_workers),
            ("realistic_bank", args.realistic_bank),
            ("val_realistic_bank", args.val_realistic_bank),
        )
        if v is not None
    }
    if args.config:
        cfg = TrainConfig.from_file(args.config, **overrides)
    else:
        cfg = TrainConfig.preset(args.preset, **overrides)
    if args.banks_only:
        return _build_banks(cfg, Path(args.out), not args.quiet)
    args.device = _check_device(args.device)
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


def _build_banks(cfg: Any, out: Path, progress: bool) -> int:
    """Build the realistic training and validation banks on every core into `out`, for a
    machine that trains but cannot build them (no data folder, or its time is precious)."""
    from ..training.loop import realistic_banks

    if cfg.realistic_fraction <= 0:
        raise ValueError("this config trains on no realistic scenes: there is no bank to build")
    out.mkdir(parents=True, exist_ok=True)
    banks = realistic_banks(cfg, out, progress)  # saved in `out` unless the config names them
    print(f"banks in {out}")
    for name, bank in zip(("scene_bank.npz", "val_scene_bank.npz"), banks, strict=True):
        assert bank is not None  # realistic_fraction > 0
        print(f"{name}: {len(bank)} scenes of {len(bank.models)} models")
    return 0


def _check_device(device: str) -> str:
    import torch

    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"

    try:
        kind = torch.device(device).type
    except (RuntimeError, ValueError, TypeError):
        raise ValueError(
            f"--device {device!r} is not a torch device (cpu, cuda, cuda:1...)"
        ) from None
    if kind == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"--device {device}: CUDA is not available on this machine")
    return device


def _add_eval_parser(sub: Any) -> None:
    e = sub.add_parser("eval", help="score the method on a benchmark (MR, MP, MF, strict F1)")
    e.add_argument(
        "--dataset",
        default="synthetic",
        choices=["synthetic", "scenes"],
        help="synthetic: the paper's protocol; scenes: realistic scans with FPFH matches "
        "(TE threshold 10%% of the model's diagonal)",
    )
    e.add_argument(
        "--scenes", type=_int_at_least(1), default=500, help="number of scenes (default 500)"
    )
    e.add_argument("--shapes", help="comma-separated shape names or mesh paths (default bunny)")
    e.add_argument("--data-dir", help="folder with meshes (e.g. ../shared/data)")
    e.add_argument(
        "--outlier-blocks",
        type=_int_at_least(0),
        default=40,
        help="outlier blocks of 256 rows: 40 = the test protocol (about 2%% of the rows per "
        "copy, 85%% wrong overall), 10 = training",
    )
    e.add_argument("--json", help="also write the figures to this JSON file")
    e.add_argument("--quiet", action="store_true", help="no progress bar")
    e.add_argument(
        "--no-refine",
        action="store_true",
        help="keep the correspondence stage's poses (no ICP on the clouds, no verification)",
    )
    _add_config_flags(e)
    e.set_defaults(func=cmd_eval)


def _add_batch_parser(sub: Any) -> None:
    b = sub.add_parser(
        "batch",
        help="register one model (or several) in many scans: one JSON line per scan, resumable",
        description="Find the copies of MODEL in every scan of SCANS (files, folders of "
        "point-cloud files, quoted glob patterns, or ROS bags: one scan per PointCloud2 "
        "message) and write one JSON line per scan to "
        "--out as each completes, in the order of SCANS: its instances, diagnosis and "
        "timings as `pointclm register --out` writes them, or the error for that scan (the "
        "batch goes on). Every scan gets the same --seed, so its poses are the same whichever "
        "worker or engine ran it.",
    )
    b.add_argument("model_file", metavar="MODEL", help="the object (mesh or point cloud)")
    b.add_argument(
        "scans", metavar="SCANS", nargs="+", help="scan files, folders, globs or ROS bags"
    )
    _add_model_flags(b)
    b.add_argument("--out", required=True, help="the JSON Lines file of results")
    b.add_argument(
        "--resume",
        action="store_true",
        help="skip the scans --out already holds and add the rest (without it an existing "
        "non-empty --out is an error)",
    )
    b.add_argument(
        "--workers",
        type=_int_at_least(1),
        default=1,
        help="worker processes (default 1: this process); each uses --num-threads (default 1)",
    )
    b.add_argument(
        "--engine",
        choices=["local", "ray"],
        default="local",
        help="local processes, or Ray tasks (pip install 'pointclm[ray]')",
    )
    b.add_argument(
        "--ray-address",
        help="Ray cluster to join (as ray.init(address=...)); default: a local one of "
        "--workers CPUs",
    )
    b.add_argument("--png-dir", help="a picture per scan in this folder (needs matplotlib)")
    b.add_argument("--ply-dir", help="a coloured point cloud per scan in this folder")
    b.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_method_flags(b)
    _add_bop_flags(b, batch=True)
    b.set_defaults(func=cmd_batch)


def _add_model_flags(b: argparse.ArgumentParser) -> None:
    """`batch`'s other part types and their symmetries."""
    b.add_argument(
        "--add-model",
        metavar="FILE",
        action="append",
        default=[],
        help="another part type (repeatable): each scan's copies of MODEL and of every "
        "--add-model found and judged together, the line holding one result per model",
    )
    b.add_argument(
        "--symmetry",
        metavar="FILE|auto|none",
        action="append",
        help="the model's proper symmetries, as register --symmetry takes them: once for "
        "every model, or once per model (MODEL, then each --add-model)",
    )


def cmd_batch(args: argparse.Namespace) -> int:
    from ..batch import run_batch
    from ..io import load_points
    from .models import load_symmetries

    models = [args.model_file, *args.add_model]
    _check_bop_args(args, len(models))  # before the (long) batch: a bad path costs nothing
    options = _method_options(args, lambda: load_points(args.model_file))
    if args.symmetry:
        symmetries = load_symmetries(args.symmetry, len(models))
        options["symmetry"] = symmetries if len(models) > 1 else symmetries[0]
    summary = run_batch(
        models if len(models) > 1 else args.model_file,
        args.scans,
        args.out,
        options=options,
        resume=args.resume,
        engine=args.engine,
        workers=args.workers,
        ray_address=args.ray_address,
        png_dir=args.png_dir,
        ply_dir=args.ply_dir,
        progress=not args.quiet,
        diagnosis=flag_names,
    )
    # Scans that failed are in the output and the count; the batch itself ran: exit 0.
    print(f"pointclm batch: {summary}")
    if args.bop_csv:
        print(f"pointclm batch: {_write_batch_bop(args)} poses in {args.bop_csv}")
    return 0


def _add_train_parser(sub: Any) -> None:
    t = sub.add_parser("train", help="train the correspondence embedding (needs torch)")
    t.add_argument("--config", help='JSON file of TrainConfig fields ("preset" to start from)')
    t.add_argument(
        "--preset",
        default="cpu",
        help="cpu (default), realistic-cpu, realistic-gpu, compact-gpu, paper, smoke",
    )
    t.add_argument("--out", required=True, help="output folder (weights, checkpoints, log)")
    t.add_argument(
        "--device", default="auto", help="auto (default: cuda when available), cpu or cuda"
    )
    t.add_argument(
        "--resume",
        action="store_true",
        help="continue from OUT/checkpoint.safetensors + checkpoint.json",
    )
    t.add_argument(
        "--max-minutes", type=_finite_float, help="stop after a checkpoint past this time"
    )
    t.add_argument("--iterations", type=_int_at_least(1))
    t.add_argument("--num-workers", type=_int_at_least(0), dest="num_workers")
    t.add_argument("--data-dir", help="folder with the training meshes (e.g. ../shared/data)")
    t.add_argument("--shape-bank", help="a shape_bank.npz from an earlier run (no meshes needed)")
    t.add_argument("--realistic-bank", help="a scene_bank.npz built earlier (--banks-only)")
    t.add_argument("--val-realistic-bank", help="a val_scene_bank.npz built earlier")
    t.add_argument(
        "--banks-only",
        action="store_true",
        help="build the realistic scene banks into OUT on every core, then stop",
    )
    t.add_argument("--quiet", action="store_true")
    t.set_defaults(func=cmd_train)

"""`pointclm` command line: `demo` on built-in data, `eval` on a benchmark, `register` files,
`batch` many scans."""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import sys
import traceback
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from . import __version__
from .batch import registration_record
from .batch.options import NO_VIEWPOINT, scan_viewpoint
from .config import Config
from .datasets import make_scenes
from .evaluation import evaluate
from .io.files import atomic_path, check_output_path
from .metrics import Summary, rotation_error_deg, score_scene, summarize
from .registration import default_config, register

#: Set to 1 to get the Python traceback of an unexpected error instead of one line.
DEBUG_ENV = "POINTCLM_DEBUG"

#: The benchmarks' rule for a found copy: RE < 15 deg and TE < 10 % of the model's diagonal.
MATCH_DEG = 15.0
MATCH_DIAGONALS = 0.1

#: A diagnosis names `register_point_clouds`' arguments; the command's user types flags.
#: How to know the sensor position `--viewpoint` asks for, said where a diagnosis suggests it.
VIEWPOINT_HINT = (
    "--viewpoint x,y,z (the sensor's position in the scan's coordinates: 0,0,0 for a scan "
    "still in its camera's or scanner's own frame; for a scan moved into a world or robot "
    "frame, the sensor's position there, from the acquisition's calibration or pose log)"
)
_FLAGS_FOR_ARGUMENTS = (
    ("viewpoint=None", "--viewpoint none"),
    ("pass viewpoint=.", f"pass {VIEWPOINT_HINT}."),
    ("viewpoint=", "--viewpoint x,y,z"),
    ("voxel_size", "--voxel-size"),
    ("mutual=False", "--no-mutual"),
    ("n_samples=None", "--all-correspondences"),
)


class _Parser(argparse.ArgumentParser):
    """Usage errors on one line, like every other error of the command."""

    def error(self, message: str) -> Any:  # argparse's signature is NoReturn
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _int_at_least(minimum: int) -> Any:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
        return value

    return parse


def _finite_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def _viewpoint(text: str) -> tuple[float, float, float] | str:
    """A sensor position x,y,z, or "none": orient the scan's normals without one even where
    the file records one (what a diagnosis suggests when that position looks wrong)."""
    if text.strip().lower() == NO_VIEWPOINT:
        return NO_VIEWPOINT
    parts = text.split(",")
    try:
        values = [float(v) for v in parts]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(
            f"expected three finite numbers x,y,z or 'none', got {text!r}"
        )
    return (values[0], values[1], values[2])


def _window(text: str) -> float | str:
    """``--mutual-window``: "auto" or a positive number of model diagonals."""
    if text.strip().lower() == "auto":
        return "auto"
    side = _finite_float(text)
    if side <= 0:
        raise argparse.ArgumentTypeError(f"must be auto or a number > 0, got {text!r}")
    return side


def _rank(text: str) -> int | None:
    """``--heap-rank``: "none" or a count >= 1."""
    if text.strip().lower() == "none":
        return None
    rank: int = _int_at_least(1)(text)
    return rank


def _scene_param(text: str) -> tuple[str, Any]:
    """``--scene NAME=VALUE``: a field of `SceneRules` and its value, typed by the core's
    schema (checked against its range when the run starts)."""
    from .scene_rules import _SCHEMA

    name, sep, value = text.partition("=")
    name = name.strip()
    if not sep or name not in _SCHEMA:
        raise argparse.ArgumentTypeError(
            f"expected NAME=VALUE with NAME one of {', '.join(_SCHEMA)}, got {text!r}"
        )
    if _SCHEMA[name]["kind"] == "count":
        return name, _int_at_least(0)(value)
    return name, _finite_float(value)


def _write_json(path: str, payload: dict[str, Any]) -> None:
    """Written to a temporary file and renamed: never a half-written JSON."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(payload, indent=2) + "\n")


def _check_folder_creatable(path: str, what: str) -> None:
    """An output folder that exists (a writable directory) or can be made."""
    folder = Path(path)
    if folder.exists():
        if not folder.is_dir():
            raise ValueError(f"{what} {folder} exists and is not a directory")
        if not os.access(folder, os.W_OK | os.X_OK):
            raise ValueError(f"{what} {folder} is not writable")
        return
    parent = folder.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{what} {folder} cannot be created: {parent} is not a writable folder")


#: The method flags: `Config` fields, in synthetic units (lengths relative to the bunny of
#: the paper's protocol); on clouds every path scales them to the voxel (`Config.for_voxel`).
CONFIG_FLAGS = ("pruning", "assignment", "ransac_iterations", "sigma_d", "inlier_threshold")


def _config_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The method flags given (no flags: the defaults of each path apply: `Config()`, a
    network's recommended thresholds, or on clouds those for refined or raw poses)."""
    return {n: getattr(args, n) for n in CONFIG_FLAGS if getattr(args, n, None) is not None}


def _add_config_flags(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group(
        "method (overrides of the path's defaults)",
        "Each flag replaces its own field of the config the path uses without flags: "
        "pointclm.Config(), the --model network's recommended thresholds, or on point clouds "
        "and realistic scenes those for refined or raw poses; the other fields keep their "
        "defaults. Lengths are in Config()'s synthetic units, scaled to the voxel on point "
        "clouds.",
    )
    g.add_argument("--pruning", choices=["paper", "authors", "none"])
    g.add_argument("--assignment", choices=["kmeans", "discretize"])
    g.add_argument("--ransac-iterations", type=_int_at_least(0), dest="ransac_iterations")
    g.add_argument("--sigma-d", type=_finite_float, dest="sigma_d")
    g.add_argument("--inlier-threshold", type=_finite_float, dest="inlier_threshold")
    p.add_argument(
        "--seed", type=_int_at_least(0), default=0, help="dataset and method seed (default 0)"
    )
    p.add_argument(
        "--num-threads", type=_int_at_least(1), default=None, help="threads (default: all)"
    )
    p.add_argument(
        "--model",
        help="learned embedding: default, paper or a weight file (run by the Rust core); "
        "omit for the training-free pipeline",
    )


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
        from .datasets.scenes import SceneParams, make_realistic_scene

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


def _pose_line(T: np.ndarray) -> str:
    """Translation and rotation (axis-angle in degrees) of a 4x4 pose, on one line."""
    R = T[:3, :3]
    angle = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    n = np.linalg.norm(axis)
    axis = axis / n if n > 1e-12 else np.array([0.0, 0.0, 1.0])
    return (
        f"t = ({T[0, 3]: .4f}, {T[1, 3]: .4f}, {T[2, 3]: .4f})  "
        f"R = {angle:6.1f} deg about ({axis[0]: .2f}, {axis[1]: .2f}, {axis[2]: .2f})"
    )


def _diagnosis(reg: Any) -> str:
    """The result's diagnosis with `register_point_clouds`' argument names as this command's
    flags, so its advice can be followed as written."""
    return flag_names(str(getattr(reg, "diagnosis", "") or ""))


def flag_names(text: str) -> str:
    """`text` (a diagnosis naming `register_point_clouds` arguments) with the command line's
    flags in their place."""
    for argument, flag in _FLAGS_FOR_ARGUMENTS:
        text = text.replace(argument, flag)
    return text


def _report(reg: Any, truth: dict[str, Any] | None = None) -> None:
    print(
        f"{len(reg.instances)} instance(s), surest first, from {len(reg.passes)} pass(es); "
        f"{len(reg.correspondences)} correspondences in the first "
        f"between {len(reg.source_points)} model and {len(reg.target_points)} scene points "
        f"(voxel {reg.voxel_size:.4g})"
    )
    for i, inst in enumerate(reg.instances):
        line = (
            f"  [{i}] {_pose_line(inst.transformation)}  "
            f"{'voted       ' if inst.matches is None else f'matches {len(inst):4d}'}  "
            f"fitness {inst.fitness:.3f}  rmse {inst.inlier_rmse:.4g}  "
            f"confidence {inst.confidence:.3f}  pass {inst.pass_index}"
        )
        if truth is not None:
            j = truth["instance_truth"][i]
            line += "  (no true pose)" if j is None else f"  = true pose {j}"
        print(line)
    if _diagnosis(reg):
        print(f"note: {_diagnosis(reg)}")
    if truth is not None:
        print(_truth_line(truth))
    print("time: " + ", ".join(f"{k} {1e3 * v:.1f} ms" for k, v in reg.timings.items() if v > 0))


def _truth_line(truth: dict[str, Any]) -> str:
    found, missed, n = truth["found"], truth["missed"], truth["poses"]
    false = sum(j is None for j in truth["instance_truth"])
    return (
        f"ground truth: {len(found)} of {n} true pose(s) found "
        f"(RE < {MATCH_DEG:g} deg, TE < {truth['max_translation']:.4g} = "
        f"{MATCH_DIAGONALS:.0%} of the model's diagonal)"
        + (f"; missed {missed}" if missed else "")
        + (f"; {false} instance(s) match no true pose" if false else "")
    )


def _load_ground_truth(path: str) -> np.ndarray:
    """(G, 4, 4) T_target_source poses from a .npy file or a JSON list of 4 x 4 matrices (or
    the "instances" of `pointclm register --out`), checked to be rigid transforms."""
    from .errors import InputError
    from .io.arrays import read_npy
    from .io.files import read_checked

    file, raw = read_checked(path, "ground-truth file")
    what = f"--ground-truth {file}"
    suffix = file.suffix.lower()
    if suffix not in (".npy", ".json"):
        raise InputError(f"{what}: expected a .npy or .json file of (G, 4, 4) poses")
    try:
        # Not np.load: read_npy checks the header's shape against the file's length before
        # allocating anything, and never unpickles. Its messages start with `what`.
        data: Any = read_npy(raw, what) if suffix == ".npy" else _json_poses(raw)
        poses = np.asarray(data, dtype=np.float64)
    except (ValueError, TypeError) as e:
        text = str(e)
        if not text.startswith(what):
            text = (
                f"{what} could not be read as poses (a .npy of (G, 4, 4), or a JSON list of "
                f"4x4 matrices): {text}"
            )
        raise InputError(text) from None
    if poses.shape == (4, 4) or poses.size == 0:  # one pose, or a scene that holds no copy
        poses = poses.reshape(-1, 4, 4)
    return _checked_poses(poses, what)


def _json_poses(raw: bytes) -> Any:
    data = json.loads(raw)
    if isinstance(data, dict) and isinstance(data.get("instances"), list):
        # An earlier `pointclm register --out` result: its instances' poses.
        return [inst.get("T_target_source") for inst in data["instances"] if isinstance(inst, dict)]
    return data


def _checked_poses(poses: np.ndarray, what: str) -> np.ndarray:
    from .errors import InputError
    from .preprocessing import are_rotations

    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise InputError(f"{what}: expected (G, 4, 4) T_target_source poses, got {poses.shape}")
    if not np.isfinite(poses).all():
        raise InputError(f"{what}: a pose has a non-finite value (NaN or inf)")
    # The core's tolerance: poses written with a few decimals are still rigid transforms.
    rigid = are_rotations(poses[:, :3, :3])
    rigid &= np.abs(poses[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) < 1e-9
    if not rigid.all():
        k = int(np.flatnonzero(~rigid)[0])
        raise InputError(
            f"{what}: pose {k} is not a rigid transform (rotation block not orthonormal "
            "with determinant 1, or last row not 0 0 0 1)"
        )
    return poses


def _score_truth(reg: Any, ground_truth: np.ndarray, model: np.ndarray) -> dict[str, Any]:
    """Which true poses the instances found, one instance per true pose at most (as the
    benchmarks count correct copies)."""
    from .metrics import max_bipartite_matching, pose_match_matrix

    diagonal = float(np.linalg.norm(np.ptp(model, axis=0))) if len(model) else 0.0
    limit = MATCH_DIAGONALS * diagonal
    match = pose_match_matrix(reg.transformations, ground_truth, MATCH_DEG, limit)
    pairs = max_bipartite_matching(match)
    found = sorted(int(j) for j in pairs if j >= 0)
    return {
        "poses": len(ground_truth),
        "found": found,
        "missed": [j for j in range(len(ground_truth)) if j not in found],
        "instance_truth": [int(j) if j >= 0 else None for j in pairs],
        "max_rotation_deg": MATCH_DEG,
        "max_translation": limit,
    }


def cmd_register(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from .io import load_points

    ground_truth = _check_register_args(args)
    stages = ["load", "register", *(["png"] if args.png else []), *(["ply"] if args.ply else [])]
    bar = tqdm(total=len(stages), desc="pointclm", unit="stage", disable=args.quiet, leave=False)
    with bar:
        bar.set_postfix_str("loading")
        model = load_points(args.model_file)
        scene = load_points(args.scene_file)
        bar.update()
        bar.set_postfix_str("FPFH, matching, registration")
        reg = _register_files(args, model, scene)
        bar.update()
        _write_pictures(args, reg, ground_truth, bar)
    truth = None if ground_truth is None else _score_truth(reg, ground_truth, model)
    _report(reg, truth)
    if args.out:
        _write_json(args.out, _register_json(args, reg, truth))
    return 0


def _check_register_args(args: argparse.Namespace) -> np.ndarray | None:
    """Everything that can be checked before the (long) work: outputs, extras, the ground
    truth (read now, so a bad file costs nothing)."""
    for flag in ("out", "png", "ply"):
        if getattr(args, flag):
            check_output_path(getattr(args, flag), f"--{flag}")
    if args.png:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise ImportError("--png needs matplotlib: pip install 'pointclm[viz]'") from None
    if args.model is not None:
        from .model.weights import load_network

        load_network(args.model)  # a wrong name fails now, naming the shipped ones (cached)
    return None if args.ground_truth is None else _load_ground_truth(args.ground_truth)


def _register_files(args: argparse.Namespace, model: np.ndarray, scene: np.ndarray) -> Any:
    from .point_clouds import register_point_clouds

    options = _method_options(args, lambda: model)
    options["viewpoint"] = scan_viewpoint(options["viewpoint"], args.scene_file)
    return register_point_clouds(model, scene, **options)


def _method_options(args: argparse.Namespace, model: Callable[[], np.ndarray]) -> dict[str, Any]:
    """`register_point_clouds`' options from the method flags `register` and `batch` share
    (the viewpoint as given: a position, "none", or None for a PCD scan's own). `model`
    gives the model's points, asked only when a method flag needs the default voxel."""
    config, voxel = _cloud_config(args, model)
    return {
        "voxel_size": voxel,
        "config": config,
        "seed": args.seed,
        "model": args.model,
        "viewpoint": args.viewpoint,
        "mutual": not args.no_mutual,
        "n_samples": None if args.all_correspondences else args.correspondences,
        "refine": not args.no_refine,
        "peel": not args.no_peel,
        "heap": True if args.heap else None,
        "num_threads": args.num_threads,
        "top_k": args.top_k,
        "k": args.k,
        "mutual_window": args.mutual_window,
        "heap_rank": args.heap_rank,
        "normals": args.normals,
        "flips": not args.no_flips,
        "scene": dict(args.scene or ()),
    }


def _write_pictures(
    args: argparse.Namespace, reg: Any, ground_truth: np.ndarray | None, bar: Any
) -> None:
    from .visualize import save_ply, save_registration_png

    if args.png:
        bar.set_postfix_str("png")
        title = f"{Path(args.model_file).name} in {Path(args.scene_file).name}"
        with atomic_path(args.png) as tmp:
            save_registration_png(tmp, reg, ground_truth=ground_truth, title=title)
        bar.update()
    if args.ply:
        bar.set_postfix_str("ply")
        with atomic_path(args.ply) as tmp:
            save_ply(
                tmp, reg.target_points, reg.source_points, reg.transformations, 1.5 * reg.voxel_size
            )
        bar.update()


def _register_json(
    args: argparse.Namespace, reg: Any, truth: dict[str, Any] | None
) -> dict[str, Any]:
    """What `pointclm batch` writes per scan (`registration_record`), plus the files and the
    ground truth's verdict."""
    # The diagnosis is "" when there is nothing to say; otherwise why the result is empty
    # or doubtful.
    record = registration_record(reg, _diagnosis(reg))
    if truth is not None:
        for entry, j in zip(record["instances"], truth["instance_truth"], strict=True):
            entry["true_pose"] = j
    return {
        "model": args.model_file,
        "scene": args.scene_file,
        **record,
        "ground_truth": None
        if truth is None
        else {k: v for k, v in truth.items() if k != "instance_truth"},
    }


def _cloud_config(
    args: argparse.Namespace, model: Callable[[], np.ndarray]
) -> tuple[Config | None, float | None]:
    """With method flags: `register_point_clouds`' own default config with the flags applied,
    scaled to the voxel as `pointclm eval` scales them (so --sigma-d means the same in both),
    and that voxel (the model's default unless --voxel-size: the call must use the voxel the
    config was scaled to); without flags, None and --voxel-size (the call's defaults)."""
    from .point_clouds import cloud_config, default_voxel_size

    overrides = _config_overrides(args)
    if not overrides:
        return None, args.voxel_size
    voxel = default_voxel_size(model()) if args.voxel_size is None else args.voxel_size
    refine = not args.no_refine
    return cloud_config(voxel, args.model, refine, refine and not args.no_peel, overrides), voxel


def _demo_scene(args: argparse.Namespace, overrides: dict[str, Any]) -> None:
    """One realistic scene from bundled data only: the coarse bunny among procedural clutter,
    seen by a virtual range sensor, registered from FPFH matches."""
    from .datasets.scenes import SceneParams, make_realistic_scene

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
        from .training import TrainConfig, train
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
    from .training.loop import realistic_banks

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


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="pointclm", description=__doc__)
    p.add_argument("--version", action="version", version=f"pointclm {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser("demo", help="register a few synthetic scenes built from bundled data")
    d.add_argument(
        "--scenes", type=_int_at_least(1), default=3, help="number of scenes (default 3)"
    )
    _add_config_flags(d)
    d.set_defaults(func=cmd_demo)

    _add_eval_parser(sub)
    _add_register_parser(sub)
    _add_batch_parser(sub)
    _add_train_parser(sub)
    return p


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


def _add_register_parser(sub: Any) -> None:
    r = sub.add_parser(
        "register",
        help="find every copy of a model in a scene (point cloud or mesh files)",
        description="Load MODEL and SCENE (.ply .pcd .off .xyz .txt .npy .npz), compute FPFH, "
        "match, and print one line per instance found (or why none was).",
    )
    r.add_argument("model_file", metavar="MODEL", help="the object (mesh or point cloud)")
    r.add_argument("scene_file", metavar="SCENE", help="the scan holding its copies")
    r.add_argument(
        "--ground-truth",
        metavar="FILE",
        help="true T_target_source poses (.npy of (G, 4, 4), or a JSON list of 4x4): the "
        "report says which were found (RE < 15 deg, TE < 10%% of the model's diagonal) and the "
        "picture draws the missed ones",
    )
    r.add_argument("--out", help="write instances, diagnosis and timings to this JSON file")
    r.add_argument("--png", help="picture of the result (needs matplotlib)")
    r.add_argument("--ply", help="coloured point cloud of the result")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_method_flags(r)
    r.set_defaults(func=cmd_register)


def _add_method_flags(p: argparse.ArgumentParser) -> None:
    """The options of `register_point_clouds`, shared by `register` and `batch`."""
    p.add_argument(
        "--voxel-size",
        type=_finite_float,
        help="default: model diagonal / 40, or 1.4 x the scan's point spacing or 2.5 x its noise",
    )
    p.add_argument(
        "--viewpoint",
        type=_viewpoint,
        help="sensor position x,y,z for scene normals and verification, or none (default: a "
        "PCD scene's VIEWPOINT; without one, a position guessed from the scan, its frame's "
        "origin or where it hides the fewest of its own points, kept if the first pass "
        "confirms it)",
    )
    p.add_argument(
        "--correspondences", type=_int_at_least(1), default=1000, help="sampled (default 1000)"
    )
    p.add_argument("--all-correspondences", action="store_true", help="keep all of the top-K")
    p.add_argument("--no-mutual", action="store_true", help="skip mutual-NN filtering")
    p.add_argument(
        "--no-refine",
        action="store_true",
        help="keep the correspondence stage's poses (no ICP on the clouds, no verification)",
    )
    p.add_argument(
        "--no-peel",
        action="store_true",
        help="one pass of the correspondence stage (no new passes over the unexplained scan)",
    )
    p.add_argument(
        "--heap",
        action="store_true",
        help="the scan is a heap of identical parts (bin picking): every pass ranks its mutual "
        "matches as in a heap (default: once 10 copies are found)",
    )
    _add_matching_flags(p)
    p.add_argument(
        "--no-flips",
        action="store_true",
        help="keep the verified poses as they are (no turned alternatives tried)",
    )
    p.add_argument(
        "--scene",
        action="append",
        type=_scene_param,
        metavar="NAME=VALUE",
        help="a scene-wide rule (repeatable), e.g. --scene max_peel_rounds=5; the names, "
        "defaults and reasons: help(pointclm.SceneRules)",
    )
    _add_config_flags(p)


def _add_matching_flags(p: argparse.ArgumentParser) -> None:
    """`register_point_clouds`' matching options beyond the sample size and mutual check."""
    p.add_argument(
        "--top-k", type=_int_at_least(1), default=10_000, help="matches kept (default 10000)"
    )
    p.add_argument(
        "--k", type=_int_at_least(1), default=1, help="model matches per scan point (default 1)"
    )
    p.add_argument(
        "--mutual-window",
        type=_window,
        default=None,
        metavar="SIDE|auto",
        help="the mutual check within cubes of SIDE model diagonals, or auto: in windows once "
        "a heap is recognised (default: scene-wide)",
    )
    p.add_argument(
        "--heap-rank",
        type=_rank,
        default=64,
        metavar="N|none",
        help="in a heap, keep a match among the model point's N most similar scan points "
        "(default 64; none: the plain mutual check)",
    )
    p.add_argument(
        "--normals",
        action="store_true",
        help="give the correspondence stage the normals at both ends of each match",
    )


def _add_batch_parser(sub: Any) -> None:
    b = sub.add_parser(
        "batch",
        help="register one model in many scans: one JSON line per scan, resumable",
        description="Find the copies of MODEL in every scan of SCANS (files, folders of "
        "point-cloud files, or quoted glob patterns) and write one JSON line per scan to "
        "--out as each completes, in the order of SCANS: its instances, diagnosis and "
        "timings as `pointclm register --out` writes them, or the error for that scan (the "
        "batch goes on). Every scan gets the same --seed, so its poses are the same whichever "
        "worker or engine ran it.",
    )
    b.add_argument("model_file", metavar="MODEL", help="the object (mesh or point cloud)")
    b.add_argument("scans", metavar="SCANS", nargs="+", help="scan files, folders or globs")
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
    b.set_defaults(func=cmd_batch)


def cmd_batch(args: argparse.Namespace) -> int:
    from .batch import run_batch
    from .io import load_points

    summary = run_batch(
        args.model_file,
        args.scans,
        args.out,
        options=_method_options(args, lambda: load_points(args.model_file)),
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


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command; an error is one line on stderr and a non-zero exit code (2: bad input
    or environment, 1: an internal error, 130: interrupted), never a traceback unless
    ``POINTCLM_DEBUG=1``."""
    args = build_parser().parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return int(args.func(args))
    except KeyboardInterrupt:
        print("pointclm: interrupted", file=sys.stderr)
        return 130
    except (ValueError, OSError, ImportError, MemoryError) as e:
        if os.environ.get(DEBUG_ENV):
            traceback.print_exc()
        reason = str(e) or type(e).__name__
        if isinstance(e, MemoryError):
            reason = f"out of memory ({reason})"
        print(f"pointclm: {_one_line(reason)}", file=sys.stderr)
        return 2
    except Exception as e:  # a bug: still one line, with a way to see the traceback
        if os.environ.get(DEBUG_ENV):
            traceback.print_exc()
        print(
            f"pointclm: internal error ({type(e).__name__}: {_one_line(str(e))}); "
            f"run with {DEBUG_ENV}=1 for the traceback",
            file=sys.stderr,
        )
        return 1


def _one_line(text: str) -> str:
    return " ".join(text.split())


_default_showwarning = warnings.showwarning


def _show_warning(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: TextIO | None = None,
    line: str | None = None,
) -> None:
    """pointclm's own warnings (a file's NaN rows dropped) as one line on stderr, like its
    errors; any other warning as Python shows it."""
    from .io import NonFinitePointsWarning

    if issubclass(category, NonFinitePointsWarning):
        print(f"pointclm: warning: {_one_line(str(message))}", file=sys.stderr)
    else:
        _default_showwarning(message, category, filename, lineno, file, line)


if __name__ == "__main__":
    sys.exit(main())

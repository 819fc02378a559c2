"""`pointclm register`: one model in one scan (several: `.models`), its report, JSON,
pictures and ground-truth score; the method flags `register` and `batch` share."""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..batch import registration_record
from ..batch.options import scan_viewpoint
from ..batch.records import FORMAT_VERSION
from ..config import Config
from ..io.files import atomic_path, check_output_path
from .args import (
    _add_config_flags,
    _add_proposal_flags,
    _config_overrides,
    _finite_float,
    _int_at_least,
    _rank,
    _scene_param,
    _viewpoint,
    _window,
    _write_json,
    flag_names,
)
from .bop import _add_bop_flags, _check_bop_args, _write_bop

#: The benchmarks' rule for a found copy: RE < 15 deg and TE < 10 % of the model's diagonal.
MATCH_DEG = 15.0


MATCH_DIAGONALS = 0.1


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
    from ..errors import InputError
    from ..io.arrays import read_npy
    from ..io.files import read_checked

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
    from ..errors import InputError
    from ..preprocessing import are_rotations

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


def _load_symmetry(arg: str | None) -> Any:
    """`--symmetry`: None, "auto", or a JSON file holding one BOP ``models_info`` entry
    (checked now, so a bad file costs nothing)."""
    if arg is None or arg == "auto":
        return arg
    from ..errors import InputError
    from ..io.files import read_checked
    from ..symmetry import from_bop

    file, raw = read_checked(arg, "symmetry file")
    what = f"--symmetry {file}"
    try:
        entry = json.loads(raw)
    except ValueError as e:
        raise InputError(f"{what} is not JSON: {e}") from None
    whole = isinstance(entry, dict) and entry and all(isinstance(v, dict) for v in entry.values())
    if whole and not {"symmetries_discrete", "symmetries_continuous"} & set(entry):
        raise InputError(
            f"{what} looks like a whole models_info.json (one entry per object): give the "
            "entry of this model alone"
        )
    try:
        return from_bop(entry)
    except ValueError as e:
        raise InputError(f"{what}: {e}") from None


def _score_truth(
    reg: Any, ground_truth: np.ndarray, model: np.ndarray, symmetry: Any = None
) -> dict[str, Any]:
    """Which true poses the instances found, one instance per true pose at most (as the
    benchmarks count correct copies), a pose matching a truth made equivalent by one of the
    model's symmetries (the registration's, declared or detected) too."""
    from ..metrics import max_bipartite_matching, pose_match_matrix

    diagonal = float(np.linalg.norm(np.ptp(model, axis=0))) if len(model) else 0.0
    limit = MATCH_DIAGONALS * diagonal
    sym = getattr(reg, "symmetry", None) or (None if symmetry == "auto" else symmetry)
    match = pose_match_matrix(reg.transformations, ground_truth, MATCH_DEG, limit, symmetries=sym)
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

    from ..io import load_points
    from .models import check_several, cmd_register_models, load_symmetries, load_truths

    several = len(args.model_files) > 1
    if several:
        check_several(args)
    _check_register_args(args)
    truths = load_truths(args.ground_truth, len(args.model_files))
    symmetries = load_symmetries(args.symmetry, len(args.model_files))
    if several:
        return cmd_register_models(args, symmetries, truths)
    args.model_file = args.model_files[0]
    ground_truth, symmetry = truths[0], symmetries[0]
    stages = ["load", "register", *(f for f in ("png", "ply", "html") if getattr(args, f))]
    bar = tqdm(total=len(stages), desc="pointclm", unit="stage", disable=args.quiet, leave=False)
    with bar:
        bar.set_postfix_str("loading")
        model = load_points(args.model_file)
        scene = load_points(args.scene_file)
        bar.update()
        bar.set_postfix_str("FPFH, matching, registration")
        reg = _register_files(args, model, scene, symmetry)
        bar.update()
        _write_pictures(args, reg, ground_truth, bar)
    truth = None if ground_truth is None else _score_truth(reg, ground_truth, model, symmetry)
    _report(reg, truth)
    if args.out:
        _write_json(args.out, _register_json(args, reg, truth))
    _write_bop(args, reg)
    return 0


def _check_register_args(args: argparse.Namespace) -> None:
    """Everything that can be checked before the (long) work: outputs, extras, the network."""
    for flag in ("out", "png", "ply", "html"):
        if getattr(args, flag):
            check_output_path(getattr(args, flag), f"--{flag}")
    _check_bop_args(args, len(args.model_files))
    if args.png:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise ImportError("--png needs matplotlib: pip install 'pointclm[viz]'") from None
    if args.model is not None:
        from ..model.weights import load_network

        load_network(args.model)  # a wrong name fails now, naming the shipped ones (cached)


def _register_files(
    args: argparse.Namespace, model: np.ndarray, scene: np.ndarray, symmetry: Any = None
) -> Any:
    from ..point_clouds import register_point_clouds

    options = _method_options(args, lambda: model)
    options["viewpoint"] = scan_viewpoint(options["viewpoint"], args.scene_file)
    return register_point_clouds(model, scene, symmetry=symmetry, **options)


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
        "proposals": args.proposals,
        "descriptor": args.descriptor,
    }


def _write_pictures(
    args: argparse.Namespace, reg: Any, ground_truth: np.ndarray | None, bar: Any
) -> None:
    from ..visualize import save_ply, save_registration_png

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
    if args.html:
        bar.set_postfix_str("html")
        title = f"{Path(args.model_file).name} in {Path(args.scene_file).name}"
        reg.to_html(args.html, ground_truth=ground_truth, title=title)
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
        "format_version": FORMAT_VERSION,
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
    from ..point_clouds import cloud_config, default_voxel_size

    overrides = _config_overrides(args)
    if not overrides:
        return None, args.voxel_size
    voxel = default_voxel_size(model()) if args.voxel_size is None else args.voxel_size
    refine = not args.no_refine
    return cloud_config(voxel, args.model, refine, refine and not args.no_peel, overrides), voxel


def _add_register_parser(sub: Any) -> None:
    r = sub.add_parser(
        "register",
        help="find every copy of a model (or of several) in a scene (point cloud or mesh files)",
        description="Load MODEL(s) and SCENE (.ply .pcd .off .xyz .txt .npy .npz; .las .laz .e57 "
        "with pointclm[io]), compute FPFH, "
        "match, and print one line per instance found (or why none was).",
    )
    r.add_argument(
        "model_files",
        metavar="MODEL",
        nargs="+",
        help="the object (mesh or point cloud); several: each part type's copies found and "
        "judged together (a scan region one model's copy explains is not another's), one "
        "result per model",
    )
    r.add_argument("scene_file", metavar="SCENE", help="the scan holding their copies")
    r.add_argument(
        "--ground-truth",
        metavar="FILE",
        action="append",
        help="true T_target_source poses (.npy of (G, 4, 4), or a JSON list of 4x4): the "
        "report says which were found (RE < 15 deg, TE < 10%% of the model's diagonal) and the "
        "picture and page draw the missed ones; with several models, one per model in order",
    )
    r.add_argument(
        "--symmetry",
        metavar="FILE|auto|none",
        action="append",
        help="the model's proper symmetries: a JSON file holding its BOP models_info entry "
        "(symmetries_discrete / symmetries_continuous, in the model's units: BOP writes mm), "
        "'auto' to detect them, or 'none'; poses come out canonical among their equivalents, "
        "and --ground-truth counts an equivalent pose as found. With several models: once for "
        "every model, or once per model in order",
    )
    r.add_argument("--out", help="write instances, diagnosis and timings to this JSON file")
    r.add_argument("--png", help="picture of the result (needs matplotlib)")
    r.add_argument("--ply", help="coloured point cloud of the result")
    r.add_argument(
        "--html",
        help="one self-contained page to turn the result around in a browser (no network needed)",
    )
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_bop_flags(r)
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
    _add_proposal_flags(p)

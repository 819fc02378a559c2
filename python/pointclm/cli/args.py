"""The command line's argument types and shared flags, and how a diagnosis's argument names
read as flags."""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path
from typing import Any

from ..batch.options import NO_VIEWPOINT
from ..io.files import atomic_path


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
    from ..scene_rules import _SCHEMA

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
    ("proposals='faces'", "--proposals faces"),
)


def flag_names(text: str) -> str:
    """`text` (a diagnosis naming `register_point_clouds` arguments) with the command line's
    flags in their place."""
    for argument, flag in _FLAGS_FOR_ARGUMENTS:
        text = text.replace(argument, flag)
    return text


def _one_line(text: str) -> str:
    return " ".join(text.split())


def _add_proposal_flags(p: Any) -> None:
    """`--proposals` and `--descriptor`: what proposes the poses verification judges."""
    p.add_argument(
        "--proposals",
        choices=("auto", "descriptors", "faces"),
        default="auto",
        help="poses verification judges: descriptor matches, or with model faces laid on the "
        "scan's planar patches too (auto: faces for models mostly made of large flat faces)",
    )
    p.add_argument(
        "--descriptor",
        default="auto",
        metavar="auto|fpfh|learned|fpfh+learned|FILE",
        help="the local descriptor clouds are matched by: FPFH, the shipped learned one, both "
        "side by side, or a .safetensors file from `pointclm train-descriptor` (auto, the "
        "default: FPFH for models mostly made of large flat faces, both for any other)",
    )

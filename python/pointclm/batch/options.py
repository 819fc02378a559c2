"""What every scan of a batch shares: the model file, `register_point_clouds`' options, where
pictures go; checked once, before any scan runs, so a bad option fails the batch at once
instead of filling the output with the same error per scan."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import preprocessing as pp
from ..config import Config
from ..errors import InputError
from ..registration import as_config, as_seed, as_threads
from ..scene_rules import SceneRules

__all__ = [
    "NO_VIEWPOINT",
    "OPTION_NAMES",
    "BatchJob",
    "ModelPoints",
    "check_models",
    "check_options",
    "recorded_options",
    "scan_viewpoint",
]

#: ``viewpoint="none"``: no sensor position, not even the one a PCD scan records (the CLI's
#: ``--viewpoint none``).
NO_VIEWPOINT = "none"

#: `register_point_clouds`' keyword options a batch passes to every scan.
OPTION_NAMES = (
    "voxel_size",
    "config",
    "seed",
    "model",
    "viewpoint",
    "top_k",
    "mutual",
    "n_samples",
    "k",
    "normals",
    "refine",
    "peel",
    "heap",
    "num_threads",
    "mutual_window",
    "heap_rank",
    "flips",
    "scene",
    "symmetry",
    "proposals",
    "descriptor",
)

#: The model's points, or with several models (judged together) each one's, in order.
ModelPoints = np.ndarray | list[np.ndarray]


@dataclass(frozen=True)
class BatchJob:
    """Everything a worker needs besides the model's points and the scan path; picklable, so
    process pools and Ray ship it as it is."""

    model_file: str
    options: dict[str, Any] = field(default_factory=dict)
    #: `recorded_options(options)`: written on every line, compared on resume.
    recorded: dict[str, Any] = field(default_factory=dict)
    png_dir: str | None = None
    ply_dir: str | None = None
    #: The models after `model_file`, judged together with it (none: one model).
    more_models: tuple[str, ...] = ()

    @property
    def models(self) -> list[str]:
        """Every model file, in order."""
        return [self.model_file, *self.more_models]


def scan_viewpoint(option: Any, scan: str | os.PathLike[str]) -> Any:
    """The viewpoint a scan is registered with: the option's position; None for "none"; the
    PCD file's ``VIEWPOINT`` when the option is None (as `pointclm register` does)."""
    from ..point_clouds import file_viewpoint

    if isinstance(option, str) and option.strip().lower() == NO_VIEWPOINT:
        return None
    if option is not None:
        return option
    return file_viewpoint(scan)


def check_options(options: dict[str, Any]) -> dict[str, Any]:
    """`options` checked and made picklable: unknown names, bad values and a model that does
    not load raise here (:class:`~pointclm.errors.InputError` and the like)."""
    unknown = sorted(set(options) - set(OPTION_NAMES))
    if unknown:
        raise InputError(
            f"unknown option(s) {', '.join(unknown)}; register_files takes "
            f"{', '.join(OPTION_NAMES)}"
        )
    out = dict(options)
    as_threads(out.get("num_threads"))
    as_seed(out.get("seed", 0))
    for flag in ("mutual", "normals", "refine", "peel", "flips"):
        if flag in out:
            pp.as_flag(out[flag], flag)
    if out.get("heap") is not None:
        pp.as_flag(out["heap"], "heap")
    if out.get("voxel_size") is not None:
        out["voxel_size"] = pp.as_positive(out["voxel_size"], "voxel_size")
    if isinstance(out.get("config"), dict):
        out["config"] = Config(**as_config(out["config"]))
    elif out.get("config") is not None and not isinstance(out["config"], Config):
        raise InputError(f"config must be a pointclm.Config, a dict or None, got {out['config']!r}")
    view = out.get("viewpoint")
    if view is not None and not (isinstance(view, str) and view.strip().lower() == NO_VIEWPOINT):
        out["viewpoint"] = pp.as_point(np.asarray(view, dtype=np.float64), "viewpoint")
    if "scene" in out:
        out["scene"] = SceneRules.resolve(out["scene"])
    if "proposals" in out:
        from ..point_clouds import _proposals

        out["proposals"] = _proposals(out["proposals"])
    if "descriptor" in out:
        from ..descriptors import descriptor_choice

        descriptor_choice(out["descriptor"])  # checked here, resolved again by the worker
        out["descriptor"] = str(out["descriptor"])
    out["model"] = _model_spec(out.get("model"))
    if "symmetry" in out:
        out["symmetry"] = _symmetry(out["symmetry"])
    return out


def _symmetry(value: Any) -> Any:
    """`symmetry` checked (:func:`pointclm.symmetry.resolve`): one value, or a list of one per
    model (its length is checked against the models in `check_models`)."""
    from ..symmetry import resolve

    if isinstance(value, list | tuple):
        return [resolve(v) for v in value]
    return resolve(value)


def check_models(options: dict[str, Any], n_models: int) -> dict[str, Any]:
    """`options` whose symmetry fits `n_models` models: one value for every model, or a list
    of one per model (for one model, that one value)."""
    symmetry = options.get("symmetry")
    if not isinstance(symmetry, list):
        return options
    if len(symmetry) not in (1, n_models):
        raise InputError(
            f"{len(symmetry)} symmetries for {n_models} model(s): give one for every model, "
            "or one per model in the models' order"
        )
    if n_models == 1 or len(symmetry) == 1:
        return {**options, "symmetry": symmetry[0]}
    return options


def recorded_options(options: dict[str, Any]) -> dict[str, Any]:
    """Every option that can change a scan's result, defaults filled in, as JSON: what each
    line records, so a resumed batch can refuse to mix results of other options."""
    import inspect

    from ..point_clouds import register_point_clouds

    defaults = {
        name: p.default for name, p in inspect.signature(register_point_clouds).parameters.items()
    }
    # The thread count does not change results; the network is recorded on its own.
    # The symmetry only when one is declared: lines written without it read the same.
    names = [n for n in OPTION_NAMES if n not in ("num_threads", "model", "symmetry")]
    out = {n: options.get(n, defaults[n]) for n in names}
    if options.get("symmetry") is not None:
        out["symmetry"] = _recorded_symmetry(options["symmetry"])
    if isinstance(out["config"], Config):
        out["config"] = out["config"].to_dict()
    if isinstance(out["viewpoint"], tuple):
        out["viewpoint"] = list(out["viewpoint"])
    out["scene"] = SceneRules.resolve(out["scene"]).to_dict()
    return out


def _recorded_symmetry(symmetry: Any) -> Any:
    """A checked symmetry as JSON: "auto", null, a models_info entry, or a list of those."""
    from ..symmetry import Symmetry

    if isinstance(symmetry, list):
        return [_recorded_symmetry(s) for s in symmetry]
    return symmetry.to_bop() if isinstance(symmetry, Symmetry) else symmetry


def _model_spec(model: Any) -> str | None:
    """The network as a name or weight path (what every worker process loads for itself),
    loaded once here so a missing or bad weight file fails before the batch starts."""
    from ..embedding import is_network, resolve

    if model is None:
        return None
    if is_network(model):
        model = model.path
    if not isinstance(model, str | os.PathLike):
        raise InputError(
            "a batch's model must be a shipped name (default, paper), a weight file or a "
            f"pointclm.Network, which every worker loads for itself; got {type(model).__name__}"
        )
    resolve(model)
    return os.fspath(model)

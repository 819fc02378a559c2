"""`pointclm register MODEL [MODEL ...] SCENE`: several part types found in one scan and judged
together (:func:`pointclm.register_models`), one result per model: the report, its JSON, each
model's ground-truth score and the BOP CSV (an object id per model); and the per-model
``--symmetry`` and ``--ground-truth`` flags."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from ..batch import registration_record
from ..batch.options import scan_viewpoint
from ..batch.records import FORMAT_VERSION
from ..errors import InputError
from .args import _write_json
from .bop import _write_bop
from .register import (
    _diagnosis,
    _load_ground_truth,
    _load_symmetry,
    _method_options,
    _report,
    _score_truth,
)

#: `--symmetry none`: this model has no symmetry (where others of the same call do).
NO_SYMMETRY = "none"

#: The outputs that draw or list one model's result; with several models they are refused.
_ONE_MODEL_OUTPUTS = ("png", "ply", "html")


def per_model(values: list[str] | None, n: int, flag: str) -> list[str | None]:
    """A repeatable flag's values, one per model: none given, None each; one, for every model;
    or exactly one per model, in the models' order."""
    if not values:
        return [None] * n
    if len(values) == 1:
        return [values[0]] * n
    if len(values) != n:
        raise InputError(
            f"{len(values)} {flag} for {n} model(s): give one for every model, or one per "
            "model in the models' order"
        )
    return list(values)


def load_symmetries(values: list[str] | None, n: int) -> list[Any]:
    """`--symmetry` (repeatable) for `n` models: each "auto", "none" or a models_info entry
    file, read and checked now (each file once)."""
    loaded: dict[str, Any] = {}
    out: list[Any] = []
    for value in per_model(values, n, "--symmetry"):
        if value is None or value.strip().lower() == NO_SYMMETRY:
            out.append(None)
            continue
        if value not in loaded:
            loaded[value] = _load_symmetry(value)
        out.append(loaded[value])
    return out


def load_truths(values: list[str] | None, n: int) -> list[np.ndarray | None]:
    """`--ground-truth` (repeatable): none, or one file per model, in the models' order (one
    file for several models would score each model's copies against the others' poses)."""
    if not values:
        return [None] * n
    if len(values) != n:
        raise InputError(
            f"{len(values)} --ground-truth for {n} model(s): give one file per model, in the "
            "models' order"
        )
    return [_load_ground_truth(v) for v in values]


def check_several(args: argparse.Namespace) -> None:
    """The outputs that hold one model's result, refused with several models before the work."""
    given = [f"--{f.replace('_', '-')}" for f in _ONE_MODEL_OUTPUTS if getattr(args, f, None)]
    if given:
        raise InputError(
            f"{', '.join(given)}: a picture or list of one model's result; with "
            f"{len(args.model_files)} models use --out (JSON, one result per model), or run "
            "register once per model"
        )


def cmd_register_models(
    args: argparse.Namespace, symmetries: list[Any], truths: list[np.ndarray | None]
) -> int:
    """The several-model form of `pointclm register` (its flags already checked)."""
    from tqdm import tqdm

    from ..clouds.joint import register_models
    from ..io import load_points

    bar = tqdm(total=2, desc="pointclm", unit="stage", disable=args.quiet, leave=False)
    with bar:
        bar.set_postfix_str("loading")
        models = [load_points(f) for f in args.model_files]
        scene = load_points(args.scene_file)
        bar.update()
        bar.set_postfix_str(f"{len(models)} models, judged together")
        options = _method_options(args, lambda: models[0])
        options["viewpoint"] = scan_viewpoint(options["viewpoint"], args.scene_file)
        regs = register_models(models, scene, symmetry=symmetries, **options)
        bar.update()
    scores = [
        None if t is None else _score_truth(r, t, m, s)
        for r, t, m, s in zip(regs, truths, models, symmetries, strict=True)
    ]
    print(_table(args.model_files, regs, scores, args.scene_file))
    for name, reg, truth in zip(args.model_files, regs, scores, strict=True):
        print(f"\n{name}:")
        _report(reg, truth)
    if args.out:
        _write_json(args.out, models_json(args, regs, scores))
    _write_bop(args, regs)
    return 0


def _table(
    names: list[str], regs: list[Any], scores: list[dict[str, Any] | None], scene: str
) -> str:
    """One row per model: its copies, ambiguous poses, best confidence and, with
    `--ground-truth`, the true poses found."""
    width = max(len("model"), *(len(Path(n).name) for n in names))
    truth = any(s is not None for s in scores)
    head = f"  {'model':<{width}}  copies  ambiguous  best confidence" + "  true found" * truth
    rows = [f"{len(names)} models in {Path(scene).name}, judged together:", head]
    for name, reg, score in zip(names, regs, scores, strict=True):
        best = max((c.confidence for c in reg.instances), default=float("nan"))
        row = (
            f"  {Path(name).name:<{width}}  {len(reg.instances):6d}  {len(reg.ambiguous):9d}  "
            + (f"{best:15.3f}" if reg.instances else f"{'-':>15}")
        )
        if truth:
            found = "-" if score is None else f"{len(score['found'])} of {score['poses']}"
            row += f"  {found:>10}"
        rows.append(row)
    return "\n".join(rows)


def models_json(
    args: argparse.Namespace, regs: list[Any], scores: list[dict[str, Any] | None]
) -> dict[str, Any]:
    """`register --out` with several models: the scene once, then one entry per model, each
    what the one-model form writes for it (less the version and scene)."""
    entries = []
    for name, reg, truth in zip(args.model_files, regs, scores, strict=True):
        record = registration_record(reg, _diagnosis(reg))
        if truth is not None:
            for entry, j in zip(record["instances"], truth["instance_truth"], strict=True):
                entry["true_pose"] = j
        entries.append(
            {
                "model": name,
                **record,
                "ground_truth": None
                if truth is None
                else {k: v for k, v in truth.items() if k != "instance_truth"},
            }
        )
    return {"format_version": FORMAT_VERSION, "scene": args.scene_file, "models": entries}

"""Resumable training checkpoints without pickle: tensors in safetensors, the rest in JSON.

``torch.save``/``torch.load(weights_only=False)`` pickle, and unpickling runs code from the
file: a run folder copied from someone else could execute anything on ``--resume``. A
checkpoint here is two plain files in the run folder:

- ``checkpoint-<iteration>.safetensors``: the model's state dict (``model.<name>``), the
  optimizer's per-parameter tensors (``optimizer.<param>.<key>``) and torch's CPU RNG state
  (``rng.torch``, uint8);
- ``checkpoint.json``: the iteration, elapsed seconds, the best validation so far, the
  optimizer's hyper-parameters (``param_groups``) and non-tensor state, and the name and
  SHA-256 of the tensor file it belongs to.

Saving writes a new tensor file, then replaces the JSON in one rename, then removes older
tensor files: a run killed at any moment leaves a JSON naming a complete tensor file, so
``--resume`` never meets a half-written or mismatched pair.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path
from typing import Any

from ..io.files import atomic_path

__all__ = ["CHECKPOINT_JSON", "LEGACY_CHECKPOINT", "load_checkpoint", "save_checkpoint"]

CHECKPOINT_JSON = "checkpoint.json"
#: What earlier versions wrote (a pickle); it is never loaded.
LEGACY_CHECKPOINT = "checkpoint.pt"
_FORMAT = "pointclm-checkpoint"
_VERSION = 1


def _tensor_name(iteration: int) -> str:
    return f"checkpoint-{iteration:09d}.safetensors"


def save_checkpoint(
    folder: str | Path,
    model: Any,
    optimizer: Any,
    *,
    iteration: int,
    best: dict[str, Any] | None,
    elapsed: float,
) -> Path:
    """Write the checkpoint of ``iteration`` into ``folder``; returns the JSON's path."""
    import torch
    from safetensors.torch import save_file

    folder = Path(folder)
    tensors: dict[str, Any] = {
        f"model.{k}": v.detach().cpu().contiguous() for k, v in model.state_dict().items()
    }
    opt = optimizer.state_dict()
    plain_state: dict[str, dict[str, Any]] = {}
    for pid, entries in opt["state"].items():
        plain: dict[str, Any] = {}
        for key, value in entries.items():
            if isinstance(value, torch.Tensor):
                tensors[f"optimizer.{pid}.{key}"] = value.detach().cpu().contiguous()
            else:
                plain[key] = value
        plain_state[str(pid)] = plain
    tensors["rng.torch"] = torch.get_rng_state().contiguous()
    name = _tensor_name(iteration)
    with atomic_path(folder / name) as tmp:
        save_file(tensors, str(tmp))
        digest = _sha256(tmp)
    meta = {
        "format": _FORMAT,
        "version": _VERSION,
        "iteration": int(iteration),
        "elapsed": float(elapsed),
        "best": best,
        "optimizer": {"param_groups": opt["param_groups"], "state": plain_state},
        "tensors": name,
        "tensors_sha256": digest,
    }
    json_path = folder / CHECKPOINT_JSON
    with atomic_path(json_path) as tmp:
        tmp.write_text(json.dumps(meta, indent=2, allow_nan=False) + "\n")
    for old in folder.glob("checkpoint-*.safetensors"):
        if old.name != name:
            old.unlink(missing_ok=True)
    return json_path


def load_checkpoint(
    folder: str | Path, model: Any, optimizer: Any, device: str = "cpu"
) -> dict[str, Any] | None:
    """Restore ``model``, ``optimizer`` and torch's RNG from ``folder``'s checkpoint.

    Returns
    -------
    dict or None
        ``iteration``, ``elapsed`` and ``best`` of the checkpoint; None when the folder
        holds none.

    Raises
    ------
    ValueError
        A malformed or mismatched checkpoint, or only a legacy pickle ``checkpoint.pt``
        (which is never unpickled).
    """
    import torch

    folder = Path(folder)
    json_path = folder / CHECKPOINT_JSON
    if not json_path.is_file():
        if (folder / LEGACY_CHECKPOINT).exists():
            raise ValueError(
                f"{folder / LEGACY_CHECKPOINT} is a pickle checkpoint of an older pointclm; "
                "it is not loaded (unpickling runs code from the file). Start a new run, "
                "or resume in a folder written by this version"
            )
        return None
    meta = _read_meta(json_path)
    tensors = _verified_tensors(folder, json_path, meta)
    model_state = {k[6:]: v for k, v in tensors.items() if k.startswith("model.")}
    optimizer_state = _optimizer_state(meta, tensors, device)
    rng = tensors.get("rng.torch")
    try:
        model.load_state_dict({k: v.to(device) for k, v in model_state.items()}, strict=True)
        optimizer.load_state_dict(optimizer_state)
        if rng is None:
            raise ValueError("no rng.torch tensor")
        torch.set_rng_state(rng.to(torch.uint8))
    except (RuntimeError, ValueError, KeyError, TypeError) as e:
        raise ValueError(f"{json_path}: the checkpoint does not fit this run ({e})") from None
    return {"iteration": meta["iteration"], "elapsed": meta["elapsed"], "best": meta["best"]}


def _verified_tensors(folder: Path, json_path: Path, meta: dict[str, Any]) -> dict[str, Any]:
    """The checkpoint's tensors, read only from the file its JSON names and hashes."""
    from safetensors.torch import load_file

    tensor_path = folder / meta["tensors"]
    if not tensor_path.is_file():
        raise ValueError(f"{json_path}: its tensor file {tensor_path.name} is missing")
    if _sha256(tensor_path) != meta["tensors_sha256"]:
        raise ValueError(f"{json_path}: {tensor_path.name} is not the file it was saved with")
    try:
        return dict(load_file(str(tensor_path), device="cpu"))
    except Exception as e:  # safetensors raises its own error type on a corrupt file
        raise ValueError(f"{tensor_path}: unreadable tensors ({e})") from None


def _optimizer_state(meta: dict[str, Any], tensors: dict[str, Any], device: str) -> dict[str, Any]:
    """The optimizer's state dict rebuilt from the JSON (plain values, param groups) and the
    ``optimizer.<param>.<name>`` tensors."""
    state: dict[int, dict[str, Any]] = {}
    for pid, plain in meta["optimizer"]["state"].items():
        state[int(pid)] = dict(plain)
    for key, value in tensors.items():
        if key.startswith("optimizer."):
            _, pid, name = key.split(".", 2)
            state.setdefault(int(pid), {})[name] = value.to(device)
    groups = [dict(g) for g in meta["optimizer"]["param_groups"]]
    for g in groups:
        if isinstance(g.get("betas"), list):
            g["betas"] = tuple(g["betas"])  # JSON has no tuples; Adam compares them
    return {"state": state, "param_groups": groups}


def _read_meta(path: Path) -> dict[str, Any]:
    try:
        meta = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: unreadable checkpoint ({e})") from None
    if not isinstance(meta, dict) or meta.get("format") != _FORMAT:
        raise ValueError(f"{path}: not a pointclm checkpoint")
    if meta.get("version") != _VERSION:
        raise ValueError(f"{path}: checkpoint version {meta.get('version')!r}, need {_VERSION}")
    it, elapsed, best = meta.get("iteration"), meta.get("elapsed"), meta.get("best")
    opt, name = meta.get("optimizer"), meta.get("tensors")
    ok = (
        isinstance(it, int)
        and not isinstance(it, bool)
        and it >= 0
        and isinstance(elapsed, int | float)
        and math.isfinite(elapsed)
        and elapsed >= 0
        and (best is None or isinstance(best, dict))
        and isinstance(opt, dict)
        and isinstance(opt.get("param_groups"), list)
        and all(isinstance(g, dict) for g in opt["param_groups"])
        and isinstance(opt.get("state"), dict)
        and all(k.isdigit() and isinstance(v, dict) for k, v in opt["state"].items())
        and isinstance(name, str)
        and name == os.path.basename(name)
        and name.startswith("checkpoint-")
        and name.endswith(".safetensors")
        and isinstance(meta.get("tensors_sha256"), str)
    )
    if not ok:
        raise ValueError(f"{path}: malformed checkpoint (missing or mistyped fields)")
    return meta


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()

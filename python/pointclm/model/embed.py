"""Inference: correspondences -> L2-normalised embeddings with a trained network."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from .weights import load_model, require_device, require_torch, weights_path

__all__ = ["embed", "resolve_model"]


@lru_cache(maxsize=4)
def _cached(path: str, device: str) -> Any:
    return load_model(path, device=device)


def resolve_model(model: Any, device: str = "cpu") -> Any:
    """A shipped name ("default", "paper") or a path -> that network (loaded once and cached);
    a torch module -> itself."""
    if isinstance(model, str | Path):
        return _cached(str(weights_path(model).resolve()), device)
    return model


def embed(correspondences: np.ndarray, model: Any = "default", device: str = "cpu") -> np.ndarray:
    """(N, 6) float64 correspondences -> (N, C) float64 unit embeddings, with torch.

    A network with inputs beyond the coordinates reads (N, `config.input_channels`) rows
    packed as `SCNonlocal` documents them (coordinates, normals, similarity).
    `pointclm.model.load_network(model).embed(...)` computes the same in Rust without torch
    (with `normals=` and `similarity=` as separate arguments).
    """
    torch = require_torch()
    require_device(device)
    net = resolve_model(model, device)
    with torch.no_grad():
        corr = torch.tensor(correspondences, dtype=torch.float32, device=device)[None]
        feats = net(corr)[0]
    return feats.double().cpu().numpy()

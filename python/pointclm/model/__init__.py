"""The contrastively trained correspondence embedding.

Weight files and the Rust network (`load_network`, `load_metadata`, `weights_path`) need only
numpy; the torch network, its training and `embed` need torch (`pip install .[train]`), which
is imported on first use of those names.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

from .weights import (
    DEFAULT_WEIGHTS,
    SHIPPED,
    load_metadata,
    load_model,
    load_network,
    save_model,
    weights_path,
)

__all__ = [
    "DEFAULT_WEIGHTS",
    "SHIPPED",
    "load_metadata",
    "EmbeddingConfig",
    "SCNonlocal",
    "contrastive_loss",
    "embed",
    "load_model",
    "load_network",
    "negative_distances",
    "normal_consistency",
    "resolve_model",
    "save_model",
    "spatial_consistency",
    "weights_path",
]

# name -> submodule; these import torch at module level
_LAZY = {
    "EmbeddingConfig": "network",
    "SCNonlocal": "network",
    "spatial_consistency": "network",
    "normal_consistency": "network",
    "contrastive_loss": "loss",
    "negative_distances": "loss",
    "embed": "embed",
    "resolve_model": "embed",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

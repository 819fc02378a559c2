"""The contrastively trained correspondence embedding (needs torch: `pip install .[train]`)."""

from .embed import embed, resolve_model
from .loss import contrastive_loss, negative_distances
from .network import EmbeddingConfig, SCNonlocal, spatial_consistency
from .weights import DEFAULT_WEIGHTS, SHIPPED, load_metadata, load_model, save_model

__all__ = [
    "DEFAULT_WEIGHTS",
    "SHIPPED",
    "load_metadata",
    "EmbeddingConfig",
    "SCNonlocal",
    "contrastive_loss",
    "embed",
    "load_model",
    "negative_distances",
    "resolve_model",
    "save_model",
    "spatial_consistency",
]

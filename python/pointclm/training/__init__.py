"""Contrastive training of the correspondence embedding (needs torch: `pip install .[train]`)."""

from .config import PRESETS, TrainConfig
from .loop import train, validate

__all__ = ["PRESETS", "TrainConfig", "train", "validate"]

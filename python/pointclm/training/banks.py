"""The realistic scene banks a training run uses: built from the config on every core, or
loaded from a saved bank or from an earlier run's folder.

Kept apart from :mod:`pointclm.training.loop` because building a bank needs no model or
optimiser, and the command line builds banks without training.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .config import TrainConfig
from .realistic import SceneBank


def _scene_bank(path: str | None, out: Path, name: str, build: Any) -> SceneBank:
    """A saved bank when given, else built once and saved in the run folder (a resumed run
    finds it there)."""
    if path:
        return SceneBank.load(path)
    cached = out / name
    if cached.is_file():
        return SceneBank.load(cached)
    bank = build()
    bank.save(cached)
    return bank


def realistic_banks(
    cfg: TrainConfig, out: Path, progress: bool
) -> tuple[SceneBank | None, SceneBank | None]:
    """The realistic training and validation banks (None, None without realistic data):
    the saved ones the config names, else those of an earlier run in `out`, else built on
    every core and saved in `out` as ``scene_bank.npz`` and ``val_scene_bank.npz``."""
    if cfg.realistic_fraction <= 0:
        return None, None
    scenes = _scene_bank(
        cfg.realistic_bank, out, "scene_bank.npz", lambda: training_bank(cfg, progress=progress)
    )
    val_real = _scene_bank(
        cfg.val_realistic_bank,
        out,
        "val_scene_bank.npz",
        lambda: validation_bank(cfg, progress=progress),
    )
    return scenes, val_real


def training_bank(
    cfg: TrainConfig, workers: int | None = None, progress: bool = False
) -> SceneBank:
    """The realistic training bank `cfg` describes: its data models and random procedural
    shapes, built in `workers` processes (default: every core)."""
    from ..datasets.procedural import procedural_family_names

    shapes = procedural_family_names(cfg.procedural_shapes, cfg.seed)
    return SceneBank.build(
        [*cfg.realistic_models, *shapes],
        [cfg.realistic_scenes_per_model] * len(cfg.realistic_models)
        + [cfg.procedural_scenes_per_shape] * len(shapes),
        cfg.seed,
        cfg.data_dir,
        workers,
        progress=progress,
    )


def validation_bank(
    cfg: TrainConfig, workers: int | None = None, progress: bool = False
) -> SceneBank:
    """The realistic validation bank: `cfg.val_shapes`, never trained on."""
    return SceneBank.build(
        cfg.val_shapes,
        cfg.val_realistic_scenes_per_model,
        cfg.seed + 1,
        cfg.data_dir,
        workers,
        progress=progress,
    )

"""`TrainConfig`: everything a training run depends on, written next to the weights."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

__all__ = ["PRESETS", "TrainConfig"]

# Shapes are split by identity: the synthetic benchmark's bunny is never trained on, and
# validation uses shapes that training never sees either.
TRAIN_SHAPES = (
    "torus",
    "box",
    "cylinder",
    "cone",
    "capsule",
    "helix-tube",
    "stanford/dragon",
    "stanford/happy",
    "modelnet/bathtub",
)
VAL_SHAPES = ("stanford/armadillo", "modelnet/bed")
# Realistic scenes (range-sensor views, FPFH matches) of the asymmetric training models: a
# symmetric shape's mirrored matches are geometrically consistent but labelled wrong.
REALISTIC_MODELS = ("stanford/dragon", "stanford/happy", "modelnet/bathtub")


@dataclass(frozen=True)
class TrainConfig:
    """A training run. `preset("cpu")` fits 2 CPU cores in under 45 minutes; `preset("paper")`
    is the paper's network and schedule for a GPU."""

    depth: int = 12
    width: int = 128
    sigma_d: float = 0.05
    iterations: int = 15000
    batch_size: int = 16
    n_correspondences: int = 1000
    lr: float = 1e-3
    weight_decay: float = 1e-6
    margin_pos: float = 0.1
    margin_neg: float = 1.4
    negatives: str = "hardest"
    train_outlier_blocks: int = 10  # outlier rate 0.95, as the paper trains
    wrong_match_fraction: float = 0.5  # share of outliers made spatially structured
    train_shapes: tuple[str, ...] = TRAIN_SHAPES
    val_shapes: tuple[str, ...] = VAL_SHAPES
    val_scenes: int = 64
    val_outlier_blocks: int = 40
    val_every: int = 500
    checkpoint_every: int = 500
    seed: int = 0
    data_dir: str | None = None
    shape_bank: str | None = None
    num_workers: int = 0
    # Share of each batch's scenes drawn from the realistic bank (0 = synthetic only).
    realistic_fraction: float = 0.0
    realistic_models: tuple[str, ...] = REALISTIC_MODELS
    realistic_scenes_per_model: int = 500
    realistic_bank: str | None = None  # a saved SceneBank; built (and saved) when None
    # Near misses (outliers within this many voxels of an instance) are left out of the
    # loss; 6 = the pose stage's inlier threshold at the point-cloud scale (0 = keep them).
    realistic_ignore_voxels: float = 6.0
    val_realistic_scenes_per_model: int = 40
    val_realistic_bank: str | None = None
    # Pipeline thresholds validation registers with (lengths in synthetic units; realistic
    # scenes scale them to their voxel). The synthetic one: the thresholds chosen for the
    # shipped networks. Smaller counts for realistic scenes: an instance there holds a handful
    # of inliers, and a learned embedding is what lets the pipeline accept so few.
    val_config: dict[str, Any] = field(default_factory=lambda: {"tau_n": 5})
    val_realistic_config: dict[str, Any] = field(
        default_factory=lambda: {"tau_n": 3, "min_cluster_size": 5}
    )
    init_weights: str | None = None  # start from these weights (fine-tuning)
    # Inputs beyond coordinates (pointclm.cues.INPUTS): only realistic scenes carry them, so
    # a network with inputs trains on the realistic bank alone (realistic_fraction 1).
    inputs: tuple[str, ...] = ()
    normal_tolerance: float = 0.5
    # What the BatchNorms normalise with (EmbeddingConfig.normalization): "scene" normalises
    # every scene by its own rows in training and at inference alike (realistic training,
    # whose scenes differ too much for shared statistics).
    normalization: str = "running"
    # Realistic scenes stacked per batch, close in size and cut to the smallest (1 = each
    # scene alone, whole). With "running" normalization the stack shares BatchNorm
    # statistics; with "scene" each scene keeps its own.
    realistic_group: int = 1
    # Random procedural shapes (pointclm.datasets.procedural_family_names) added to the
    # realistic training models, so the embedding learns consistency rather than shapes.
    procedural_shapes: int = 0
    procedural_scenes_per_shape: int = 4
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for f in fields(self):
            _check_type(f.name, str(f.type), getattr(self, f.name))
        if self.negatives not in ("hardest", "random"):
            raise ValueError(f"negatives must be 'hardest' or 'random', got {self.negatives!r}")
        for name in (
            "iterations",
            "batch_size",
            "n_correspondences",
            "val_every",
            "checkpoint_every",
            "depth",
            "width",
        ):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1")
        if set(self.train_shapes) & set(self.val_shapes):
            raise ValueError("train_shapes and val_shapes must not share a shape")
        if set(self.realistic_models) & set(self.val_shapes):
            raise ValueError("realistic_models and val_shapes must not share a shape")
        if not 0.0 <= self.realistic_fraction <= 1.0:
            raise ValueError(
                f"realistic_fraction must lie in [0, 1], got {self.realistic_fraction}"
            )
        from ..cues import check_inputs

        if tuple(self.inputs) != check_inputs(self.inputs):
            raise ValueError(f"inputs must be in the order {check_inputs(self.inputs)}")
        if self.inputs and self.realistic_fraction < 1.0:
            raise ValueError(
                f"a network with inputs {self.inputs} trains on realistic scenes only "
                "(synthetic ones carry no cues): set realistic_fraction to 1"
            )
        if self.realistic_group < 1:
            raise ValueError(f"realistic_group must be >= 1, got {self.realistic_group}")
        if self.procedural_shapes < 0 or self.procedural_scenes_per_shape < 1:
            raise ValueError("need procedural_shapes >= 0 and procedural_scenes_per_shape >= 1")

    @classmethod
    def preset(cls, name: str, **overrides: Any) -> TrainConfig:
        if not isinstance(name, str) or name not in PRESETS:
            raise ValueError(f"unknown preset {name!r}; choose from {sorted(PRESETS)}")
        unknown = set(overrides) - {f.name for f in fields(cls)}
        if unknown:
            raise ValueError(f"unknown training config fields: {sorted(unknown)}")
        return cls(**{**PRESETS[name], **overrides})

    @classmethod
    def from_file(cls, path: str | Path, **overrides: Any) -> TrainConfig:
        """A JSON file of fields; `"preset": NAME` starts from a preset."""
        from ..io.files import read_checked  # only a regular file (a FIFO would block)

        try:
            raw = json.loads(read_checked(path, "training config file")[1])
        except UnicodeDecodeError:
            raise ValueError(f"{path}: not a JSON text file") from None
        except json.JSONDecodeError as e:
            raise ValueError(f"{path}: not valid JSON ({e})") from None
        if not isinstance(raw, dict):
            raise ValueError(f"{path}: expected a JSON object of TrainConfig fields")
        preset = raw.pop("preset", "cpu")
        if not isinstance(preset, str) or preset not in PRESETS:
            raise ValueError(f"{path}: unknown preset {preset!r}; choose from {sorted(PRESETS)}")
        base = PRESETS[preset]
        known = {f.name for f in fields(cls)}
        unknown = set(raw) - known
        if unknown:
            raise ValueError(f"unknown training config fields: {sorted(unknown)}")
        merged = {**base, **raw, **overrides}
        for key in ("train_shapes", "val_shapes", "realistic_models", "inputs"):
            if isinstance(merged.get(key), list):
                merged[key] = tuple(merged[key])
        return cls(**merged)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["train_shapes"], d["val_shapes"] = list(self.train_shapes), list(self.val_shapes)
        d["realistic_models"] = list(self.realistic_models)
        d["inputs"] = list(self.inputs)
        return d

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")


def _check_type(name: str, annotation: str, value: Any) -> None:
    """Each field holds what its annotation says, so a JSON config with ``"depth": [1]`` or
    ``"lr": "fast"`` fails with a ValueError naming the field rather than deep in training."""
    optional = annotation.endswith("| None")
    if optional and value is None:
        return
    kind = annotation.removesuffix("| None").strip()
    if kind == "int":
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind == "float":
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        ok = ok and math.isfinite(value)
    elif kind == "str":
        ok = isinstance(value, str)
    elif kind.startswith("tuple"):
        ok = isinstance(value, tuple) and all(isinstance(v, str) for v in value)
    elif kind.startswith("dict"):
        ok = isinstance(value, dict) and all(isinstance(k, str) for k in value)
    else:  # pragma: no cover - a new field type must be added above
        ok = True
    if not ok:
        raise ValueError(f"training config field {name} must be {annotation}, got {value!r}")


PRESETS: dict[str, dict[str, Any]] = {
    # Compact network, short schedule: the shipped default when no GPU was available.
    "cpu": {
        "depth": 6,
        "width": 64,
        "iterations": 1500,
        "batch_size": 4,
        "lr": 1e-3,
        "val_every": 250,
        "checkpoint_every": 250,
        "val_scenes": 32,
    },
    # Compact network trained long on a GPU (what ships when one was available).
    "compact-gpu": {
        "depth": 6,
        "width": 64,
        "iterations": 15000,
        "batch_size": 16,
        "lr": 1e-3,
        "num_workers": 8,
    },
    # The paper: 12 blocks x 128 channels, batch 16, 15K iterations.
    "paper": {
        "depth": 12,
        "width": 128,
        "iterations": 15000,
        "batch_size": 16,
        "lr": 1e-3,
        "num_workers": 8,
    },
    # The compact network fine-tuned on a mixture: 6 realistic scenes (range-sensor views,
    # FPFH matches; a bank built once) and 2 synthetic ones per batch. On 2 CPU cores: the
    # bank of 1500 scenes takes about 15 minutes, the 1500 iterations about 8.
    "realistic-cpu": {
        "depth": 6,
        "width": 64,
        "init_weights": "default",
        "iterations": 1500,
        "batch_size": 8,
        "realistic_fraction": 0.75,
        "lr": 5e-4,
        "val_every": 250,
        "checkpoint_every": 250,
        "val_scenes": 32,
    },
    # Realistic scenes only, of 3 data models and 600 random procedural shapes, the network
    # taking normals and match similarity: sized for a GPU (the bank, 2,700 scenes,
    # is built beforehand on every core: `pointclm train --banks-only`).
    "realistic-gpu": {
        "depth": 6,
        "width": 64,
        "iterations": 4000,
        "batch_size": 16,
        "lr": 1e-3,
        "realistic_fraction": 1.0,
        "realistic_scenes_per_model": 100,
        "procedural_shapes": 600,
        "procedural_scenes_per_shape": 4,
        "inputs": ("normals", "similarity"),
        "normalization": "scene",
        "val_every": 250,
        "checkpoint_every": 250,
        "num_workers": 4,
    },
    # A few steps, for tests and CI.
    "smoke": {
        "depth": 2,
        "width": 16,
        "iterations": 6,
        "batch_size": 2,
        "n_correspondences": 200,
        "val_every": 3,
        "checkpoint_every": 3,
        "val_scenes": 2,
    },
}

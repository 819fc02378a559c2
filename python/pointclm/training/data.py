"""Training batches generated on the fly, seeded by the iteration so a run is reproducible and
resumable: the synthetic protocol at the training outlier rate, with part of the outliers made
spatially structured (wrong matches onto the instances' surfaces, as feature matching makes)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..datasets import load_shape, make_scene
from ..datasets.synthetic import label_correspondences
from ..io.arrays import read_npz_members
from ..io.files import read_checked

__all__ = ["ShapeBank", "make_batch", "structured_outliers"]

SHAPE_POINTS = 2048


class ShapeBank:
    """Unit-sphere clouds (2048 points) by name, loaded once; saved as one .npz so that a
    machine without the meshes (a GPU box) can train on exactly the same shapes."""

    def __init__(self, clouds: dict[str, np.ndarray]) -> None:
        self.clouds = clouds

    @classmethod
    def build(cls, names: Sequence[str], data_dir: str | None, seed: int = 0) -> ShapeBank:
        return cls({n: load_shape(n, SHAPE_POINTS, seed, data_dir=data_dir) for n in names})

    @classmethod
    def load(cls, path: str | Path) -> ShapeBank:
        """A bank saved by :meth:`save`; read without pickle, sizes checked before reading.

        Raises FileNotFoundError for a missing file, ValueError for anything else wrong."""
        file, raw = read_checked(path, "shape bank")
        try:
            arrays, _ = read_npz_members(raw, None)
        except ValueError as e:
            raise ValueError(f"{file}: {e}") from None
        for name, cloud in arrays.items():
            if cloud.ndim != 2 or cloud.shape[1] != 3 or len(cloud) == 0:
                raise ValueError(f"{file}: shape {name!r} has shape {cloud.shape}, not (N, 3)")
            if not np.isfinite(cloud).all():
                raise ValueError(f"{file}: shape {name!r} has non-finite points")
        if not arrays:
            raise ValueError(f"{file}: the shape bank is empty")
        return cls({k: v.copy() for k, v in arrays.items()})

    def save(self, path: str | Path) -> None:
        np.savez_compressed(path, **self.clouds)  # type: ignore[arg-type]

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self.clouds:
            raise ValueError(f"shape {name!r} is not in the shape bank ({sorted(self.clouds)})")
        return self.clouds[name]


def structured_outliers(
    corr: np.ndarray,
    labels: np.ndarray,
    poses: np.ndarray,
    source: np.ndarray,
    fraction: float,
    rng: np.random.Generator,
    noise: float = 0.01,
) -> tuple[np.ndarray, np.ndarray]:
    """Moves `fraction` of the outliers' targets onto an instance's surface, at the image of
    a wrong source point: consistent-looking distractors that uniform noise never produces."""
    out = labels < 0
    pick = np.flatnonzero(out & (rng.random(len(labels)) < fraction))
    if len(pick) == 0 or len(poses) == 0:
        return corr, labels
    corr = corr.copy()
    k = rng.integers(0, len(poses), len(pick))
    wrong = source[rng.integers(0, len(source), len(pick))]
    moved = np.einsum("nij,nj->ni", poses[k, :3, :3], wrong) + poses[k, :3, 3]
    corr[pick, 3:] = moved + rng.normal(0.0, noise, moved.shape)
    return corr, label_correspondences(corr, poses)


def make_batch(
    bank: ShapeBank,
    shapes: Sequence[str],
    seed: int,
    batch_size: int,
    n_corr: int,
    outlier_blocks: int,
    wrong_fraction: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(B, n_corr, 6) float32 correspondences and (B, n_corr) int64 labels."""
    rng = np.random.default_rng(seed)
    corrs, labels = [], []
    for _ in range(batch_size):
        cloud = bank[shapes[int(rng.integers(len(shapes)))]]
        # new points and proportions every scene: the protocol uses the cloud's first 256
        cloud = cloud[rng.permutation(len(cloud))] * rng.uniform(0.6, 1.4, 3)
        scene = make_scene(
            int(rng.integers(2**62)), shape=cloud, n_keep=n_corr, n_outlier_blocks=outlier_blocks
        )
        c, lab = structured_outliers(
            scene.correspondences, scene.labels, scene.poses, scene.source, wrong_fraction, rng
        )
        corrs.append(c)
        labels.append(lab)
    return np.stack(corrs).astype(np.float32), np.stack(labels)

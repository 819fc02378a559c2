"""The paper's synthetic multi-instance benchmark, seeded.

Why: the PointCLM paper's synthetic numbers (SPEC section 3) come from a generator in the
authors' code that is not seeded, so its test set cannot be rebuilt. This module follows the
same recipe exactly, from a ``seed``, so that every scene can be rebuilt bit for bit:

1. source = the first 256 points of a unit-sphere-normalised 2048-point cloud of a shape;
2. 10 slots, of which ``n_real`` ~ U{5..10} (chosen at random) are real instances: Gaussian noise
   (sigma 0.01, clipped to +-0.05 per coordinate) is added to the source, then
   ``R = Rx(a) Ry(b) Rz(c)`` with a, b, c ~ U[0, 2 pi) and t ~ U[0, 5)^3; target = R (x + n) + t;
3. dropped slots keep their source points but get U[0, 6)^3 targets;
4. ``n_outlier_blocks`` more blocks of 256 rows pair the same source points with U[0, 6)^3
   targets (40 blocks: outlier rate 0.98, the test protocol; 10 blocks: 0.95, training);
5. all rows are shuffled and the first ``n_keep`` (1000) kept: about 2 % of the rows per
   instance at 40 blocks, 5 % at 10;
6. a row's label is the instance k with ``||T_k x - y|| < 0.05`` (the smallest residual if
   several), else -1.

Randomness: ``SeedSequence(seed)`` is split into two streams, one for sampling the shape and one
for the scene, so that the same seed gives the same poses and outliers whatever the shape.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from .shapes import load_shape, normalize_unit_sphere

__all__ = [
    "SyntheticScene",
    "label_correspondences",
    "make_planted_scene",
    "make_scene",
    "make_scenes",
]

#: Points in the normalised shape cloud the source is cut from.
SHAPE_POINTS = 2048
#: Points in the source (and rows per slot or outlier block).
BLOCK = 256
#: Slots: real instances plus dropped ones.
N_SLOTS = 10
#: Side of the box of instance translations; random targets fill a box of side 1.2 times it.
TRANSLATION_RANGE = 5.0
OUTLIER_RANGE = 6.0

ShapeArg = str | os.PathLike[str] | np.ndarray


@dataclass(frozen=True, eq=False)
class SyntheticScene:
    """One multi-instance registration problem with its ground truth.

    Attributes
    ----------
    correspondences : numpy.ndarray
        (N, 6) float64 rows ``(x, y)``: source xyz then target xyz.
    labels : numpy.ndarray
        (N,) int64: index into ``poses`` of the instance a row is an inlier of, or -1.
    poses : numpy.ndarray
        (M, 4, 4) float64 ``T_target_source`` of the real instances (maps source into target).
    source : numpy.ndarray
        (S, 3) float64 source cloud (S = 256 for the protocol).
    shape : str
        Name of the shape (``"array"`` for a user array).
    seed : int
        Seed that rebuilds the scene with the same arguments.

    Notes
    -----
    The arrays are read-only; copy them to modify.
    """

    correspondences: np.ndarray
    labels: np.ndarray
    poses: np.ndarray
    source: np.ndarray
    shape: str
    seed: int

    def __post_init__(self) -> None:
        for arr in (self.correspondences, self.labels, self.poses, self.source):
            arr.setflags(write=False)

    @property
    def n_instances(self) -> int:
        """Number of real instances M."""
        return len(self.poses)

    @property
    def inlier_ratio(self) -> float:
        """Fraction of rows that are inliers of some instance (all instances together)."""
        return float(np.mean(self.labels >= 0)) if len(self.labels) else 0.0

    @property
    def source_points(self) -> np.ndarray:
        """(N, 3) source side of the correspondences."""
        return self.correspondences[:, :3]

    @property
    def target_points(self) -> np.ndarray:
        """(N, 3) target side of the correspondences."""
        return self.correspondences[:, 3:]


def _rotations_xyz(angles: np.ndarray) -> np.ndarray:
    """``Rx(a) @ Ry(b) @ Rz(c)`` for each row ``(a, b, c)`` of ``angles``; (K, 3, 3)."""
    c, s = np.cos(angles), np.sin(angles)
    one, zero = np.ones(len(angles)), np.zeros(len(angles))
    rx = np.stack([one, zero, zero, zero, c[:, 0], -s[:, 0], zero, s[:, 0], c[:, 0]], 1)
    ry = np.stack([c[:, 1], zero, s[:, 1], zero, one, zero, -s[:, 1], zero, c[:, 1]], 1)
    rz = np.stack([c[:, 2], -s[:, 2], zero, s[:, 2], c[:, 2], zero, zero, zero, one], 1)
    return rx.reshape(-1, 3, 3) @ ry.reshape(-1, 3, 3) @ rz.reshape(-1, 3, 3)


def _poses(rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
    poses = np.tile(np.eye(4), (len(rot), 1, 1))
    poses[:, :3, :3] = rot
    poses[:, :3, 3] = trans
    return poses


def label_correspondences(
    correspondences: np.ndarray, poses: np.ndarray, threshold: float = 0.05
) -> np.ndarray:
    """Ground-truth instance label of each correspondence.

    Parameters
    ----------
    correspondences : numpy.ndarray
        (N, 6) rows ``(x, y)``.
    poses : numpy.ndarray
        (M, 4, 4) ``T_target_source``.
    threshold : float, default 0.05
        A row is an inlier of instance k if ``||T_k x - y|| < threshold``.

    Returns
    -------
    numpy.ndarray
        (N,) int64: the instance with the smallest residual among those under the threshold,
        or -1.
    """
    corr = np.asarray(correspondences, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    if len(poses) == 0 or len(corr) == 0:
        return np.full(len(corr), -1, dtype=np.int64)
    x, y = corr[:, :3], corr[:, 3:]
    warped = np.einsum("kij,nj->kni", poses[:, :3, :3], x) + poses[:, None, :3, 3]
    res = np.linalg.norm(warped - y[None], axis=2)  # (M, N)
    best = res.argmin(axis=0)
    ok = res[best, np.arange(len(corr))] < threshold
    return np.where(ok, best, -1).astype(np.int64)


def _shape_cloud(
    shape: ShapeArg,
    n_points: int,
    rng: np.random.Generator,
    data_dir: str | os.PathLike[str] | None,
    shape_name: str | None,
    normalize: bool = True,
) -> tuple[np.ndarray, str]:
    if isinstance(shape, np.ndarray):
        if shape.ndim != 2 or shape.shape[1] != 3 or len(shape) < n_points:
            raise ValueError(f"shape array must be (P, 3) with P >= {n_points}, got {shape.shape}")
        cloud = normalize_unit_sphere(shape) if normalize else np.asarray(shape, np.float64)
        return cloud, shape_name or "array"
    cloud = load_shape(shape, n_points, rng, data_dir=data_dir)
    return cloud, shape_name or os.fspath(shape)


def _check_seed(seed: int) -> int:
    seed = int(seed)
    if seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed}")
    return seed


def make_scene(
    seed: int,
    shape: ShapeArg = "bunny",
    *,
    n_outlier_blocks: int = 40,
    n_keep: int | None = 1000,
    noise_sigma: float = 0.01,
    noise_clip: float = 0.05,
    label_threshold: float = 0.05,
    data_dir: str | os.PathLike[str] | None = None,
    shape_name: str | None = None,
    normalize: bool = True,
) -> SyntheticScene:
    """Build one scene of the paper's synthetic protocol.

    Parameters
    ----------
    seed : int
        Non-negative seed; the same arguments and seed give identical arrays.
    shape : str or os.PathLike or numpy.ndarray, default "bunny"
        A name or file for :func:`pointclm.datasets.load_shape` (sampled to 2048 points from
        the seed), or a (P, 3) array with P >= 2048 (e.g. one ModelNet40 cloud), which is
        re-normalised to the unit sphere (see ``normalize``); the source is its first 256 points.
    n_outlier_blocks : int, default 40
        Extra blocks of 256 outlier rows: 40 gives the test protocol's outlier rate 0.98,
        10 the training protocol's 0.95.
    n_keep : int or None, default 1000
        Rows kept after shuffling (``None``: all ``256 * (10 + n_outlier_blocks)``).
    noise_sigma, noise_clip : float
        Gaussian noise added to the source of each real instance, clipped per coordinate.
    label_threshold : float, default 0.05
        Residual under which a row is an inlier of an instance.
    data_dir : str or os.PathLike, optional
        Data folder in which shape names such as ``"stanford/dragon"`` are resolved.
    shape_name : str, optional
        Name stored in the scene (default: the shape's name, or ``"array"``).
    normalize : bool, default True
        Re-normalise an array ``shape`` to the unit sphere. ModelNet40's HDF5 clouds are
        already normalised by their publishers; ``normalize=False`` uses them exactly as the
        authors' generator does.

    Returns
    -------
    SyntheticScene
        Correspondences, labels, the 5 to 10 poses (in slot order) and the source.
    """
    seed = _check_seed(seed)
    _check_protocol_args(n_outlier_blocks, n_keep)
    cloud, name, rng = _cloud_and_rng(seed, shape, SHAPE_POINTS, data_dir, shape_name, normalize)
    source = cloud[:BLOCK].copy()
    # One generator for the whole scene, in this order: slots, outliers, shuffle.
    rot, trans, real, targets = _protocol_slots(rng, source, noise_sigma, noise_clip)
    corr = _shuffled(rng, _protocol_rows(rng, source, targets, n_outlier_blocks), n_keep)
    poses = _poses(rot[real], trans[real])
    labels = label_correspondences(corr, poses, label_threshold)
    return SyntheticScene(corr, labels, poses, source, name, seed)


def _check_protocol_args(n_outlier_blocks: int, n_keep: int | None) -> None:
    if n_outlier_blocks < 0:
        raise ValueError(f"n_outlier_blocks must be >= 0, got {n_outlier_blocks}")
    if n_keep is not None and n_keep < 1:
        raise ValueError(f"n_keep must be positive or None, got {n_keep}")


def _cloud_and_rng(
    seed: int,
    shape: ShapeArg,
    n_points: int,
    data_dir: str | os.PathLike[str] | None,
    shape_name: str | None,
    normalize: bool = True,
) -> tuple[np.ndarray, str, np.random.Generator]:
    """The shape's cloud and name, and the scene's generator: two independent streams
    spawned from the seed, so the scene's draws do not depend on how the shape was drawn."""
    shape_seq, scene_seq = np.random.SeedSequence(seed).spawn(2)
    cloud, name = _shape_cloud(
        shape, n_points, np.random.default_rng(shape_seq), data_dir, shape_name, normalize
    )
    return cloud, name, np.random.default_rng(scene_seq)


def _protocol_slots(
    rng: np.random.Generator, source: np.ndarray, noise_sigma: float, noise_clip: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The protocol's 10 slots: a pose for each, 5 to 10 of them real instances (noisy
    transformed sources), the others blocks of uniform outliers.

    Returns the rotations and translations of all slots, the real slots (sorted) and the
    (N_SLOTS, BLOCK, 3) target blocks.
    """
    noise = np.clip(rng.normal(0.0, noise_sigma, (N_SLOTS, BLOCK, 3)), -noise_clip, noise_clip)
    rot = _rotations_xyz(rng.uniform(0.0, 2.0 * np.pi, (N_SLOTS, 3)))
    trans = rng.uniform(0.0, TRANSLATION_RANGE, (N_SLOTS, 3))
    n_real = int(rng.integers(5, N_SLOTS + 1))
    real = np.sort(rng.choice(N_SLOTS, size=n_real, replace=False))
    dropped = np.setdiff1d(np.arange(N_SLOTS), real)
    targets = np.einsum("kij,knj->kni", rot, source[None] + noise) + trans[:, None]
    targets[dropped] = rng.uniform(0.0, OUTLIER_RANGE, (len(dropped), BLOCK, 3))
    return rot, trans, real, targets


def _protocol_rows(
    rng: np.random.Generator, source: np.ndarray, targets: np.ndarray, n_outlier_blocks: int
) -> np.ndarray:
    """Every block's rows unshuffled: the source against each slot's targets, then against
    ``n_outlier_blocks`` blocks of uniform outliers (drawn here)."""
    outliers = rng.uniform(0.0, OUTLIER_RANGE, (n_outlier_blocks, BLOCK, 3))
    return np.hstack(
        [
            np.tile(source, (N_SLOTS + n_outlier_blocks, 1)),
            np.concatenate([targets, outliers]).reshape(-1, 3),
        ]
    )


def _shuffled(rng: np.random.Generator, corr: np.ndarray, n_keep: int | None) -> np.ndarray:
    """The rows in random order (so no row's position tells its label), the first n_keep."""
    corr = corr[rng.permutation(len(corr))]
    if n_keep is not None:
        corr = corr[:n_keep]
    return np.ascontiguousarray(corr)


def make_scenes(
    n: int,
    seed: int = 0,
    shapes: Sequence[ShapeArg] | None = None,
    **kw: object,
) -> Iterator[SyntheticScene]:
    """Yield ``n`` protocol scenes with per-scene seeds derived from one seed.

    Parameters
    ----------
    n : int
        Number of scenes.
    seed : int, default 0
        Master seed; scene i gets ``SeedSequence(seed).spawn(n)[i]``'s first 64-bit word as
        its seed (stored in ``scene.seed``), so scene i does not depend on ``n``.
    shapes : sequence of str or numpy.ndarray, optional
        Shapes cycled over the scenes (default ``["bunny"]``).
    **kw
        Passed on to :func:`make_scene`.

    Yields
    ------
    SyntheticScene
    """
    seed = _check_seed(seed)
    shapes = ["bunny"] if shapes is None else list(shapes)
    if not shapes:
        raise ValueError("shapes must not be empty")
    for i, child in enumerate(np.random.SeedSequence(seed).spawn(n)):
        scene_seed = int(child.generate_state(1, dtype=np.uint64)[0])
        yield make_scene(scene_seed, shapes[i % len(shapes)], **kw)  # type: ignore[arg-type]


def make_planted_scene(
    n_correspondences: int,
    seed: int,
    n_instances: int = 5,
    inlier_fraction: float = 0.02,
    *,
    shape: ShapeArg = "bunny",
    noise_sigma: float = 0.01,
    noise_clip: float = 0.05,
    label_threshold: float = 0.05,
    data_dir: str | os.PathLike[str] | None = None,
    shape_name: str | None = None,
) -> SyntheticScene:
    """A protocol-like scene of any size, for scale tests (N = 10,000 or 50,000).

    Each of the ``n_instances`` instances gets ``round(inlier_fraction * N)`` inlier rows
    (default 2 %, the protocol's rate per instance); the other rows pair source points with
    uniform random targets. To keep the scene as hard as the 1000-row protocol, the volume grows
    with N: with ``s = (N / 1000) ** (1/3)``, translations are U[0, 5 s)^3 and random targets
    U[0, 6 s)^3, so the density of random targets (rows per unit volume), which is what decides
    how many of them look spatially consistent, stays that of the protocol. (A pair is
    consistent only if its target distance is within about 0.02 of its source distance, at most
    2 on the unit sphere; for uniform targets that probability falls as 1 / side^3, so an
    outlier keeps a median of 2 consistent partners at N = 1000 to 5000, while each instance's
    inliers grow with N.)

    The source has ``max(256, inliers per instance)`` points (the first ones of a
    unit-sphere-normalised sample of the shape with at least 2048 points); each instance uses a
    random subset of it, and outlier rows draw their source points uniformly from it.

    Parameters
    ----------
    n_correspondences : int
        N, the number of rows.
    seed : int
        Non-negative seed.
    n_instances : int, default 5
        Number of instances M.
    inlier_fraction : float, default 0.02
        Fraction of the N rows that are inliers of each instance.
    shape, noise_sigma, noise_clip, label_threshold, data_dir, shape_name
        As in :func:`make_scene`.

    Returns
    -------
    SyntheticScene
    """
    seed = _check_seed(seed)
    n, n_in = _planted_counts(n_correspondences, n_instances, inlier_fraction)
    n_source = max(BLOCK, n_in)
    n_points = max(SHAPE_POINTS, n_source)
    cloud, name, rng = _cloud_and_rng(seed, shape, n_points, data_dir, shape_name)
    source = cloud[:n_source].copy()
    rot, trans, corr = _planted_rows(rng, source, n, n_instances, n_in, noise_sigma, noise_clip)
    corr = _shuffled(rng, corr, None)
    poses = _poses(rot, trans)
    labels = label_correspondences(corr, poses, label_threshold)
    return SyntheticScene(corr, labels, poses, source, name, seed)


def _planted_counts(
    n_correspondences: int, n_instances: int, inlier_fraction: float
) -> tuple[int, int]:
    """N and the inliers per instance, checked to fit."""
    n = int(n_correspondences)
    n_in = int(round(inlier_fraction * n))
    if n < 1 or n_instances < 1 or n_in < 3:
        raise ValueError("need N >= 1, n_instances >= 1 and at least 3 inliers per instance")
    if n_instances * n_in > n:
        raise ValueError(f"{n_instances} x {n_in} inliers do not fit in {n} rows")
    return n, n_in


def _planted_rows(
    rng: np.random.Generator,
    source: np.ndarray,
    n: int,
    n_instances: int,
    n_in: int,
    noise_sigma: float,
    noise_clip: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The instances' rotations and translations, and the N rows unshuffled: each
    instance's n_in inliers, then outliers (random source point, uniform target), in a
    volume that grows with N (see :func:`make_planted_scene`)."""
    scale = (n / 1000.0) ** (1.0 / 3.0)
    rot = _rotations_xyz(rng.uniform(0.0, 2.0 * np.pi, (n_instances, 3)))
    trans = rng.uniform(0.0, TRANSLATION_RANGE * scale, (n_instances, 3))
    n_source = len(source)
    idx = np.stack([rng.choice(n_source, size=n_in, replace=False) for _ in range(n_instances)])
    x_in = source[idx]  # (M, n_in, 3)
    noise = np.clip(rng.normal(0.0, noise_sigma, x_in.shape), -noise_clip, noise_clip)
    y_in = np.einsum("kij,knj->kni", rot, x_in + noise) + trans[:, None]
    n_out = n - n_instances * n_in
    x_out = source[rng.integers(0, n_source, n_out)]
    y_out = rng.uniform(0.0, OUTLIER_RANGE * scale, (n_out, 3))
    corr = np.hstack(
        [np.concatenate([x_in.reshape(-1, 3), x_out]), np.concatenate([y_in.reshape(-1, 3), y_out])]
    )
    return rot, trans, corr

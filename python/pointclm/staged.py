"""The pipeline one stage at a time, for inspection and research (small_gicp-style staged
API). `pointclm.register` runs all of it in one call without building dense N x N matrices.

correspondences -> `spatial_consistency` / `density_counts` -> `spectral_clustering` of an
affinity -> `kabsch` per group.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from . import _core
from .config import Config
from .errors import InputError
from .registration import (
    MIN_CORRESPONDENCES,
    as_config,
    as_correspondences,
    as_features,
    as_matrix,
    as_seed,
    as_threads,
)

__all__ = [
    "density_counts",
    "eigh",
    "kabsch",
    "normalized_laplacian",
    "spatial_consistency",
    "spectral_clustering",
]


def spatial_consistency(correspondences: ArrayLike, sigma_d: float = 0.05) -> np.ndarray:
    """Dense (N, N) ``beta_ij = [1 - d_ij^2 / sigma_d^2]_+`` (memory N^2: small N only)."""
    corr, _ = as_correspondences(correspondences, None)
    try:
        sigma = float(sigma_d)
    except (TypeError, ValueError):
        raise InputError(f"sigma_d must be a positive number, got {sigma_d!r}") from None
    return _core.spatial_consistency(corr, sigma)


def density_counts(
    correspondences: ArrayLike,
    features: ArrayLike | None = None,
    config: Config | None = None,
    *,
    num_threads: int | None = None,
) -> np.ndarray:
    """Per-row count of consistent correspondences under ``config.pruning`` (itself
    included); rows above `tau_n` (or `min_count`) survive pruning."""
    corr, _ = as_correspondences(correspondences, None)
    return _core.density_counts(
        corr,
        as_features(features, len(corr)),
        as_config(config),
        num_threads=as_threads(num_threads),
    )


def normalized_laplacian(affinity: ArrayLike) -> np.ndarray:
    """``L = I - D^-1/2 A D^-1/2`` of a symmetric non-negative affinity."""
    return _core.normalized_laplacian(as_matrix(affinity, "affinity", None))


def eigh(matrix: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and eigenvectors (columns) of a symmetric matrix (faer)."""
    return _core.eigh(as_matrix(matrix, "matrix", None))


def spectral_clustering(
    affinity: ArrayLike,
    n_clusters: int | None = None,
    *,
    max_clusters: int | None = None,
    assignment: str = "kmeans",
    restarts: int = 10,
    seed: int = 0,
) -> tuple[np.ndarray, int, np.ndarray]:
    """Labels, cluster count (eigengap when `n_clusters` is None) and the normalised
    Laplacian's eigenvalues, ascending, as the pipeline's clustering computes them: all of
    them below 64 rows; from there the Ritz values of a partial solver, of which those up to
    the eigengap are right to about 1e-2 and the rest upper bounds of the eigenvalues of
    their rank (all of them, in f32, where the partial solver hands the work back from 400
    rows; ``eigh(normalized_laplacian(affinity))`` gives the exact spectrum)."""
    if not isinstance(assignment, str):
        raise InputError(f"assignment must be 'kmeans' or 'discretize', got {assignment!r}")
    return _core.spectral_clustering(
        as_matrix(affinity, "affinity", None),
        None if n_clusters is None else _as_count(n_clusters, "n_clusters"),
        None if max_clusters is None else _as_count(max_clusters, "max_clusters"),
        assignment,
        _as_count(restarts, "restarts"),
        as_seed(seed),
    )


def _as_count(value: int, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise InputError(f"{name} must be an int >= 1, got {value!r}")
    if value >= 2**63:  # would overflow the core's usize
        raise InputError(f"{name} is too large: {value}")
    return int(value)


def kabsch(source: ArrayLike, target: ArrayLike) -> np.ndarray:
    """Least-squares ``T_target_source`` (4x4) mapping `source` rows onto `target` rows."""
    src = as_matrix(source, "source", 3)
    dst = as_matrix(target, "target", 3)
    if len(src) != len(dst):
        raise InputError(
            f"source and target must have the same length, got {len(src)} and {len(dst)}"
        )
    if len(src) < MIN_CORRESPONDENCES:
        raise InputError(f"need at least {MIN_CORRESPONDENCES} point pairs, got {len(src)}")
    return _core.kabsch(src, dst)

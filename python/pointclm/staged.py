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
from .registration import as_config, as_correspondences, as_features, as_matrix

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
    return _core.spatial_consistency(corr, float(sigma_d))


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
        corr, as_features(features, len(corr)), as_config(config), num_threads=num_threads
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
    """Labels, cluster count (eigengap when `n_clusters` is None) and Laplacian spectrum."""
    return _core.spectral_clustering(
        as_matrix(affinity, "affinity", None),
        n_clusters,
        max_clusters,
        assignment,
        restarts,
        seed,
    )


def kabsch(source: ArrayLike, target: ArrayLike) -> np.ndarray:
    """Least-squares ``T_target_source`` (4x4) mapping `source` rows onto `target` rows."""
    corr, _ = as_correspondences(source, target)
    return _core.kabsch(np.ascontiguousarray(corr[:, :3]), np.ascontiguousarray(corr[:, 3:]))

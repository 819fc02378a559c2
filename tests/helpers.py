"""Assertions and inputs shared by the test modules (tests/ is on sys.path under pytest)."""

from __future__ import annotations

import numpy as np
from pointclm import RegistrationResult
from pointclm.datasets import make_scene


def assert_same_result(a: RegistrationResult, b: RegistrationResult) -> None:
    """Bit-identical results (same poses, labels, kept set, instance metadata)."""
    assert len(a) == len(b)
    np.testing.assert_array_equal(a.transformations, b.transformations)
    np.testing.assert_array_equal(a.labels, b.labels)
    np.testing.assert_array_equal(a.kept, b.kept)
    assert a.n_clusters == b.n_clusters
    for ia, ib in zip(a.instances, b.instances, strict=True):
        np.testing.assert_array_equal(ia.inliers, ib.inliers)
        assert ia.fitness == ib.fitness
        assert ia.inlier_rmse == ib.inlier_rmse


def scene_with_inputs(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A synthetic scene's (N, 6) correspondences, (N, 6) unit normals (random at the source,
    carried by the true pose to the target for inliers, every third flipped; random for
    outliers) and (N,) similarities in [0.05, 1)."""
    scene = make_scene(seed)
    rng = np.random.default_rng(seed)
    n = len(scene.correspondences)
    ns, nt = rng.normal(size=(2, n, 3))
    for i, k in enumerate(scene.labels):
        if k >= 0:
            nt[i] = scene.poses[k][:3, :3] @ ns[i] * (-1 if i % 3 == 0 else 1)
    normals = np.hstack([ns, nt])
    normals /= np.linalg.norm(normals.reshape(n, 2, 3), axis=2).repeat(3, axis=1)
    return scene.correspondences, normals, rng.uniform(0.05, 1.0, size=n)

"""Assertions shared by the test modules (tests/ is on sys.path under pytest)."""

from __future__ import annotations

import numpy as np
from pointclm import RegistrationResult


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

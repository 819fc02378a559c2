"""Assertions and inputs shared by the test modules (tests/ is on sys.path under pytest)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from pointclm import RegistrationResult
from pointclm.datasets import make_scene
from pointclm.datasets.scenes import default_data_dir

#: The real data some tests read (Stanford scans and models, PCL and 3DMatch clouds, ModelNet
#: and common3d meshes: public files, too large or under terms that keep them out of the
#: repository): ``$POINTCLM_DATA_DIR``, else ``../shared/data`` beside the clone.
DATA = Path(
    os.environ.get("POINTCLM_DATA_DIR") or Path(__file__).resolve().parents[2] / "shared" / "data"
)
#: Why a test that needs the data folder is skipped, and how to get it.
DATA_HINT = (
    f"needs the real data folder, not found at {DATA}: put it at ../shared/data beside the "
    "clone or set POINTCLM_DATA_DIR; tests/DATA_SOURCES.md lists its files and where to "
    "download each"
)
#: Skips a test that reads files of the data folder.
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=DATA_HINT)
#: Skips a test whose realistic scenes need the data folder (`make_realistic_scene` with its
#: default model, the Stanford bunny and its real range scans, or another model stored there;
#: the packaged model="bunny" with procedural clutter needs nothing).
needs_scene_data = pytest.mark.skipif(default_data_dir() is None, reason=DATA_HINT)


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


def box_surface(size: tuple[float, float, float], step: float = 0.004) -> np.ndarray:
    """The surface of a box of `size` centred at the origin, on a grid of `step`."""
    faces = []
    for axis in range(3):
        u, v = (a for a in range(3) if a != axis)
        gu = np.arange(-size[u] / 2, size[u] / 2 + 1e-9, step)
        gv = np.arange(-size[v] / 2, size[v] / 2 + 1e-9, step)
        a, b = np.meshgrid(gu, gv)
        for sign in (-1.0, 1.0):
            face = np.zeros((a.size, 3))
            face[:, u], face[:, v], face[:, axis] = a.ravel(), b.ravel(), sign * size[axis] / 2
            faces.append(face)
    return np.unique(np.vstack(faces).round(9), axis=0)

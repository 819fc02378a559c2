"""The numpy/scikit-learn reference pipeline solves the synthetic protocol."""

from __future__ import annotations

import numpy as np
import pytest
from pointclm.datasets import make_scenes
from pointclm.metrics import score_scene, summarize

pytest.importorskip("scipy")
pytest.importorskip("sklearn")

from benchmarks.correspondences import reference_numpy as ref  # noqa: E402


def test_kabsch_recovers_pose() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(20, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    y = x @ q.T + [1.0, -2.0, 0.5]
    pose = ref.kabsch(x, y)
    np.testing.assert_allclose(pose[:3, :3], q, atol=1e-10)
    np.testing.assert_allclose(pose[:3, 3], [1.0, -2.0, 0.5], atol=1e-10)
    # a reflection in the data still gives a proper rotation
    assert np.linalg.det(ref.kabsch(x, x * [1, 1, -1])[:3, :3]) == pytest.approx(1.0)


def test_reference_on_synthetic_protocol() -> None:
    scores = []
    for scene in make_scenes(5, seed=2024):
        poses = ref.register_reference(scene.correspondences)
        for p in poses:
            assert p.shape == (4, 4)
        scores.append(score_scene(poses, scene.poses))
    summary = summarize(scores)
    assert summary.strict_f1 >= 0.85, str(summary)


def test_reference_handles_pure_outliers() -> None:
    rng = np.random.default_rng(1)
    corr = np.hstack([rng.random((300, 3)), 6 * rng.random((300, 3))])
    assert ref.register_reference(corr) == []

"""Accuracy on 50 seeded scenes of the paper's synthetic protocol (SPEC section 3)."""

from __future__ import annotations

import numpy as np
import pointclm
import pytest
from pointclm.datasets import make_scenes
from pointclm.metrics import (
    max_bipartite_matching,
    pose_match_matrix,
    rotation_error_deg,
    score_scene,
    summarize,
)

N_SCENES = 50


@pytest.fixture(scope="module")
def runs() -> list[tuple[np.ndarray, np.ndarray]]:
    """(predicted poses, GT poses) per scene, default config."""
    scenes = list(make_scenes(N_SCENES, seed=2024))
    results = pointclm.register_batch(scenes)
    return [(r.transformations, s.poses) for r, s in zip(results, scenes, strict=True)]


def test_paper_and_strict_f1(runs) -> None:
    summary = summarize(score_scene(pred, gt) for pred, gt in runs)
    assert summary.n_scenes == N_SCENES
    assert summary.mean_f1 >= 0.95, str(summary)  # paper: MF 96.01
    assert summary.strict_f1 >= 0.94, str(summary)


def test_rotation_error_of_matched_instances(runs) -> None:
    errors = []
    for pred, gt in runs:
        # one-to-one pairs of the strict matching (RE < 15 deg and TE < 0.1)
        pair = max_bipartite_matching(pose_match_matrix(pred, gt))
        for i in np.flatnonzero(pair >= 0):
            errors.append(float(rotation_error_deg(pred[i, :3, :3], gt[pair[i], :3, :3])))
    errors = np.asarray(errors)
    n_gt = sum(len(gt) for _, gt in runs)
    assert len(errors) >= 0.9 * n_gt
    assert errors.mean() < 3.0, f"mean rotation error {errors.mean():.2f} deg"

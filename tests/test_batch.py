"""`register_batch` equals serial `register`, whatever the thread count and the scene form."""

from __future__ import annotations

import numpy as np
import pointclm
import pytest
from helpers import assert_same_result
from pointclm import RegistrationResult
from pointclm.datasets import SyntheticScene, make_scenes


@pytest.fixture(scope="module")
def scenes() -> list[SyntheticScene]:
    return list(make_scenes(12, seed=11))


@pytest.fixture(scope="module")
def serial(scenes: list[SyntheticScene]) -> list[RegistrationResult]:
    return [pointclm.register(s.correspondences, seed=5) for s in scenes]


@pytest.mark.parametrize("num_threads", [1, 2, None])
def test_batch_equals_serial(
    scenes: list[SyntheticScene], serial: list[RegistrationResult], num_threads: int | None
) -> None:
    batch = pointclm.register_batch(scenes, seed=5, num_threads=num_threads)
    assert isinstance(batch, list) and len(batch) == len(scenes)
    assert sum(len(r) for r in batch) > 3 * len(scenes)  # real work was done
    for b, s in zip(batch, serial, strict=True):
        assert_same_result(b, s)


def test_batch_order_is_kept(scenes: list[SyntheticScene], serial) -> None:
    rev = pointclm.register_batch(scenes[::-1], seed=5, num_threads=2)
    for b, s in zip(rev, serial[::-1], strict=True):
        assert_same_result(b, s)


def test_batch_seed_and_config_apply_to_every_scene(scenes: list[SyntheticScene]) -> None:
    cfg = {"ransac_iterations": 5, "assignment": "discretize"}
    batch = pointclm.register_batch(scenes[:4], config=cfg, seed=9, num_threads=2)
    for b, s in zip(batch, scenes[:4], strict=True):
        assert_same_result(b, pointclm.register(s.correspondences, config=cfg, seed=9))


def test_batch_accepts_the_four_scene_forms(scenes: list[SyntheticScene]) -> None:
    s = scenes[0]
    corr = np.array(s.correspondences)
    # near-orthogonal random features: S = S^F * beta prunes everything, so a result with
    # features is told apart from one without
    feats = np.random.default_rng(0).normal(size=(len(corr), 64))
    feats /= np.linalg.norm(feats, axis=1, keepdims=True)

    class WithFeatures:
        correspondences = corr
        features = feats

    forms = [
        corr,  # (N, 6) array
        (corr, feats),  # (correspondences, features)
        (corr[:, :3], corr[:, 3:]),  # (source, target)
        s,  # object with .correspondences
        WithFeatures(),  # ... and .features
        (corr, None),  # features left out
        corr.tolist(),  # nested lists
    ]
    plain = pointclm.register(corr)
    with_feats = pointclm.register(corr, feats)
    expected = [plain, with_feats, plain, plain, with_feats, plain, plain]
    batch = pointclm.register_batch(forms, num_threads=2)
    for b, e in zip(batch, expected, strict=True):
        assert_same_result(b, e)
    assert len(plain) > 0 and len(with_feats) == 0  # the features did reach the core


def test_batch_accepts_any_iterable(scenes: list[SyntheticScene], serial) -> None:
    gen = (s.correspondences for s in scenes[:3])
    for b, s in zip(pointclm.register_batch(gen, seed=5), serial[:3], strict=True):
        assert_same_result(b, s)


def test_empty_batch() -> None:
    assert pointclm.register_batch([]) == []
    assert pointclm.register_batch([], num_threads=2) == []
    assert pointclm.register_batch(iter(())) == []

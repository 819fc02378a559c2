"""Several part types in one scan: each model's copies judged together, so that a copy of one
model does not claim what a copy of another explains."""

from __future__ import annotations

import numpy as np
import pointclm
import pytest
from pointclm.datasets.sensed import SensedSceneParams, make_sensed_scene
from pointclm.metrics import pose_match_matrix


@pytest.fixture(scope="module")
def mixed_bin():  # type: ignore[no-untyped-def]
    """A pile of two box products in a bin, seen from 0.6 m."""
    params = SensedSceneParams(parts=("box_95x36x68", "box_232x44x52"), copies=(3, 4))
    scene = make_sensed_scene(1, params)
    found = pointclm.register_models(scene.models, scene.scan, heap=True)
    alone = [pointclm.register_point_clouds(m, scene.scan, heap=True) for m in scene.models]
    return scene, found, alone


def _on_other_product(scene, product: int, poses: np.ndarray) -> int:  # type: ignore[no-untyped-def]
    """How many of `poses` (of `product`) lie on a copy of another product: within 10 % of
    their own diagonal of where that copy's centroid is."""
    centre = scene.models[product].mean(0)
    at = poses[:, :3, :3] @ centre + poses[:, :3, 3]
    others = scene.product != product
    if not others.any():
        return 0
    theirs = np.array(
        [pose[:3, :3] @ scene.models[p].mean(0) + pose[:3, 3]
         for pose, p in zip(scene.poses[others], scene.product[others], strict=True)]
    )  # fmt: skip
    near = np.linalg.norm(at[:, None] - theirs[None], axis=2) < 0.5 * scene.diameters[product]
    return int(near.any(axis=1).sum())


def _right(scene, product: int, reg) -> int:  # type: ignore[no-untyped-def]
    """How many of `reg`'s copies are right (15 degrees, 10 % of the diagonal)."""
    if not reg.instances:
        return 0
    truth = scene.poses[scene.product == product]
    tol = 0.1 * scene.diameters[product]
    sym = scene.symmetries[product]
    ok = pose_match_matrix(reg.transformations, truth, 15, tol, symmetries=sym)
    return int(ok.any(axis=1).sum())


def test_one_result_per_model_and_only_fewer_copies_than_alone(mixed_bin) -> None:
    scene, found, alone = mixed_bin
    assert len(found) == len(scene.models)
    for joint, single in zip(found, alone, strict=True):
        kept = {tuple(np.round(c.transformation, 9).ravel()) for c in joint.instances}
        every = {tuple(np.round(c.transformation, 9).ravel()) for c in single.instances}
        assert kept <= every  # judged together, never added to
    # The right copies of each product stay.
    for p, (joint, single) in enumerate(zip(found, alone, strict=True)):
        assert _right(scene, p, joint) == _right(scene, p, single)
    # And none of the joint result lies on the other product's copies more than alone.
    for p, (joint, single) in enumerate(zip(found, alone, strict=True)):
        if joint.instances:
            assert _on_other_product(scene, p, joint.transformations) <= _on_other_product(
                scene, p, single.transformations
            )


def test_bad_model_lists_are_value_errors() -> None:
    pts = np.random.default_rng(0).random((50, 3))
    with pytest.raises(ValueError, match="non-empty list"):
        pointclm.register_models([], pts)
    with pytest.raises(ValueError, match="non-empty list"):
        pointclm.register_models(pts, pts)
    with pytest.raises(ValueError, match="symmetries"):
        pointclm.register_models([pts, pts], pts, symmetry=[None])

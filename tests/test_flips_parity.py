"""The core's resolve_flips against the Python implementation it replaces
(tests/_flips_reference.py), on the inputs the scene pipeline gives it: the same poses to
rounding and the same order."""

from __future__ import annotations

from typing import Any

import _flips_reference as reference
import numpy as np
import pointclm
import pytest
from helpers import needs_scene_data
from pointclm.clouds import ranking
from pointclm.datasets.bins import BinParams, make_bin_scene
from pointclm.datasets.scenes import HELDOUT_MODELS, SceneParams, make_realistic_scene

FIELDS = [f for f in pointclm.refinement.RefinedPoses._fields if f != "by_visibility"]


def _recorded(model: np.ndarray, scan: np.ndarray, **kwargs: Any) -> list[tuple[Any, ...]]:
    """Every resolve_flips call the pipeline makes on the scene, with the core's answer."""
    calls = []
    core = ranking.resolve_flips

    def record(*args: Any, **kw: Any) -> Any:
        out = core(*args, **kw)
        calls.append((args, kw, out))
        return out

    mp = pytest.MonkeyPatch()
    mp.setattr(ranking, "resolve_flips", record)
    try:
        pointclm.register_point_clouds(model, scan, flips=True, num_threads=2, **kwargs)
    finally:
        mp.undo()
    return calls


def _scenes() -> list[tuple[str, np.ndarray, np.ndarray, dict[str, Any]]]:
    out = []
    for model in ("box", "common3d/fandisk", "stanford/dragon"):
        sc = make_bin_scene(0, BinParams(model=model, copies=(20, 30)))
        out.append((f"bin {model}", sc.model_points, sc.scan, {"viewpoint": sc.sensor}))
    for model in HELDOUT_MODELS:
        for seed in range(2):
            sc = make_realistic_scene(seed, SceneParams(model=model))
            view = {"viewpoint": sc.viewpoint} if seed == 0 else {}
            out.append((f"{model} {seed}", sc.source_points, sc.target_points, view))
    return out


@needs_scene_data
def test_the_core_resolves_flips_as_the_python_implementation_did() -> None:
    worst, turned, by_visibility = 0.0, 0, set()
    for name, model, scan, kwargs in _scenes():
        for args, kw, (got, order) in _recorded(model, scan, **kwargs):
            want, want_order = reference.resolve_flips(*args, **kw)
            np.testing.assert_array_equal(order, want_order, err_msg=name)
            for f in FIELDS:
                a, b = getattr(got, f), getattr(want, f)
                np.testing.assert_allclose(a, b, rtol=0, atol=1e-12, err_msg=f"{name} {f}")
                worst = max(worst, float(np.nanmax(np.abs(a - b), initial=0.0)))
            poses = args[2]
            turned += int(
                (np.abs(got.transformations - poses.transformations[order]) > 0)
                .any(axis=(1, 2))
                .sum()
            )
            by_visibility.add(poses.by_visibility)
    print(f"largest difference {worst:.1e}; {turned} poses turned")
    assert turned > 0 and by_visibility == {True, False}


def test_the_core_resolves_synthetic_turns_as_the_python_implementation_did() -> None:
    from pointclm.datasets import load_shape
    from pointclm.point_clouds import default_voxel_size
    from test_refinement import _apply, _pose, _slab_with_a_block

    box = load_shape("box", 4000, rng=0)
    voxel = default_voxel_size(box)
    box = pointclm.preprocessing.voxel_downsample(box, voxel)
    slab = _slab_with_a_block()
    truth = _pose([0.3, 1.0, 0.2], 40.0, [0.5, -0.2, 0.1])
    cases = []
    for src, vox in ((box, voxel), (slab, 0.04)):
        scan = _apply(truth, src)
        turns = np.concatenate([reference.flip_turns(src, vox), reference.quarter_turns(src, vox)])
        starts = np.concatenate([truth[None], truth @ turns])
        cases.append((src, scan, vox, starts, None))
        cases.append((src, scan, vox, starts[1:], turns[:2, :3, :3].transpose(0, 2, 1)))
        top = scan[_apply(np.linalg.inv(truth), scan)[:, 2] < 0.25]
        cases.append((src, top, vox, starts[:2], None))
    changed = 0
    for src, scan, vox, starts, rotations in cases:
        np.testing.assert_allclose(
            pointclm.refinement.flip_turns(src, vox), reference.flip_turns(src, vox), atol=1e-14
        )
        np.testing.assert_allclose(
            pointclm.refinement.quarter_turns(src, vox),
            reference.quarter_turns(src, vox),
            atol=1e-14,
        )
        keep = {"max_shared": 1.0, "min_fitness": 0.0, "min_relative_fitness": 0.0}
        poses = pointclm.refine_poses(src, scan, starts, vox, **keep)
        got, order = pointclm.refinement.resolve_flips(src, scan, poses, vox, rotations=rotations)
        want, want_order = reference.resolve_flips(src, scan, poses, vox, rotations=rotations)
        np.testing.assert_array_equal(order, want_order)
        for f in FIELDS:
            np.testing.assert_allclose(getattr(got, f), getattr(want, f), rtol=0, atol=1e-12)
        changed += int((got.confidence != poses.confidence[order]).sum())
    assert changed > 0

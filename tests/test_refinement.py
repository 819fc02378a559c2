"""ICP refinement and verification on the clouds (`pointclm.refine_poses`), and its place in
`register_point_clouds`."""

from __future__ import annotations

import warnings

import numpy as np
import pointclm
import pytest
from helpers import needs_scene_data
from pointclm.datasets.procedural import PROCEDURAL_SHAPES
from pointclm.datasets.scenes import SceneParams, make_realistic_scene
from pointclm.metrics import rotation_error_deg, score_scene


def _rot(axis: list[float], deg: float) -> np.ndarray:
    a = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    t = np.radians(deg)
    return np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * k @ k


def _pose(axis: list[float], deg: float, t: list[float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = _rot(axis, deg), t
    return T


def _blob(n: int = 1500, seed: int = 0) -> np.ndarray:
    """A bumpy, asymmetric closed surface."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = 1 + 0.25 * np.sin(3 * d[:, 0]) * np.cos(2 * d[:, 1]) + 0.15 * d[:, 2] ** 2
    return d * r[:, None] * [1.0, 1.4, 0.8]


def _apply(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ T[:3, :3].T + T[:3, 3]


def test_icp_corrects_a_rough_pose_and_verification_drops_a_false_one() -> None:
    model = _blob()
    truth = _pose([0.2, 1, 0.4], 35, [4.0, 1.0, -2.0])
    scene = np.vstack([_apply(truth, model), np.random.default_rng(1).uniform(-8, 8, (300, 3))])
    rough = truth @ _pose([1, 0, 0], 4, [0.1, -0.05, 0.08])
    false = _pose([0, 0, 1], 90, [-5.0, -5.0, 5.0])
    before = model.copy()
    out = pointclm.refine_poses(model, scene, np.stack([false, rough]), voxel_size=0.1)
    np.testing.assert_array_equal(model, before)  # inputs untouched
    assert out.origin.tolist() == [1]
    T = out.transformations[0]
    assert (
        rotation_error_deg(T[:3, :3], truth[:3, :3]) < 0.5
        and np.linalg.norm(T[:3, 3] - truth[:3, 3]) < 0.02
    )
    assert out.fitness[0] > 0.95 and out.inlier_rmse[0] < 0.05


def test_without_icp_poses_are_kept_as_given_and_only_scored() -> None:
    model = _blob(500)
    truth = _pose([0, 1, 0], 20, [1.0, 0.0, 0.0])
    scene = _apply(truth, model)
    off = truth @ _pose([0, 0, 1], 0, [0.3, 0.0, 0.0])
    out = pointclm.refine_poses(
        model,
        scene,
        [off, truth],
        0.1,
        icp=False,
        min_fitness=0,
        min_relative_fitness=0,
        max_shared=1.0,
    )
    assert out.origin.tolist() == [1, 0]  # best fitness first
    # Kept as given, up to the rounding of re-orthonormalisation.
    np.testing.assert_allclose(out.transformations[0], truth, atol=1e-12)
    np.testing.assert_allclose(out.transformations[1], off, atol=1e-12)
    assert out.fitness[0] == 1.0 > out.fitness[1]


def test_same_result_whatever_the_threads() -> None:
    model = _blob(800)
    truth = _pose([1, 1, 0], 50, [0.0, 2.0, 0.0])
    scene = _apply(truth, model)
    starts = np.stack([truth @ _pose([0, 1, 0], k, [0.02 * k, 0, 0]) for k in range(6)])
    a = pointclm.refine_poses(model, scene, starts, 0.1, num_threads=1)
    b = pointclm.refine_poses(model, scene, starts, 0.1, num_threads=2)
    assert a.sliding is not None and b.sliding is not None
    for x, y in zip([*a[:-1], *a.sliding[:-1]], [*b[:-1], *b.sliding[:-1]], strict=True):
        np.testing.assert_array_equal(x, y)


def test_no_poses_is_a_valid_empty_result() -> None:
    model = _blob(100)
    out = pointclm.refine_poses(model, model, np.zeros((0, 4, 4)), 0.1)
    assert out.transformations.shape == (0, 4, 4) and len(out.fitness) == 0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"transformations": np.eye(3)[None]}, r"shape \(K, 4, 4\)"),
        ({"transformations": 2 * np.eye(4)[None]}, "not a rigid motion"),
        ({"transformations": np.diag([1.0, 1.0, -1.0, 1.0])[None]}, "not a rigid motion"),
        ({"viewpoint": [0.0, 1.0]}, "viewpoint"),
        ({"max_contradiction": 2.0}, r"\[0, 1\]"),
        ({"transformations": np.full((1, 4, 4), np.nan)}, "non-finite"),
        ({"voxel_size": 0.0}, "positive"),
        ({"voxel_size": float("nan")}, "positive"),
        ({"min_fitness": 1.5}, r"\[0, 1\]"),
        ({"min_relative_fitness": -0.1}, r"\[0, 1\]"),
        ({"source_points": np.zeros((0, 3))}, "empty"),
        ({"source_points": np.zeros((5, 2))}, r"\(N, 3\)"),
        ({"target_points": [[0.0, 0.0, np.inf]] * 5}, "non-finite|NaN|inf"),
    ],
)
def test_bad_inputs_are_value_errors(kwargs: dict, match: str) -> None:
    args = {
        "source_points": _blob(50),
        "target_points": _blob(50),
        "transformations": np.eye(4)[None],
        "voxel_size": 0.1,
    }
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        pointclm.refine_poses(**args)


#: The packaged coarse bunny among procedural clutter: a realistic scene that needs no data
#: folder, the same whether or not one is present (by default the clutter is drawn from the
#: data folder's models when there is one).
BUNNY_ONLY = SceneParams(model="bunny", data_dir=None, clutter_models=PROCEDURAL_SHAPES)


def test_register_point_clouds_refines_by_default() -> None:
    # Packaged coarse bunny, 7 copies, no sensor position: FPFH poses get 4 of them within
    # 15 deg / 10 %; point-to-plane ICP and verification find all 7.
    scene = make_realistic_scene(0, BUNNY_ONLY)
    kw = {"voxel_size": scene.voxel_size}
    ref = pointclm.register_point_clouds(scene.source_points, scene.target_points, **kw)
    raw = pointclm.register_point_clouds(
        scene.source_points, scene.target_points, refine=False, **kw
    )
    assert "refinement" in ref.timings
    assert all(isinstance(i, pointclm.CloudInstance) for i in ref.instances)
    sure = [i.confidence for i in ref.instances]
    assert sure == sorted(sure, reverse=True)
    good = score_scene(ref.transformations, scene.poses, 15.0, scene.max_translation)
    base = score_scene(raw.transformations, scene.poses, 15.0, scene.max_translation)
    assert good.n_matched >= 5 and good.precision >= 0.85
    assert base.n_matched <= good.n_matched


def test_without_refinement_the_poses_are_the_correspondence_stage_s() -> None:
    scene = make_realistic_scene(0, BUNNY_ONLY)
    raw = pointclm.register_point_clouds(
        scene.source_points, scene.target_points, scene.voxel_size, refine=False
    )
    # Without refinement: the correspondence stage's poses, in its order.
    np.testing.assert_allclose(raw.transformations, raw.result.transformations, atol=1e-12)


def test_near_rotations_are_orthonormalised() -> None:
    model = _blob(400)
    truth = _pose([0.3, 1, 0.2], 40, [1.0, 0.0, 0.0])
    rounded = np.round(truth, 6)  # as written to a text file
    rounded[:3, :3] += 3e-5
    out = pointclm.refine_poses(model, _apply(truth, model), rounded[None], 0.1, icp=False)
    R = out.transformations[0][:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert rotation_error_deg(R, truth[:3, :3]) < 0.01


@needs_scene_data
def test_a_mostly_hidden_copy_is_kept_with_the_viewpoint() -> None:
    # Validation model (dragon): every true pose of a single-sensor scene, judged by what the
    # sensor could see of it, is kept; judged against the best copy's share, not all are.
    scene = make_realistic_scene(1, SceneParams(model="stanford/dragon"))
    if scene.viewpoint is None:
        pytest.skip("scene without a sensor position")
    kw = {"voxel_size": scene.voxel_size, "max_shared": 1.0}
    seen = pointclm.refine_poses(
        scene.source_points, scene.target_points, scene.poses, viewpoint=scene.viewpoint, **kw
    )
    blind = pointclm.refine_poses(scene.source_points, scene.target_points, scene.poses, **kw)
    assert seen.by_visibility and not blind.by_visibility
    assert len(seen.origin) == scene.n_instances > len(blind.origin)
    assert np.all(np.diff(seen.confidence) <= 0) and np.all(seen.confidence <= 1)
    assert np.all(seen.contradiction < 0.05)


@needs_scene_data
def test_a_copy_that_sits_loosely_on_the_scan_stands_out_against_the_others() -> None:
    # Validation model (dragon): the true poses' visible sides lie on the scan alike (within
    # 1.1 times their median); one of them moved by 1.5 voxels, the inlier distance, still
    # passes every rule that judges a pose alone, and lies 1.7 times looser than the median.
    from pointclm.refinement import MAX_RELATIVE_VISIBLE_RMSE, loose_poses

    scene = make_realistic_scene(1, SceneParams(model="stanford/dragon"))
    if scene.viewpoint is None or scene.n_instances < 3:
        pytest.skip("scene without a sensor position or with fewer than three copies")
    shaken = scene.poses[0].copy()
    shaken[:3, 3] += [1.5 * scene.voxel_size, 0.0, 0.0]
    poses = np.concatenate([scene.poses, shaken[None]])
    kw = {"voxel_size": scene.voxel_size, "max_shared": 1.0, "icp": False}
    out = pointclm.refine_poses(
        scene.source_points, scene.target_points, poses, viewpoint=scene.viewpoint, **kw
    )
    assert out.by_visibility and len(out.origin) == len(poses)
    rmse = out.visible_rmse[np.argsort(out.origin)]
    assert np.isfinite(rmse).all() and (rmse < 1.5 * scene.voxel_size).all()
    truth = rmse[:-1]
    assert truth.max() <= MAX_RELATIVE_VISIBLE_RMSE * np.median(truth)
    assert loose_poses(rmse).tolist() == [False] * len(truth) + [True]
    blind = pointclm.refine_poses(scene.source_points, scene.target_points, poses, **kw)
    assert np.isnan(blind.visible_rmse).all() and not loose_poses(blind.visible_rmse).any()


def test_loose_poses_compares_with_the_median_of_known_values() -> None:
    from pointclm.refinement import loose_poses

    rmse = np.array([1.0, np.nan, 1.0, 0.9, 1.25, 1.4])  # median 1.0
    before = rmse.copy()
    assert loose_poses(rmse).tolist() == [False, False, False, False, False, True]
    np.testing.assert_array_equal(rmse, before)  # the input is not modified
    assert loose_poses(rmse, 1.2).tolist() == [False, False, False, False, True, True]
    # Fewer than three known values: nothing to compare with.
    assert not loose_poses([1.0, 5.0]).any()
    assert not loose_poses([1.0, np.nan, 5.0]).any()
    assert loose_poses([]).shape == (0,)


def test_fit_tightness_ranks_loose_poses_below_the_median_and_leaves_the_rest() -> None:
    from pointclm.refinement import fit_tightness

    rmse = np.array([1.0, np.nan, 1.0, 0.8, 1.25, 2.0])  # median of the known values 1.0
    before = rmse.copy()
    np.testing.assert_allclose(fit_tightness(rmse), [1.0, 1.0, 1.0, 1.0, 0.8, 0.5])
    np.testing.assert_array_equal(rmse, before)  # the input is not modified
    # Fewer than three known values, or none: nothing to compare with, nobody is less sure.
    np.testing.assert_array_equal(fit_tightness([1.0, np.nan, 5.0]), [1.0, 1.0, 1.0])
    assert fit_tightness([]).shape == (0,)
    # A scan whose median copy fits exactly: the others are as unsure as can be, no warning.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(fit_tightness([0.0, 0.0, 0.0, 1.0]), [1.0, 1.0, 1.0, 0.0])
        np.testing.assert_array_equal(fit_tightness([0.0, 1.0, 1.0, 1.0]), [1.0, 1.0, 1.0, 1.0])


@needs_scene_data
def test_register_point_clouds_makes_loose_and_loosely_pinned_copies_less_sure() -> None:
    # Validation model (dragon), judged from the sensor, no turned alternatives: each copy's
    # confidence is its visible fitness, less what contradicts it, times its fit's tightness
    # and how firmly the scan pins it, both against the scene's median copy; the instances
    # come surest first by that.
    from pointclm import preprocessing as pp
    from pointclm.refinement import fit_tightness, pose_stability, stability_factor
    from scipy.spatial import cKDTree

    # (Seed 1 holds one right copy and three wrong poses, which the normal-agreement rule
    # rejects; seed 2's seven copies are all found.)
    scene = make_realistic_scene(2, SceneParams(model="stanford/dragon"))
    if scene.viewpoint is None:
        pytest.skip("scene without a sensor position")
    reg = pointclm.register_point_clouds(
        scene.source_points,
        scene.target_points,
        voxel_size=scene.voxel_size,
        viewpoint=scene.viewpoint,
        flips=False,
    )
    inst = reg.instances
    assert len(inst) >= 3
    vrmse = np.array([i.visible_rmse for i in inst])
    assert np.isfinite(vrmse).all()
    tight = fit_tightness(vrmse)
    src = scene.source_points
    model = pp.describe(src, scene.voxel_size, away_from=src.mean(0))
    np.testing.assert_array_equal(model.points, reg.source_points)
    poses = np.array([i.transformation for i in inst])
    stable = stability_factor(
        pose_stability(
            model.points,
            model.normals,
            cKDTree(reg.target_points),
            poses,
            1.5 * scene.voxel_size,
        )
    )
    # Both rules are exercised: some copy fits looser, some is pinned less, than the median.
    assert tight.min() < 1.0 and stable.min() < 1.0
    plain = np.array([i.visible_fitness * (1.0 - i.contradiction) for i in inst])
    np.testing.assert_allclose([i.confidence for i in inst], plain * tight * stable, rtol=1e-12)
    sure = [i.confidence for i in inst]
    assert sure == sorted(sure, reverse=True)


def test_stability_is_low_for_a_pose_that_only_a_plane_explains() -> None:
    # Three faces of a cube (its top and two sides, the sides' rows stopping a step below the
    # top edge). Posed flush in a large flat scan, only its top is explained: sliding and
    # spinning in that plane are free, so the smallest eigenvalue is zero. In a scan of the
    # three faces it is pinned in every direction.
    from pointclm.refinement import pose_stability, stability_factor
    from scipy.spatial import cKDTree

    g = np.linspace(-0.5, 0.5, 21)
    u, v = np.meshgrid(g, g)
    top = np.column_stack([u.ravel(), v.ravel(), np.full(u.size, 0.5)])
    a, z = np.meshgrid(g, g[:-1])  # z from -0.5 to 0.45
    side_y = np.column_stack([a.ravel(), np.full(a.size, 0.5), z.ravel()])
    side_x = np.column_stack([np.full(a.size, 0.5), a.ravel(), z.ravel()])
    cube = np.concatenate([top, side_y, side_x])
    normals = np.repeat(np.eye(3)[[2, 1, 0]], [len(top), len(side_y), len(side_x)], axis=0)
    gg = np.linspace(-3.0, 3.0, 121)
    uu, vv = np.meshgrid(gg, gg)
    floor = np.column_stack([uu.ravel(), vv.ravel(), np.full(uu.size, 0.5)])
    eye = np.eye(4)[None]
    before = cube.copy()
    flat = pose_stability(cube, normals, cKDTree(floor), eye, 0.03)
    corner = pose_stability(cube, normals, cKDTree(cube), eye, 0.03)
    np.testing.assert_array_equal(cube, before)
    assert flat[0] < 1e-12 and 0.05 < corner[0] <= 1.0
    # Turned a quarter about the vertical, the pose is as firm: no axis is preferred.
    turn = np.eye(4)
    turn[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    turned_scan = cKDTree(cube @ turn[:3, :3].T)
    np.testing.assert_allclose(
        pose_stability(cube, normals, turned_scan, turn[None], 0.03), corner, rtol=1e-9
    )
    # Nothing explained: 0; as a factor against firmer copies it ranks last.
    assert pose_stability(cube, normals, cKDTree(floor + 10.0), eye, 0.03).tolist() == [0.0]
    np.testing.assert_allclose(stability_factor([0.2, 0.2, 0.1, 0.4]), [1.0, 1.0, 0.5, 1.0])
    np.testing.assert_array_equal(stability_factor([0.1, np.nan, 0.4]), [1.0, 1.0, 1.0])


def test_a_pose_turned_about_a_near_symmetry_is_turned_back() -> None:
    # The box with a block on one corner posed half a turn about one of its axes: ICP settles
    # the cuboid on the copy and the pose passes verification, but the block is on the wrong
    # side; the turned-back hypothesis explains the whole copy and replaces it.
    from pointclm.datasets import load_shape
    from pointclm.point_clouds import default_voxel_size
    from pointclm.refinement import flip_turns, resolve_flips

    model = load_shape("box", 4000, rng=0)
    voxel = default_voxel_size(model)
    src = pointclm.preprocessing.voxel_downsample(model, voxel)
    truth = _pose([0.3, 1.0, 0.2], 40.0, [0.5, -0.2, 0.1])
    scan = _apply(truth, src)
    turns = flip_turns(src, voxel)
    assert 1 <= len(turns) <= 3
    wrong = [truth @ t for t in turns]
    refined = pointclm.refine_poses(
        src, scan, wrong, voxel, max_shared=1.0, min_fitness=0.0, min_relative_fitness=0.0
    )
    assert len(refined.origin) == len(wrong)
    before = rotation_error_deg(refined.transformations[:, :3, :3], truth[:3, :3])
    assert (before > 90.0).all()
    fixed, order = resolve_flips(src, scan, refined, voxel)
    assert sorted(order.tolist()) == list(range(len(wrong)))
    after = rotation_error_deg(fixed.transformations[:, :3, :3], truth[:3, :3])
    assert (after < 5.0).all()
    assert (fixed.fitness >= refined.fitness[order] - 1e-9).all()
    assert (np.diff(fixed.confidence) <= 0).all()


def _slab_with_a_block(step: float = 0.04) -> np.ndarray:
    """A square slab with a small block on two opposite corners: a quarter turn about its
    vertical axis maps the slab onto itself and moves only the blocks, a half turn about it
    maps the whole onto itself."""
    g = np.arange(0.0, 1.0 + 1e-9, step)
    x, y = np.meshgrid(g, g)
    top = np.c_[x.ravel(), y.ravel(), np.full(x.size, 0.2)]
    bottom = top * [1, 1, 0]
    h = np.arange(0.0, 0.2 + 1e-9, step)
    sides = [np.c_[np.full(h.size, e), np.full(h.size, t), h] for e in (0.0, 1.0) for t in g]
    sides += [np.c_[np.full(h.size, t), np.full(h.size, e), h] for e in (0.0, 1.0) for t in g]
    b = np.arange(0.0, 0.3 + 1e-9, step)
    bx, by = np.meshgrid(b, b)
    block = [np.c_[bx.ravel(), by.ravel(), np.full(bx.size, z)] for z in (0.3, 0.4, 0.5)]
    opposite = [b * [-1, -1, 1] + [1, 1, 0] for b in block]
    return np.concatenate([top, bottom, *sides, *block, *opposite])


def test_a_pose_a_quarter_turn_off_about_a_near_symmetry_is_turned_back() -> None:
    # The slab's blocks on the wrong corners: the pose explains all of the slab, and its
    # blocks, lying where the scan has nothing, cost it a share that a fitness-only judge does
    # not tell from noise; only a quarter turn puts them back, and it replaces the pose.
    from pointclm.refinement import quarter_turns, resolve_flips

    src = _slab_with_a_block()
    voxel = 0.04
    turns = quarter_turns(src, voxel)
    assert 1 <= len(turns) <= 6
    truth = _pose([0.2, 0.3, 1.0], 25.0, [0.4, -0.1, 0.3])
    scan = _apply(truth, src)
    wrong = truth @ turns[0]
    refined = pointclm.refine_poses(
        src, scan, wrong[None], voxel, max_shared=1.0, min_fitness=0.0, min_relative_fitness=0.0
    )
    assert rotation_error_deg(refined.transformations[:, :3, :3], truth[:3, :3])[0] > 80.0
    fixed, _ = resolve_flips(src, scan, refined, voxel)
    # Right up to the slab's half-turn symmetry: every model point back on its own place.
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(scan).query(_apply(fixed.transformations[0], src))
    assert fixed.fitness[0] == 1.0 and dist.max() < 0.25 * voxel
    # A right pose stays: its turns explain none of the points that tell them apart.
    right = pointclm.refine_poses(
        src, scan, truth[None], voxel, max_shared=1.0, min_fitness=0.0, min_relative_fitness=0.0
    )
    kept, _ = resolve_flips(src, scan, right, voxel)
    np.testing.assert_array_equal(kept.transformations, right.transformations)
    assert kept.confidence[0] == right.confidence[0]
    # With the blocks out of the scan nothing tells the pose from its quarter turns: it stays,
    # one of several hypotheses, and says so in its confidence.
    slab = scan[_apply(np.linalg.inv(truth), scan)[:, 2] < 0.25]
    alone = pointclm.refine_poses(
        src, slab, truth[None], voxel, max_shared=1.0, min_fitness=0.0, min_relative_fitness=0.0
    )
    unsure, _ = resolve_flips(src, slab, alone, voxel)
    np.testing.assert_array_equal(unsure.transformations, alone.transformations)
    assert unsure.confidence[0] <= alone.confidence[0] / 2


def test_register_point_clouds_flips_argument_is_checked() -> None:
    src = _blob()
    with pytest.raises(ValueError, match="flips"):
        pointclm.register_point_clouds(src, src, flips="yes")  # type: ignore[arg-type]


def test_a_context_refines_as_refine_poses_does() -> None:
    from pointclm.refinement import RefinementContext

    model = _blob()
    truth = _pose([0.2, 1, 0.4], 35, [4.0, 1.0, -2.0])
    scene = np.vstack([_apply(truth, model), np.random.default_rng(1).uniform(-8, 8, (300, 3))])
    poses = np.stack(
        [_pose([0, 0, 1], 90, [-5.0, -5.0, 5.0]), truth @ _pose([1, 0, 0], 4, [0.1, 0, 0.08])]
    )
    eye = np.array([4.0, 1.0, 30.0])
    for viewpoint in (None, eye):
        context = RefinementContext(model, scene, 0.1, viewpoint=viewpoint)
        for kwargs in ({}, {"icp": False}, {"min_fitness": 0.0, "max_shared": 1.0}, {}):
            once = pointclm.refine_poses(model, scene, poses, 0.1, viewpoint=viewpoint, **kwargs)
            again = context.refine(poses, **kwargs)
            assert once.sliding is not None and again.sliding is not None
            both = zip(
                [*once[:-1], *once.sliding[:-1]], [*again[:-1], *again.sliding[:-1]], strict=True
            )
            for a, b in both:
                np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="voxel_size"):
        RefinementContext(model, scene, 0.0)
    with pytest.raises(ValueError, match="max_shared"):
        RefinementContext(model, scene, 0.1).refine(poses, max_shared=2.0)


def test_a_context_counts_what_each_pose_holds_before_icp() -> None:
    from pointclm.refinement import RefinementContext
    from scipy.spatial import cKDTree

    model = _blob()
    truth = _pose([0.2, 1, 0.4], 35, [4.0, 1.0, -2.0])
    scene = np.vstack([_apply(truth, model), np.random.default_rng(1).uniform(-8, 8, (300, 3))])
    poses = np.stack(
        [truth, _pose([0, 0, 1], 90, [30.0, -5.0, 5.0]), truth @ _pose([1, 0, 0], 9, [0, 0, 0])]
    )
    context = RefinementContext(model, scene, 0.1)
    sample = model[::3]
    before = (poses.copy(), sample.copy())
    for radius in (0.05, 0.2, 1.0):
        shares = context.near_shares(poses, sample, radius, num_threads=1)
        d, _ = cKDTree(scene).query(
            np.einsum("kij,nj->kni", poses[:, :3, :3], sample) + poses[:, None, :3, 3]
        )
        np.testing.assert_array_equal(shares, (d < radius).mean(axis=1))
        np.testing.assert_array_equal(shares, context.near_shares(poses, sample, radius))
    assert shares[0] == 1.0 and shares[1] == 0.0
    np.testing.assert_array_equal(before[0], poses)
    np.testing.assert_array_equal(before[1], sample)
    assert context.near_shares(np.empty((0, 4, 4)), sample, 0.2).shape == (0,)
    with pytest.raises(ValueError, match="radius"):
        context.near_shares(poses, sample, 0.0)
    with pytest.raises(ValueError, match="points"):
        context.near_shares(poses, sample[:, :2], 0.2)
    with pytest.raises(ValueError, match="transformations"):
        context.near_shares(poses[:, :3], sample, 0.2)


def test_a_pose_turned_where_no_principal_turn_reaches_is_turned_back_by_the_scenes_own() -> None:
    # The slab posed a quarter turn off, the principal-axis quarter turns withheld (a zero
    # max_quarter_turn_change): the
    # pose stays wrong, unless the turn comes in `rotations` (as a duplicate on the same copy
    # at the right rotation would give it).
    from pointclm.refinement import quarter_turns, resolve_flips

    src = _slab_with_a_block()
    voxel = 0.04
    turn = quarter_turns(src, voxel)[0]
    truth = _pose([0.2, 0.3, 1.0], 25.0, [0.4, -0.1, 0.3])
    scan = _apply(truth, src)
    refined = pointclm.refine_poses(
        src,
        scan,
        (truth @ turn)[None],
        voxel,
        max_shared=1.0,
        min_fitness=0.0,
        min_relative_fitness=0.0,
    )
    no_quarters = {"max_quarter_turn_change": 0.0}
    stays, _ = resolve_flips(src, scan, refined, voxel, scene=no_quarters)
    assert rotation_error_deg(stays.transformations[:, :3, :3], truth[:3, :3])[0] > 80.0
    back = np.linalg.inv(turn)[None, :3, :3]
    fixed, _ = resolve_flips(src, scan, refined, voxel, rotations=back, scene=no_quarters)
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(scan).query(_apply(fixed.transformations[0], src))
    assert fixed.fitness[0] == 1.0 and dist.max() < 0.25 * voxel


def test_resolve_flips_rotations_are_checked() -> None:
    from pointclm.refinement import resolve_flips

    src = _blob()
    truth = _pose([0.3, 1.0, 0.2], 40.0, [0.2, 0.1, -0.3])
    scan = _apply(truth, src)
    refined = pointclm.refine_poses(src, scan, truth[None], 0.05)
    with pytest.raises(ValueError, match=r"shape \(K, 3, 3\)"):
        resolve_flips(src, scan, refined, 0.05, rotations=np.eye(4)[None])
    with pytest.raises(ValueError, match="non-finite"):
        resolve_flips(src, scan, refined, 0.05, rotations=np.full((1, 3, 3), np.nan))
    # A near-rotation is made one; the identity is no alternative: the same result.
    base, _ = resolve_flips(src, scan, refined, 0.05)
    same, _ = resolve_flips(src, scan, refined, 0.05, rotations=[np.eye(3) * (1 + 1e-7)])
    np.testing.assert_array_equal(same.transformations, base.transformations)
    none, _ = resolve_flips(src, scan, refined, 0.05, rotations=[])
    np.testing.assert_array_equal(none.transformations, base.transformations)
    # A scaled matrix or a reflection is no rotation, whatever its nearest rotation would be.
    for wrong in (np.eye(3) * 1.01, np.diag([1.0, 1.0, -1.0])):
        with pytest.raises(ValueError, match=r"rotations\[1\] is not a rotation"):
            resolve_flips(src, scan, refined, 0.05, rotations=[np.eye(3), wrong])


def _terraced_bunny() -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """A bunny 2 m from a structured-light camera (900 px focal length, 5 cm baseline,
    disparity found to 1/8 pixel, so depth steps 11 mm deep there): the model, its visible
    side as the camera returns it (each depth rounded to a disparity step), the true pose and
    the part's diagonal."""
    from pointclm.datasets.parts import load_part, model_form, surface_samples

    part = load_part("bunny")
    pts, normals = surface_samples(part, 60_000, seed=1)
    a = np.deg2rad(30.0)
    truth = np.eye(4)
    truth[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    truth[:3, 3] = [0.0, 0.0, 2.0]
    copy = pts @ truth[:3, :3].T + truth[:3, 3]
    scan = copy[np.sum((normals @ truth[:3, :3].T) * -copy, axis=1) > 0]
    fb = 900 * 0.05
    depth = fb / (np.round(fb / scan[:, 2] * 8) / 8)
    return model_form(part, "fine_mesh"), scan * (depth / scan[:, 2])[:, None], truth, part.diameter


def test_a_copy_seen_through_depth_steps_is_kept_and_the_result_says_why() -> None:
    """Within one 11 mm depth step the scan is a flat terrace facing the camera: its normals
    over 2 voxels are the line of sight, and the exact pose fails the normals rule. Estimated
    by pointclm, they are fitted over 4 voxels there, and the pose is kept."""
    import pointclm.preprocessing as pp
    from pointclm import RefinementContext

    model, scan, truth, diagonal = _terraced_bunny()
    voxel = diagonal / 40
    src, tgt = pp.voxel_downsample(model, voxel), pp.voxel_downsample(scan, voxel)
    fine = pp.estimate_normals(tgt, 2 * voxel)
    given = RefinementContext(src, tgt, voxel, target_normals=fine)
    assert [r.rule for r in given.rejections(truth[None])] == ["min_normal_agreement"]
    kept = RefinementContext(src, tgt, voxel).refine(truth[None])
    assert len(kept.transformations) == 1
    assert rotation_error_deg(kept.transformations[0][:3, :3], truth[:3, :3]) < 5.0
    # The pipeline describes the scan with the same normals, and says so.
    reg = pointclm.register_point_clouds(model, scan, voxel_size=voxel)
    assert "depth steps make flat terraces" in reg.orientation


def test_terraced_share_sees_depth_steps_and_refuses_bad_input() -> None:
    import pointclm.preprocessing as pp

    model, scan, _, diagonal = _terraced_bunny()
    voxel = diagonal / 40
    steps = pp.terraced_share(pp.voxel_downsample(scan, voxel), 2 * voxel)
    smooth = pp.terraced_share(pp.voxel_downsample(model + [0.0, 0.0, 2.0], voxel), 2 * voxel)
    assert steps > 0.5 > pp.MAX_TERRACED_SHARE > abs(smooth), (steps, smooth)
    # Seen from the side, the same terraces are not turned towards the line of sight.
    side = pp.terraced_share(pp.voxel_downsample(scan, voxel), 2 * voxel, (5.0, 0.0, 2.0))
    assert side <= pp.MAX_TERRACED_SHARE
    given = scan.copy()
    for bad, match in [
        ((scan, -1.0), "radius"),
        ((scan[:, :2], 0.01), "points"),
        ((np.where(np.arange(len(scan))[:, None] == 3, np.nan, scan), 0.01), "NaN|finite"),
        ((scan, 0.01, (0.0, np.inf, 0.0)), "viewpoint"),
    ]:
        with pytest.raises(ValueError, match=match):
            pp.terraced_share(*bad)
    assert np.array_equal(scan, given)

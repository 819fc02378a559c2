"""Random procedural shape families: ``"superquadric-<seed>"``, ``"blend-<seed>"``
and ``"extrusion-<seed>"`` are seeded, valid, asymmetric meshes that every path taking a model
name accepts."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest
from pointclm.datasets import (
    PROCEDURAL_FAMILIES,
    PROCEDURAL_SHAPES,
    is_procedural,
    load_shape,
    procedural_family_names,
    procedural_mesh,
    sample_surface,
)
from pointclm.datasets.scenes import SceneParams, make_realistic_scene

scipy_spatial = pytest.importorskip("scipy.spatial")

SEEDS = range(30)
# The seven non-identity symmetries a shape with distinct principal moments can have, in its
# principal frame: three mirrors, three half-turns and the point reflection.
FLIPS = [
    np.diag(d)
    for d in [
        (-1, 1, 1),
        (1, -1, 1),
        (1, 1, -1),
        (-1, -1, 1),
        (-1, 1, -1),
        (1, -1, -1),
        (-1, -1, -1),
    ]
]


def _triangle_areas(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    a, b, c = (verts[faces[:, i]] for i in range(3))
    return np.asarray(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1))


def _chamfer(tree_a: Any, a: np.ndarray, b: np.ndarray) -> float:
    tree_b = scipy_spatial.cKDTree(b)
    return float(tree_a.query(b)[0].mean() + tree_b.query(a)[0].mean())


def _align(tree_a: Any, a: np.ndarray, b: np.ndarray, iterations: int = 6) -> np.ndarray:
    """A few rigid ICP steps of ``b`` onto ``a``: a symmetry need not sit exactly on the
    principal axes of a sampled cloud."""
    for _ in range(iterations):
        q = a[tree_a.query(b)[1]]
        mb, mq = b.mean(0), q.mean(0)
        u, _, vt = np.linalg.svd((b - mb).T @ (q - mq))
        r = vt.T @ np.diag([1.0, 1.0, np.linalg.det(vt.T @ u.T)]) @ u.T
        b = (b - mb) @ r.T + mq
    return b


def _symmetry_ratio(name: str, n: int = 1500) -> float:
    """Best chamfer distance between one sample of the shape and a mirrored or half-turned
    second sample, over that of the two samples as they are: about 1 (or below: ICP fits the
    sampling noise too) for a symmetric shape, clearly above for an asymmetric one."""
    verts, faces = procedural_mesh(name)
    a = sample_surface(verts, faces, n, 1)
    b = sample_surface(verts, faces, n, 2)
    a, b = a - a.mean(0), b - b.mean(0)
    _, axes = np.linalg.eigh(a.T @ a)
    tree_a = scipy_spatial.cKDTree(a)
    same = _chamfer(tree_a, a, b)
    flipped = [_align(tree_a, a, b @ axes @ m @ axes.T) for m in FLIPS]
    return min(_chamfer(tree_a, a, f) for f in flipped) / same


@pytest.mark.parametrize("family", PROCEDURAL_FAMILIES)
def test_family_meshes_are_valid_small_and_fast(family: str) -> None:
    start = time.perf_counter()
    meshes = [procedural_mesh(f"{family}-{s}") for s in SEEDS]
    per_mesh = (time.perf_counter() - start) / len(meshes)
    assert per_mesh < 0.05, per_mesh
    for verts, faces in meshes:
        assert verts.dtype == np.float64 and verts.ndim == 2 and verts.shape[1] == 3
        assert faces.dtype == np.int32 and faces.ndim == 2 and faces.shape[1] == 3
        assert np.isfinite(verts).all()
        assert faces.min() >= 0 and faces.max() < len(verts)
        assert 500 < len(faces) <= 6000
        areas = _triangle_areas(verts, faces)
        assert areas.min() > 0 and 1.0 < areas.sum() < 20.0  # about unit size
        assert np.linalg.norm(verts, axis=1).max() == pytest.approx(1.0)


def test_same_name_same_mesh_and_names_differ() -> None:
    meshes = {}
    for name in ("superquadric-17", "superquadric-18", "blend-17", "extrusion-17", "blend-0"):
        verts, faces = procedural_mesh(name)
        again = procedural_mesh(name)
        np.testing.assert_array_equal(verts, again[0])
        np.testing.assert_array_equal(faces, again[1])
        meshes[name] = verts
    names = list(meshes)
    for i, first in enumerate(names):
        for second in names[i + 1 :]:
            a, b = meshes[first], meshes[second]
            assert a.shape != b.shape or not np.allclose(a, b), (first, second)


@pytest.mark.parametrize("family", PROCEDURAL_FAMILIES)
def test_family_shapes_have_no_symmetry(family: str) -> None:
    ratios = {s: _symmetry_ratio(f"{family}-{s}") for s in SEEDS}
    worst = min(ratios, key=ratios.__getitem__)
    assert ratios[worst] > 1.15, f"{family}-{worst} looks symmetric: {ratios[worst]:.2f}"


def test_the_symmetry_check_sees_symmetric_shapes() -> None:
    # The elliptic cylinder and the capsule are mirror-symmetric; the check must say so.
    for name in ("cylinder", "capsule"):
        assert _symmetry_ratio(name) < 1.05, name


@pytest.mark.parametrize(
    ("name", "reason"),
    [
        ("superquadric-abc", "'abc' is not a non-negative integer"),
        ("superquadric--3", "'-3' is not a non-negative integer"),
        ("blend-07", "without leading zeros"),
        ("extrusion-", "'' is not a non-negative integer"),
        ("extrusion-1.5", "'1.5' is not"),
        ("sphere-3", "neither a fixed shape nor of a known family"),
        ("Torus", "neither a fixed shape nor of a known family"),
    ],
)
def test_bad_names_say_what_a_valid_name_is(name: str, reason: str) -> None:
    assert not is_procedural(name)
    with pytest.raises(ValueError) as info:
        procedural_mesh(name)
    message = str(info.value)
    assert reason in message and repr(name) in message
    assert "'<family>-<seed>'" in message and "superquadric-17" in message
    assert all(f in message for f in PROCEDURAL_FAMILIES)


def test_is_procedural() -> None:
    assert all(is_procedural(n) for n in PROCEDURAL_SHAPES)
    assert all(is_procedural(f"{f}-{s}") for f in PROCEDURAL_FAMILIES for s in (0, 7, 10**12))
    assert not any(is_procedural(n) for n in ("bunny", "stanford/dragon", "", "blend", None, 3))
    assert len(PROCEDURAL_SHAPES) == 6  # other code iterates the fixed shapes only


def test_family_names_for_training() -> None:
    names = procedural_family_names(300, seed=5)
    assert len(names) == len(set(names)) == 300
    assert all(is_procedural(n) for n in names)
    assert [n.split("-")[0] for n in names[:6]] == [*PROCEDURAL_FAMILIES] * 2
    assert procedural_family_names(300, seed=5) == names
    assert procedural_family_names(10, seed=5) == names[:10]
    assert procedural_family_names(10, seed=6) != names[:10]
    assert procedural_family_names(0) == ()
    for bad in ({"n": -1}, {"n": 2.0}, {"n": 3, "seed": -1}, {"n": True}):
        with pytest.raises(ValueError, match="non-negative int"):
            procedural_family_names(**bad)  # type: ignore[arg-type]


def test_load_shape_takes_family_names() -> None:
    cloud = load_shape("blend-5", n_points=500, rng=3)
    assert cloud.shape == (500, 3)
    np.testing.assert_allclose(cloud.mean(axis=0), 0.0, atol=1e-12)
    assert np.linalg.norm(cloud, axis=1).max() == pytest.approx(1.0)
    np.testing.assert_array_equal(cloud, load_shape("blend-5", n_points=500, rng=3))
    with pytest.raises(ValueError, match="'abc' is not a non-negative integer"):
        load_shape("superquadric-abc")
    with pytest.raises(ValueError, match="superquadric-17"):
        load_shape("no-such-shape")


def test_realistic_scene_with_a_family_model() -> None:
    params = SceneParams(model="superquadric-3", data_dir=None, clutter_models=PROCEDURAL_SHAPES)
    scene = make_realistic_scene(0, params)
    assert scene.model == "superquadric-3" and scene.n_instances >= 2
    assert (scene.labels >= 0).sum() >= 10
    assert (scene.inlier_ratios > 0).sum() >= 2
    bad = SceneParams(model="extrusion-x", data_dir=None, clutter_models=PROCEDURAL_SHAPES)
    with pytest.raises(ValueError, match="'x' is not a non-negative integer"):
        make_realistic_scene(0, bad)

"""Declared and detected symmetries: detection on boxes, a cylinder and the bunny, the BOP
form and its errors, symmetry-aware metrics, canonical poses, and `symmetry=` in
`register_point_clouds`."""

from __future__ import annotations

import json

import numpy as np
import pointclm
import pytest
from helpers import DATA
from pointclm import symmetry as sy
from pointclm.metrics import add_s, pose_match_matrix, symmetric_errors

BUNNY = DATA / "stanford/bunny/reconstruction/bun_zipper_res2.ply"


def box(sides, n=4000, seed=0, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """`n` points drawn uniformly on the faces of a box centred on `centre`."""
    rng = np.random.default_rng(seed)
    s = np.asarray(sides, dtype=np.float64)
    areas = np.array([s[1] * s[2], s[0] * s[2], s[0] * s[1]])
    axis = rng.choice(3, n, p=areas / areas.sum())
    p = (rng.random((n, 3)) - 0.5) * s
    p[np.arange(n), axis] = np.where(rng.random(n) < 0.5, -0.5, 0.5) * s[axis]
    return p + centre


def cylinder(n=4000, seed=0) -> np.ndarray:
    """`n` points on a closed cylinder along z (radius 0.5, height 2)."""
    rng = np.random.default_rng(seed)
    side, cap = 2 * np.pi * 0.5 * 2.0, np.pi * 0.25
    on_side = rng.random(n) * (side + 2 * cap) < side
    th = rng.random(n) * 2 * np.pi
    rho = np.where(on_side, 0.5, 0.5 * np.sqrt(rng.random(n)))
    z = np.where(on_side, (rng.random(n) - 0.5) * 2.0, np.where(rng.random(n) < 0.5, -1.0, 1.0))
    return np.stack([rho * np.cos(th), rho * np.sin(th), z], axis=1)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def random_pose(rng: np.random.Generator) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = random_rotation(rng), rng.normal(size=3)
    return t


def rotated(points: np.ndarray, r: np.ndarray) -> np.ndarray:
    return points @ r.T


# Detection.


def test_a_box_of_three_distinct_sides_has_four():
    r = random_rotation(np.random.default_rng(1))
    found = sy.detect(rotated(box([1.0, 2.0, 3.0]), r))
    assert found.order == 4
    traces = np.trace(found.discrete[:, :3, :3], axis1=1, axis2=2)
    assert np.allclose(np.sort(traces), [-1, -1, -1, 3], atol=1e-2)  # three half turns


def test_a_square_section_box_has_eight():
    r = random_rotation(np.random.default_rng(2))
    assert sy.detect(rotated(box([1.0, 1.0, 2.5], seed=3), r)).order == 8


def test_a_cylinder_has_a_continuous_axis():
    r = random_rotation(np.random.default_rng(4))
    found = sy.detect(rotated(cylinder(), r))
    assert found.order is None and len(found.axes) == 1
    assert abs(found.axes[0] @ (r @ [0, 0, 1])) > 0.999


def test_the_bunny_has_none():
    if not BUNNY.exists():
        pytest.skip(f"{BUNNY} is missing")
    pts = pointclm.io.load_points(BUNNY)
    assert sy.detect(pts).is_trivial


def test_a_box_with_a_block_on_a_corner_has_none():
    pts = np.concatenate([box([1, 2, 3]), box([0.4, 0.4, 0.4], 400, 1, (0.3, 0.8, 1.3))])
    assert sy.detect(pts).is_trivial


# The BOP form.

HALF_X = [1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1]
HALF_Y = [-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1]


def test_a_models_info_entry_passes_as_it_is():
    entry = {"diameter": 120.0, "min_x": -30.0, "symmetries_discrete": [HALF_X, HALF_Y]}
    found = sy.from_bop(entry)
    assert found.order == 4  # the half turn about z is their product
    again = sy.from_bop(found.to_bop())
    assert again.order == 4
    cyl = sy.from_bop(
        {
            "symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 5]}],
            "symmetries_discrete": [np.array(HALF_X, dtype=float).reshape(4, 4)],
        },
        scale=0.001,
    )
    assert cyl.order is None and np.allclose(cyl.offsets[0], [0, 0, 0.005])


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ({"symmetries_discrete": [[1, 0, 0, 0, 1, 0, 0, 0, 1]]}, "16 numbers"),
        ({"symmetries_discrete": [[1, 0.2, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]]}, "rotation"),
        ({"symmetries_discrete": [[-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]]}, "rotation"),
        ({"symmetries_discrete": [[np.nan] + HALF_X[1:]]}, "non-finite"),
        ({"symmetries_discrete": [HALF_X[:12] + [0, 0, 1, 1]]}, "last row"),
        ({"symmetries_discrete": "x"}, "list"),
        ({"symmetries_continuous": [{"axis": [0, 0]}]}, "3 numbers"),
        ({"symmetries_continuous": [{"axis": [0, 0, 0], "offset": [0, 0, 0]}]}, "zero"),
        ({"symmetries_continuous": [{"offset": [0, 0, 0]}]}, "axis"),
        ({"symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, np.inf, 0]}]}, "non-finite"),
    ],
)
def test_bad_entries_are_value_errors(entry, message):
    with pytest.raises(ValueError, match=message):
        sy.from_bop(entry)


def test_a_turn_generating_no_finite_group_is_a_value_error():
    c, s = np.cos(1.0), np.sin(1.0)  # a radian about z, and about x
    about_z = [c, -s, 0, 0, s, c, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]
    about_x = [1, 0, 0, 0, 0, c, -s, 0, 0, s, c, 0, 0, 0, 0, 1]
    with pytest.raises(ValueError, match="finite group"):
        sy.from_bop({"symmetries_discrete": [about_z, about_x]})


def test_resolve_takes_the_forms_and_refuses_others():
    assert sy.resolve(None) is None and sy.resolve("auto") == "auto"
    assert sy.resolve(np.eye(4)[None]).is_trivial
    with pytest.raises(ValueError, match="auto"):
        sy.resolve("yes")
    with pytest.raises(ValueError, match=r"\(S, 4, 4\)"):
        sy.resolve(np.eye(3))


# Metrics and canonical poses: every equivalent pose scores, and comes out, the same.

BOX = sy.from_bop({"symmetries_discrete": [HALF_X, HALF_Y]})
CYL = sy.from_bop(
    {
        "symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0.1, 0.0, 0.0]}],
        "symmetries_discrete": [HALF_X[:11] + [0.0] + HALF_X[12:]],
    }
)


def equivalents(sym: sy.Symmetry, pose: np.ndarray, rng: np.random.Generator) -> list:
    out = [pose @ s for s in sym.discrete]
    for a, o in zip(sym.axes, sym.offsets, strict=True):
        th = np.radians(rng.integers(1, 360))  # whole degrees: the ADD test's grid
        k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
        c = np.eye(4)
        c[:3, :3] = np.eye(3) + np.sin(th) * k + (1 - np.cos(th)) * k @ k
        c[:3, 3] = o - c[:3, :3] @ o
        out += [pose @ c @ s for s in sym.discrete]
    return out


def symmetric_points(sym: sy.Symmetry) -> np.ndarray:
    """Points that every symmetry of `sym` maps onto themselves (about a continuous axis,
    every whole degree): ADD is the same for equivalent poses only on such a set."""
    if sym is BOX:
        pts = box([1.0, 2.0, 3.0], 100)
        return np.concatenate([pts @ s[:3, :3].T + s[:3, 3] for s in sym.discrete])
    th = np.radians(np.arange(360))[:, None]
    ring = np.concatenate([np.cos(th), np.sin(th)], axis=1) * 0.5 + [0.1, 0.0]
    return np.concatenate([np.c_[ring, np.full(360, z)] for z in (-1.0, -0.3, 0.3, 1.0)])


@pytest.mark.parametrize("sym", [BOX, CYL], ids=["box", "cylinder"])
def test_every_equivalent_pose_scores_the_same(sym):
    rng = np.random.default_rng(5)
    pts = symmetric_points(sym)
    for _ in range(15):
        gt, pred = random_pose(rng), random_pose(rng)
        pred[:3, :3] = pred[:3, :3] @ gt[:3, :3]
        re0, te0 = symmetric_errors(pred, gt, sym)
        add0 = add_s(pred, gt, pts, sym)
        for e in equivalents(sym, pred, rng):
            re, te = symmetric_errors(e, gt, sym)
            assert np.allclose(re, re0, atol=1e-6) and np.allclose(te, te0, atol=1e-6)
            assert abs(add_s(e, gt, pts, sym) - add0) < 1e-6
        for e in equivalents(sym, gt, rng):  # the truth's equivalents: a perfect score
            re, te = symmetric_errors(e, gt, sym)
            assert re[0, 0] < 1e-5 and te[0, 0] < 1e-9
            assert pose_match_matrix(e, gt, 1.0, 1e-6, symmetries=sym).all()
            assert add_s(e, gt, pts, sym) < 1e-6


def test_errors_without_a_symmetry_are_plain():
    rng = np.random.default_rng(6)
    a, b = random_pose(rng), random_pose(rng)
    re, te = symmetric_errors(a, b)
    assert np.isclose(re[0, 0], pointclm.metrics.rotation_error_deg(a[:3, :3], b[:3, :3]))
    assert np.isclose(te[0, 0], np.linalg.norm(a[:3, 3] - b[:3, 3]))


@pytest.mark.parametrize("sym", [BOX, CYL], ids=["box", "cylinder"])
def test_equivalent_poses_have_one_canonical_pose(sym):
    rng = np.random.default_rng(7)
    for _ in range(20):
        pose = random_pose(rng)
        canon = sym.canonical(pose)
        for e in equivalents(sym, pose, rng):
            assert np.allclose(sym.canonical(e), canon, atol=1e-9)
        # The rotation nearest the identity among the equivalents.
        trace = np.trace(canon[:3, :3])
        assert all(np.trace(e[:3, :3]) <= trace + 1e-9 for e in equivalents(sym, pose, rng))


# register_point_clouds.


def _scene(model: np.ndarray, poses: list[np.ndarray]) -> np.ndarray:
    return np.concatenate([model @ t[:3, :3].T + t[:3, 3] for t in poses])


def test_register_point_clouds_returns_canonical_poses():
    rng = np.random.default_rng(8)
    model = box([1.0, 2.0, 3.0], 3000)
    poses = []
    for k in range(2):
        t = random_pose(rng)
        t[:3, 3] = [6.0 * k, 0.0, 0.0]
        poses.append(t)
    scan = _scene(box([1.0, 2.0, 3.0], 3000, seed=9), poses)
    reg = pointclm.register_point_clouds(
        model, scan, symmetry={"symmetries_discrete": [HALF_X, HALF_Y]}
    )
    assert reg.symmetry is not None and reg.symmetry.order == 4
    assert len(reg.instances) == 2
    for inst in reg.instances:
        assert np.allclose(BOX.canonical(inst.transformation), inst.transformation, atol=1e-9)
    # Each truth is found, up to the box's symmetry.
    match = pose_match_matrix(reg.transformations, poses, 5.0, 0.1, symmetries=BOX)
    assert match.any(axis=0).all()
    auto = pointclm.register_point_clouds(model, scan, symmetry="auto")
    assert auto.symmetry.order == 4
    for inst in auto.instances:
        assert np.allclose(auto.symmetry.canonical(inst.transformation), inst.transformation)


def test_a_symmetry_in_other_units_is_a_value_error():
    model = box([1.0, 2.0, 3.0], 2000)
    shifted = HALF_X[:7] + [500.0] + HALF_X[8:]  # a translation in mm for a model in m
    with pytest.raises(ValueError, match="units"):
        pointclm.register_point_clouds(model, model, symmetry={"symmetries_discrete": [shifted]})


def test_the_cli_scores_with_a_symmetry(tmp_path, capsys):
    from pointclm.cli import main

    rng = np.random.default_rng(10)
    model = box([1.0, 2.0, 3.0], 3000)
    t = random_pose(rng)
    scan = _scene(box([1.0, 2.0, 3.0], 3000, seed=11), [t])
    np.save(tmp_path / "m.npy", model)
    np.save(tmp_path / "s.npy", scan)
    # The truth written turned by a symmetry: still found.
    np.save(tmp_path / "gt.npy", (t @ np.array(HALF_X, dtype=float).reshape(4, 4))[None])
    info = tmp_path / "info.json"
    info.write_text(json.dumps({"diameter": 3.7, "symmetries_discrete": [HALF_X, HALF_Y]}))
    args = [str(tmp_path / f) for f in ("m.npy", "s.npy")]
    assert main(["register", *args, "--ground-truth", str(tmp_path / "gt.npy"),
                 "--symmetry", str(info), "--quiet"]) == 0  # fmt: skip
    assert "1 of 1 true pose(s) found" in capsys.readouterr().out
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"symmetries_discrete": [[1, 2, 3]]}))
    assert main(["register", *args, "--symmetry", str(bad), "--quiet"]) != 0
    assert "16 numbers" in capsys.readouterr().err


def test_other_matching_options_return_canonical_poses_too():
    rng = np.random.default_rng(12)
    model = box([1.0, 2.0, 3.0], 3000)
    t = random_pose(rng)
    scan = _scene(box([1.0, 2.0, 3.0], 3000, seed=13), [t])
    reg = pointclm.register_point_clouds(model, scan, k=2, symmetry="auto")
    assert reg.symmetry is not None and reg.symmetry.order == 4
    assert reg.instances
    for inst in reg.instances:
        assert np.allclose(reg.symmetry.canonical(inst.transformation), inst.transformation)


def test_refine_poses_returns_canonical_poses_as_register_point_clouds_does():
    rng = np.random.default_rng(14)
    model = box([1.0, 2.0, 3.0], 3000)
    t = random_pose(rng)
    scan = _scene(box([1.0, 2.0, 3.0], 3000, seed=15), [t])
    # The true pose and the same pose turned by a symmetry: one canonical pose, same scores.
    turned = t @ np.array(HALF_X, dtype=float).reshape(4, 4)
    plain = pointclm.refine_poses(model, scan, [turned], 0.1, icp=False)
    declared = {"symmetries_discrete": [HALF_X, HALF_Y]}
    refined = pointclm.refine_poses(model, scan, [turned], 0.1, icp=False, symmetry=declared)
    assert len(refined.transformations) == 1
    np.testing.assert_allclose(refined.transformations[0], BOX.canonical(t), atol=1e-9)
    np.testing.assert_allclose(refined.fitness, plain.fitness)
    assert not np.allclose(plain.transformations[0], refined.transformations[0])
    auto = pointclm.refine_poses(model, scan, [t, turned], 0.1, symmetry="auto")
    for pose in auto.transformations:
        assert np.allclose(BOX.canonical(pose), pose, atol=1e-9)
    with pytest.raises(ValueError, match="symmetry"):
        pointclm.refine_poses(model, scan, [t], 0.1, symmetry="mirror")

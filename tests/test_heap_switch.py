"""`register_point_clouds` in heaps: once the accepted copies show one, the later
passes relax the mutual check, by rank (``heap_rank``, the default) or within windows
(``mutual_window="auto"``)."""

from __future__ import annotations

import inspect
from typing import Any

import numpy as np
import pointclm
import pointclm.point_clouds as pc
import pointclm.preprocessing as pp
import pytest
from pointclm import scene_rules
from pointclm.datasets.bins import make_bin_scene
from pointclm.errors import InputError
from pointclm.scene_rules import SceneRules
from test_bins import SMALL  # a small bin of procedural boxes: about a second per registration


@pytest.fixture(scope="module")
def scene():
    return make_bin_scene(0, SMALL)


def _defaults(monkeypatch: pytest.MonkeyPatch, **fields: Any) -> None:
    """The scene-wide rules' defaults with `fields` changed, for every call in the test."""
    monkeypatch.setattr(scene_rules, "SCENE_DEFAULTS", SceneRules(**fields))


def _register(scene, **kwargs: Any) -> pointclm.PointCloudRegistration:
    kwargs.setdefault("mutual_window", "auto")
    return pointclm.register_point_clouds(
        scene.model_points,
        scene.scan,
        voxel_size=scene.voxel_size,
        viewpoint=scene.sensor,
        num_threads=1,
        **kwargs,
    )


def _described(scene, reg: pointclm.PointCloudRegistration) -> tuple[Any, Any]:
    """The model and `reg`'s scan (its downsampled points) described as the core describes
    them with the scan's sensor given."""
    voxel = reg.voxel_size
    model = pp.describe(scene.model_points, voxel, away_from=scene.model_points.mean(0))
    np.testing.assert_array_equal(model.points, reg.source_points)
    radii = {"normal_radius": 2.0 * voxel, "feature_radius": 5.0 * voxel}
    scan = pp.describe(reg.target_points, None, towards=scene.sensor, **radii)
    return model, scan


def _same_matching(scene, reg, checks: list[dict[str, Any]]) -> None:
    """Every pass of `reg` matched as the public matcher
    (:class:`pointclm.preprocessing.DescriptorMatcher`) matches its scan points with the
    keyword arguments `checks[r]` and the pass's seed: the core's checks are the matcher's."""
    model, scan = _described(scene, reg)
    matcher = pp.DescriptorMatcher(model.descriptors, scan.descriptors, target_points=scan.points)
    assert len(checks) == len(reg.passes)
    for r, (p, check) in enumerate(zip(reg.passes, checks, strict=True)):
        m = matcher.match(p.scan_points, seed=r, **check)
        np.testing.assert_array_equal(
            m.correspondences(model.points, scan.points), p.correspondences
        )


def _diagonal(scene) -> float:
    pts = scene.model_points
    return float(np.linalg.norm(pts.max(0) - pts.min(0)))


PLAIN = {"mutual": True, "n_samples": 1000}
RANKED = {**PLAIN, "mutual_rank": pc.HEAP_RANK}


def test_the_scene_wide_check_is_the_default() -> None:
    # "auto" costs 1.75x on heaps for a small gain (BENCHMARKS.md, bins): opt-in.
    default = inspect.signature(pointclm.register_point_clouds).parameters["mutual_window"]
    assert default.default is None


def test_below_the_count_auto_is_the_scene_wide_check(scene, monkeypatch) -> None:
    # A count no scene reaches: every pass matches as with mutual_window=None.
    _defaults(monkeypatch, heap_min_copies=10_000)
    auto = _register(scene)
    _same_matching(scene, auto, [PLAIN] * len(auto.passes))
    plain = _register(scene, mutual_window=None)
    np.testing.assert_array_equal(auto.transformations, plain.transformations)
    assert len(auto.passes) == len(plain.passes)


def test_once_the_count_is_reached_later_passes_match_in_windows(scene, monkeypatch) -> None:
    # This small bin's first pass finds one box: a count of 1 makes the later passes switch.
    _defaults(monkeypatch, heap_min_copies=1)
    reg = _register(scene)
    assert len(reg.passes) >= 2
    windowed = {"mutual": True, "n_samples": None, "window": pc.HEAP_WINDOW * _diagonal(scene)}
    accepted = np.cumsum([p.added for p in reg.passes])
    # Pass 0 always matches scene-wide; pass r in windows once passes 0..r-1 found a copy.
    checks = [windowed if r and accepted[r - 1] >= 1 else PLAIN for r in range(len(reg.passes))]
    assert windowed in checks
    _same_matching(scene, reg, checks)
    # The poses are verified as ever: deterministic, each a distinct copy.
    again = _register(scene)
    np.testing.assert_array_equal(again.transformations, reg.transformations)


def test_auto_leaves_matching_it_cannot_make_local_alone(scene, monkeypatch) -> None:
    # Without the mutual check (or with k > 1) there is nothing to make local: "auto" is a
    # no-op there, not an error, so that it can be passed with any matching.
    _defaults(monkeypatch, heap_min_copies=1)
    reg = _register(scene, mutual=False)
    assert len(reg.passes) >= 1
    _same_matching(scene, reg, [{"mutual": False, "n_samples": 1000}] * len(reg.passes))


@pytest.mark.parametrize("bad", ["Auto", "windows", ""])
def test_other_strings_are_rejected(scene, bad: str) -> None:
    with pytest.raises(InputError, match="mutual_window must be a number"):
        _register(scene, mutual_window=bad)


def test_by_default_a_heap_relaxes_the_check_by_rank(scene, monkeypatch) -> None:
    default = inspect.signature(pointclm.register_point_clouds).parameters["heap_rank"]
    assert default.default == pc.HEAP_RANK == 64
    _defaults(monkeypatch, heap_min_copies=1)
    reg = _register(scene, mutual_window=None)
    accepted = np.cumsum([p.added for p in reg.passes])
    # Pass 0 is the mutual nearest check; pass r ranked once passes 0..r-1 found a copy.
    checks = [RANKED if r and accepted[r - 1] >= 1 else PLAIN for r in range(len(reg.passes))]
    assert RANKED in checks
    _same_matching(scene, reg, checks)


def test_below_the_count_or_without_a_rank_every_pass_is_the_mutual_check(scene, monkeypatch):
    _defaults(monkeypatch, heap_min_copies=1)
    plain = _register(scene, mutual_window=None, heap_rank=None)
    _same_matching(scene, plain, [PLAIN] * len(plain.passes))
    _defaults(monkeypatch, heap_min_copies=10_000)
    ranked = _register(scene, mutual_window=None)
    np.testing.assert_array_equal(ranked.transformations, plain.transformations)
    _same_matching(scene, ranked, [PLAIN] * len(ranked.passes))


@pytest.mark.parametrize("bad", [0, -3, 2.5, True, "64"])
def test_a_bad_heap_rank_is_rejected(scene, bad) -> None:
    with pytest.raises(InputError, match="heap_rank must be an int"):
        _register(scene, heap_rank=bad)


def test_a_scan_said_to_be_a_heap_relaxes_the_check_in_every_pass(scene, monkeypatch):
    reg = _register(scene, mutual_window=None, heap=True)
    _same_matching(scene, reg, [RANKED] * len(reg.passes))
    _defaults(monkeypatch, heap_min_copies=1)  # heap=False wins over any count
    never = _register(scene, mutual_window=None, heap=False)
    _same_matching(scene, never, [PLAIN] * len(never.passes))
    plain = _register(scene, mutual_window=None, heap_rank=None)
    np.testing.assert_array_equal(never.transformations, plain.transformations)


@pytest.mark.parametrize("bad", [1, "yes", 0.5])
def test_heap_is_true_false_or_none(scene, bad) -> None:
    with pytest.raises(InputError, match="heap must be True or False"):
        _register(scene, heap=bad)


def _empty_tail(reg: pointclm.PointCloudRegistration) -> int:
    """How many passes at the end added no copy."""
    tail = 0
    for p in reversed(reg.passes[1:]):
        if p.added:
            break
        tail += 1
    return tail


@pytest.mark.parametrize("rounds", [1, 2, 3])
def test_in_a_heap_peeling_stops_after_its_count_of_empty_rounds(scene, monkeypatch, rounds):
    _defaults(monkeypatch, heap_empty_rounds=rounds)
    reg = _register(scene, mutual_window=None, heap=True)
    if len(reg.passes) <= pc.MAX_PEEL_ROUNDS:  # not cut by the round limit
        assert _empty_tail(reg) == rounds
    # Outside a heap one empty round ends it, whatever the heap's count.
    plain = _register(scene, mutual_window=None, heap=False)
    assert _empty_tail(plain) <= 1

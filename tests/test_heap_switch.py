"""`register_point_clouds` in heaps: once the accepted copies show one (issue 18), the later
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


def _spy_on_matching(monkeypatch) -> list[dict[str, Any]]:
    """Every `DescriptorMatcher.match` call's keyword arguments, in order (the Python stages
    run: the core's pipeline matches inside the core)."""
    from pointclm.clouds import core_path

    monkeypatch.setattr(core_path, "ENABLED", False)
    calls: list[dict[str, Any]] = []
    match = pp.DescriptorMatcher.match

    def spy(self, *args: Any, **kwargs: Any):
        calls.append(kwargs)
        return match(self, *args, **kwargs)

    monkeypatch.setattr(pp.DescriptorMatcher, "match", spy)
    return calls


def test_the_scene_wide_check_is_the_default() -> None:
    # "auto" costs 1.75x on heaps for a small gain (BENCHMARKS.md, bins): opt-in.
    default = inspect.signature(pointclm.register_point_clouds).parameters["mutual_window"]
    assert default.default is None


def test_below_the_count_auto_is_the_scene_wide_check(scene, monkeypatch) -> None:
    # A count no scene reaches: every pass matches as with mutual_window=None.
    _defaults(monkeypatch, heap_min_copies=10_000)
    calls = _spy_on_matching(monkeypatch)
    auto = _register(scene)
    assert all("window" not in c for c in calls)
    plain = _register(scene, mutual_window=None)
    np.testing.assert_array_equal(auto.transformations, plain.transformations)
    assert len(auto.passes) == len(plain.passes)


def test_once_the_count_is_reached_later_passes_match_in_windows(scene, monkeypatch) -> None:
    # This small bin's first pass finds one box: a count of 1 makes the later passes switch.
    _defaults(monkeypatch, heap_min_copies=1)
    calls = _spy_on_matching(monkeypatch)
    reg = _register(scene)
    assert len(reg.passes) == len(calls) >= 2
    diagonal = float(np.linalg.norm(np.ptp(reg.source_points, axis=0)))
    accepted = np.cumsum([p.added for p in reg.passes])
    # Pass 0 always matches scene-wide; pass r in windows once passes 0..r-1 found a copy.
    assert "window" not in calls[0] and calls[0]["n_samples"] == 1000
    for r in range(1, len(calls)):
        if accepted[r - 1] >= 1:
            assert calls[r]["window"] == pytest.approx(pc.HEAP_WINDOW * diagonal)
            assert calls[r]["n_samples"] is None and calls[r]["mutual"] is True
        else:
            assert "window" not in calls[r]
    assert any("window" in c for c in calls)
    # The poses are verified as ever: deterministic, each a distinct copy.
    again = _register(scene)
    np.testing.assert_array_equal(again.transformations, reg.transformations)


def test_auto_leaves_matching_it_cannot_make_local_alone(scene, monkeypatch) -> None:
    # Without the mutual check (or with k > 1) there is nothing to make local: "auto" is a
    # no-op there, not an error, so that it can be passed with any matching.
    _defaults(monkeypatch, heap_min_copies=1)
    calls = _spy_on_matching(monkeypatch)
    reg = _register(scene, mutual=False)
    assert len(reg.passes) >= 1 and all("window" not in c for c in calls)


@pytest.mark.parametrize("bad", ["Auto", "windows", ""])
def test_other_strings_are_rejected(scene, bad: str) -> None:
    with pytest.raises(InputError, match="mutual_window must be a number"):
        _register(scene, mutual_window=bad)


def test_by_default_a_heap_relaxes_the_check_by_rank(scene, monkeypatch) -> None:
    default = inspect.signature(pointclm.register_point_clouds).parameters["heap_rank"]
    assert default.default == pc.HEAP_RANK == 64
    _defaults(monkeypatch, heap_min_copies=1)
    calls = _spy_on_matching(monkeypatch)
    reg = _register(scene, mutual_window=None)
    accepted = np.cumsum([p.added for p in reg.passes])
    assert "mutual_rank" not in calls[0]  # pass 0 is the mutual nearest check
    for r in range(1, len(calls)):
        ranked = accepted[r - 1] >= 1
        assert calls[r].get("mutual_rank") == (pc.HEAP_RANK if ranked else None)
        assert calls[r]["n_samples"] == 1000 and "window" not in calls[r]
    assert any("mutual_rank" in c for c in calls)


def test_below_the_count_or_without_a_rank_every_pass_is_the_mutual_check(scene, monkeypatch):
    calls = _spy_on_matching(monkeypatch)
    plain = _register(scene, mutual_window=None, heap_rank=None)
    assert all("mutual_rank" not in c for c in calls)
    _defaults(monkeypatch, heap_min_copies=10_000)
    ranked = _register(scene, mutual_window=None)
    np.testing.assert_array_equal(ranked.transformations, plain.transformations)
    assert all("mutual_rank" not in c for c in calls)


@pytest.mark.parametrize("bad", [0, -3, 2.5, True, "64"])
def test_a_bad_heap_rank_is_rejected(scene, bad) -> None:
    with pytest.raises(InputError, match="heap_rank must be an int"):
        _register(scene, heap_rank=bad)


def test_a_scan_said_to_be_a_heap_relaxes_the_check_in_every_pass(scene, monkeypatch):
    calls = _spy_on_matching(monkeypatch)
    reg = _register(scene, mutual_window=None, heap=True)
    assert len(calls) == len(reg.passes) >= 1
    assert all(c.get("mutual_rank") == pc.HEAP_RANK for c in calls)
    calls.clear()
    _defaults(monkeypatch, heap_min_copies=1)  # heap=False wins over any count
    never = _register(scene, mutual_window=None, heap=False)
    assert all("mutual_rank" not in c for c in calls)
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

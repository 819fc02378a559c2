"""The picture of a result: two views, a key with every copy's fitness, missed ground truth,
and an empty result that says so."""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")

from matplotlib.image import imread  # noqa: E402
from pointclm.visualize import (  # noqa: E402
    MISSED,
    _frame,
    _hull,
    draw_registration,
    save_png,
    save_registration_png,
)

RNG = np.random.default_rng(7)


def pose(angle_deg: float, t: tuple[float, float, float]) -> np.ndarray:
    a = np.radians(angle_deg)
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:3, 3] = t
    return T


def make_scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A lumpy, asymmetric model (an ellipsoid's surface) three times on a floor."""
    d = RNG.normal(size=(600, 3))
    model = d / np.linalg.norm(d, axis=1, keepdims=True) * [0.5, 0.3, 0.2] + [0, 0, 0.2]
    truth = np.stack([pose(0, (-1.5, 0, 0)), pose(60, (0, 1, 0)), pose(120, (1.5, -0.5, 0))])
    floor = np.c_[RNG.uniform(-3, 3, size=(3000, 2)), np.zeros(3000)]
    copies = [model @ T[:3, :3].T + T[:3, 3] for T in truth]
    return np.vstack([floor, *copies]), model, truth


SCENE, MODEL, TRUTH = make_scene()


def legend_texts(fig) -> list[str]:
    assert len(fig.legends) == 1
    return [t.get_text() for t in fig.legends[0].get_texts()]


def figure_texts(fig) -> str:
    return "\n".join(t.get_text() for t in fig.texts)


def test_two_views_side_by_side_with_equal_aspect() -> None:
    fig = draw_registration(SCENE, MODEL, TRUTH, 0.05)
    top, oblique = fig.axes
    assert top.name != "3d" and oblique.name == "3d"
    assert top.get_aspect() == 1.0
    # The 3D box has the data's proportions, so no axis is stretched.
    spans = np.array([np.ptp(lim) for lim in np.reshape(oblique.get_w_lims(), (3, 2))])
    np.testing.assert_allclose(
        oblique.get_box_aspect() / oblique.get_box_aspect().max(), spans / spans.max(), rtol=1e-6
    )
    # Side by side: the views share a row.
    assert top.get_position().x1 <= oblique.get_position().x0 + 1e-6


def test_key_has_one_entry_per_copy_with_its_fitness() -> None:
    fig = draw_registration(
        SCENE, MODEL, TRUTH, 0.05, fitness=[0.91, 0.72, 0.5], confidence=[0.8, np.nan, 0.3]
    )
    copies = [t for t in legend_texts(fig) if "fitness" in t]
    assert copies == [
        "0: fitness 0.91, confidence 0.80",
        "1: fitness 0.72",
        "2: fitness 0.50, confidence 0.30",
    ]
    assert "3 copies found" in fig.get_suptitle()
    # Both views number the copies as the key does, from 0 like the console's [0], [1], ...
    for ax in fig.axes:  # (the numbers are the outlined texts; the scale bar's is not)
        numbers = sorted(t.get_text() for t in ax.texts if t.get_path_effects())
        assert numbers == ["0", "1", "2"]


def test_fitness_is_measured_when_not_given() -> None:
    # The true poses lay the model on its copies; a pose far from the scene explains nothing.
    poses = np.stack([TRUTH[0], pose(0, (0, 0, 10))])
    fig = draw_registration(SCENE, MODEL, poses, 0.05)
    assert [t for t in legend_texts(fig) if "fitness" in t] == [
        "0: fitness 1.00",
        "1: fitness 0.00",
    ]


def test_each_copy_has_its_own_colour_and_outline() -> None:
    fig = draw_registration(SCENE, MODEL, TRUTH, 0.05)
    top = fig.axes[0]
    outlines = [line for line in top.get_lines() if line.get_linestyle() == "-"]
    colours = {
        tuple(np.round(line.get_color(), 3)) for line in outlines if len(line.get_xdata()) > 2
    }
    assert len(colours) == len(TRUTH)


def test_fitness_count_must_match_the_poses() -> None:
    with pytest.raises(ValueError, match="one value per pose"):
        draw_registration(SCENE, MODEL, TRUTH, 0.05, fitness=[0.5])


def test_empty_result_says_so_with_its_reason() -> None:
    fig = draw_registration(SCENE, MODEL, np.zeros((0, 4, 4)), 0.05, reason="too few matches")
    text = figure_texts(fig)
    assert "no copy found" in text and "too few matches" in text
    assert "no copy found" in fig.get_suptitle()
    assert not [t for t in legend_texts(fig) if "fitness" in t]
    # A result with copies shows no such banner.
    assert "no copy found" not in figure_texts(draw_registration(SCENE, MODEL, TRUTH, 0.05))


def missed_artists(fig) -> list:
    return [a for ax in fig.axes for a in ax.get_children() if a.get_gid() == "missed"]


def test_missed_ground_truth_is_drawn_dashed_and_hollow() -> None:
    # Copy 2 found, copy 1 found 20 degrees off (a miss), copy 3 not found.
    found = np.stack([TRUTH[1], TRUTH[0] @ pose(20, (0, 0, 0))])
    fig = draw_registration(SCENE, MODEL, found, 0.05, ground_truth=TRUTH)
    drawn = missed_artists(fig)
    dashed = [a for a in drawn if a in fig.axes[0].get_lines()]
    hollow = [a for a in drawn if a in fig.axes[1].collections]
    assert len(dashed) == 2 and len(hollow) == 2
    assert all(line.get_linestyle() == "--" for line in dashed)
    assert all(np.allclose(c.get_facecolor(), 0) for c in hollow)  # no fill
    assert all(np.allclose(c.get_edgecolor()[0][:3], MISSED) for c in hollow)
    assert "missed ground truth" in legend_texts(fig)
    assert "1 of 3 true copies matched" in fig.get_suptitle()


def test_nothing_missed_when_every_true_copy_is_found_or_none_given() -> None:
    fig = draw_registration(SCENE, MODEL, TRUTH[::-1], 0.05, ground_truth=TRUTH)
    assert not missed_artists(fig)
    assert "3 of 3 true copies matched" in fig.get_suptitle()
    assert not missed_artists(draw_registration(SCENE, MODEL, TRUTH[:1], 0.05))


def read_png(path: Path) -> np.ndarray:
    img = imread(path)
    assert img.ndim == 3 and img.shape[0] > 400 and img.shape[1] > 800
    return img[..., :3]


def saturated(img: np.ndarray) -> np.ndarray:
    return (img.max(-1) - img.min(-1)) > 0.4


def test_png_is_non_trivial(tmp_path: Path) -> None:
    path = tmp_path / "result.png"
    # The CLI's positional call, unchanged.
    save_png(path, SCENE, MODEL, TRUTH[:2], 0.05, "a title")
    assert path.stat().st_size > 20_000
    img = read_png(path)
    grey = (np.abs(img - 0.8).max(-1) < 0.02).mean()
    assert grey > 0.002, "the scene is drawn in light grey"
    assert saturated(img).mean() > 0.002, "the copies are drawn in colour"


def test_empty_png_shows_the_message(tmp_path: Path) -> None:
    path = tmp_path / "empty.png"
    save_png(path, SCENE, MODEL, np.zeros((0, 4, 4)), 0.05, reason="nothing matched")
    img = read_png(path)
    red = (img[..., 0] > 0.6) & (img[..., 1] < 0.15) & (img[..., 2] < 0.15)
    assert red.sum() > 500, "the 'no copy found' banner is large and red"


def test_registration_png_uses_the_results_scores(tmp_path: Path, monkeypatch) -> None:
    import pointclm.visualize as viz

    seen: dict = {}
    real = viz.draw_registration

    def spy(*args, **kwargs):
        seen.update(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr(viz, "draw_registration", spy)
    inst = SimpleNamespace(transformation=TRUTH[0], fitness=0.66, confidence=0.9)
    reg = SimpleNamespace(
        instances=[inst],
        transformations=TRUTH[:1],
        target_points=SCENE,
        source_points=MODEL,
        voxel_size=0.04,
        result=[],
        correspondences=np.zeros((30, 6)),
    )
    save_registration_png(tmp_path / "one.png", reg, ground_truth=TRUTH)
    assert seen["fitness"] == [0.66] and seen["confidence"] == [0.9] and seen["reason"] is None
    assert (tmp_path / "one.png").stat().st_size > 20_000

    empty = SimpleNamespace(
        **{**vars(reg), "instances": [], "transformations": np.zeros((0, 4, 4))}
    )
    save_registration_png(tmp_path / "none.png", empty)
    assert "30 correspondences" in seen["reason"]
    empty.result = [object(), object()]
    save_registration_png(tmp_path / "none.png", empty)
    assert "2 poses" in seen["reason"] and "supported none" in seen["reason"]
    # The result's own diagnosis, when it has one, is the reason shown.
    empty.diagnosis = "no candidate pose: try a smaller voxel"
    save_registration_png(tmp_path / "none.png", empty)
    assert seen["reason"] == "no candidate pose: try a smaller voxel"


def test_missing_matplotlib_is_a_clear_import_error(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    with pytest.raises(ImportError, match=r"pointclm\[viz\]"):
        draw_registration(SCENE, MODEL, TRUTH, 0.05)


def test_hull_is_the_closed_convex_outline() -> None:
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    inside = RNG.uniform(0.1, 0.9, size=(50, 2))
    ring = _hull(np.vstack([inside, square]))
    np.testing.assert_array_equal(ring[0], ring[-1])
    assert {tuple(p) for p in ring} == {tuple(p) for p in square}


def test_frame_puts_the_floor_down_and_objects_up() -> None:
    # Upside down: objects hang below the floor; the picture turns them back up.
    flipped = SCENE * [1, -1, -1]
    centre, rot = _frame(flipped)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    heights = (flipped - centre) @ rot[2]
    floor = heights[:3000]
    assert np.median(heights[3000:]) > np.median(floor)
    assert np.ptp(floor) < 0.05 * np.ptp(heights)

"""Pictures of a result: each copy found in its own colour over the grey scene.

The PLY (any viewer) needs nothing beyond numpy; the PNG needs matplotlib
(``pip install 'pointclm[viz]'``).

The PNG shows the scene from above and from a three-quarter view side by side, both with
equal aspect, in the scene's principal frame (its thinnest axis up: a tabletop's floor lies
flat). Each copy found is the model placed by its pose, drawn in its own colour and outlined
(its footprint from above), numbered from 0 in the order of the result (surest first), as
``pointclm register`` prints them (``[0]``), as ``reg.instances`` and the JSON of ``--out``
list them, with its fitness (and confidence, when known) in the key. Given the ground-truth
poses, the true copies no found pose matches are drawn hollow and dashed in black. A result
with no copy says so across the picture, with the reason if given.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from ._core import nearest_neighbours
from .metrics import pose_match_matrix

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "colour_scene",
    "draw_registration",
    "palette",
    "save_png",
    "save_ply",
    "save_registration_png",
]

GREY = np.array([0.6, 0.6, 0.6])
#: The PNG's scene: light enough that every copy's colour stands out on it.
SCENE_GREY = (0.8, 0.8, 0.8)
#: Missed ground truth: black, the one colour the palette never gives a copy.
MISSED = (0.0, 0.0, 0.0)
#: A found pose matches a true one as the benchmarks score it: rotation error under 15
#: degrees, translation error under a tenth of the model's bounding-box diagonal.
MATCH_DEG, MATCH_DIAMETERS = 15.0, 0.1
#: Points drawn at most: matplotlib's 3D scatter slows down past this with no visible gain.
MAX_SCENE_POINTS, MAX_MODEL_POINTS = 60_000, 1500


def palette(n: int) -> np.ndarray:
    """`n` distinct saturated colours (golden-ratio hues), (n, 3) in [0, 1]."""
    h = (np.arange(n) * 0.618033988749895) % 1.0
    i = np.floor(h * 6).astype(int) % 6
    f = h * 6 - np.floor(h * 6)
    v, s = 0.95, 0.85
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    table = np.stack(
        [
            np.stack([np.full(n, v), t, np.full(n, p)], 1),
            np.stack([q, np.full(n, v), np.full(n, p)], 1),
            np.stack([np.full(n, p), np.full(n, v), t], 1),
            np.stack([np.full(n, p), q, np.full(n, v)], 1),
            np.stack([t, np.full(n, p), np.full(n, v)], 1),
            np.stack([np.full(n, v), np.full(n, p), q], 1),
        ]
    )
    return table[i, np.arange(n)]


def colour_scene(
    scene: np.ndarray, model: np.ndarray, poses: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Scene colours (scene points within `radius` of a placed model take its colour, others
    grey), the instance colours, and each model placed by its pose."""
    colours = np.tile(GREY, (len(scene), 1))
    cols = palette(len(poses))
    placed = []
    best = np.full(len(scene), np.inf)
    for k, T in enumerate(poses):
        m = model @ T[:3, :3].T + T[:3, 3]
        placed.append(m)
        _, d = nearest_neighbours(m, scene)
        near = (d < radius) & (d < best)
        colours[near] = cols[k]
        best[near] = d[near]
    return colours, cols, placed


def save_ply(
    path: str | os.PathLike[str],
    scene: np.ndarray,
    model: np.ndarray,
    poses: np.ndarray,
    radius: float,
) -> None:
    """Scene points coloured by instance, plus each placed model in a darker shade."""
    from .io import write_ply

    colours, cols, placed = colour_scene(scene, model, poses, radius)
    pts = [scene, *placed]
    rgb = [colours, *[np.tile(0.6 * c, (len(m), 1)) for c, m in zip(cols, placed, strict=True)]]
    write_ply(path, np.concatenate(pts), colors=np.concatenate(rgb))


@dataclass
class _Copy:
    """One model placed in the picture's frame: a found copy or a missed true one."""

    points: np.ndarray
    colour: Any
    label: str


def _frame(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The scene's centre and a rotation to its principal axes, the thinnest one up."""
    if len(points) < 3:
        return (points.mean(0) if len(points) else np.zeros(3)), np.eye(3)
    centre = points.mean(0)
    sample = (points - centre)[:: max(1, len(points) // 20000)]
    _, _, vt = np.linalg.svd(sample, full_matrices=False)
    rot = vt.copy()
    # The SVD's signs are arbitrary. On a tabletop the floor holds most points at the bottom
    # and the objects stick out above it, so heights are skewed upwards when up is up.
    if np.mean((sample @ rot[2]) ** 3) < 0:
        rot[2] *= -1
    if np.linalg.det(rot) < 0:
        rot[1] *= -1
    return centre, rot


def _hull(xy: np.ndarray) -> np.ndarray:
    """The closed convex hull of 2D points (Andrew's monotone chain): a copy's footprint."""
    pts = np.unique(xy, axis=0)
    if len(pts) < 3:
        return pts

    def chain(seq: np.ndarray) -> list[np.ndarray]:
        out: list[np.ndarray] = []
        for p in seq:
            while len(out) >= 2:
                (ax, ay), (bx, by) = out[-1] - out[-2], p - out[-2]
                if ax * by - ay * bx > 0:
                    break
                out.pop()
            out.append(p)
        return out

    ring = chain(pts)[:-1] + chain(pts[::-1])[:-1]
    return np.array([*ring, ring[0]])


def _fitness(scene: np.ndarray, placed: np.ndarray, radius: float) -> float:
    """Open3D's fitness of one placed model: the share of its points within `radius` of the
    scene (what the result reports, when the caller has not passed it)."""
    if len(scene) == 0 or len(placed) == 0:
        return 0.0
    _, d = nearest_neighbours(scene, placed)
    return float(np.mean(d < radius))


def _copy_label(k: int, fitness: float, confidence: float) -> str:
    text = f"{k}: fitness {fitness:.2f}"
    return text + (f", confidence {confidence:.2f}" if np.isfinite(confidence) else "")


def _placed(model: np.ndarray, T: np.ndarray, centre: np.ndarray, rot: np.ndarray) -> np.ndarray:
    return (model @ T[:3, :3].T + T[:3, 3] - centre) @ rot.T


def _as_scores(values: ArrayLike | None, n: int, name: str) -> np.ndarray | None:
    if values is None:
        return None
    arr = np.asarray(values, dtype=np.float64).reshape(-1)
    if len(arr) != n:
        raise ValueError(f"{name} needs one value per pose ({n}), got {len(arr)}")
    return arr


def _copies(
    scene: np.ndarray,
    model: np.ndarray,
    poses: np.ndarray,
    radius: float,
    fitness: ArrayLike | None,
    confidence: ArrayLike | None,
    frame: tuple[np.ndarray, np.ndarray],
) -> list[_Copy]:
    """The found copies in the picture's frame, each with its colour and key entry."""
    fit = _as_scores(fitness, len(poses), "fitness")
    conf = _as_scores(confidence, len(poses), "confidence")
    sub = model[:: max(1, len(model) // MAX_MODEL_POINTS)]
    out = []
    for k, (T, colour) in enumerate(zip(poses, palette(len(poses)), strict=True)):
        f = fit[k] if fit is not None else _fitness(scene, model @ T[:3, :3].T + T[:3, 3], radius)
        c = conf[k] if conf is not None else float("nan")
        out.append(_Copy(_placed(sub, T, *frame), colour, _copy_label(k, f, c)))
    return out


def _missed(
    model: np.ndarray,
    poses: np.ndarray,
    ground_truth: ArrayLike,
    frame: tuple[np.ndarray, np.ndarray],
) -> tuple[list[_Copy], int]:
    """The true copies no found pose matches (as the benchmarks score a pose), and how many
    true copies there are."""
    gt = np.asarray(ground_truth, dtype=np.float64).reshape(-1, 4, 4)
    diameter = float(np.linalg.norm(np.ptp(model, axis=0))) if len(model) else 0.0
    match = pose_match_matrix(poses, gt, MATCH_DEG, MATCH_DIAMETERS * diameter)
    sub = model[:: max(1, len(model) // MAX_MODEL_POINTS)]
    missed = [
        _Copy(_placed(sub, T, *frame), MISSED, "missed ground truth")
        for T, hit in zip(gt, np.asarray(match.any(axis=0)).reshape(-1), strict=True)
        if not hit
    ]
    return missed, len(gt)


def _nice_length(limit: float) -> float:
    """The largest 1, 2 or 5 times a power of ten not over `limit`: a scale bar's length."""
    if limit <= 0:
        return 0.0
    e = 10.0 ** np.floor(np.log10(limit))
    return float(next(m * e for m in (5, 2, 1) if m * e <= limit))


def _dot(n: int) -> float:
    """A scene point's marker area: a sparse scan's points must stay visible, a dense one's
    must not merge into a grey blot."""
    return float(np.clip(15_000 / max(n, 1), 0.8, 6.0))


def _outlined(ax: Any, text: str, xy: Sequence[float], colour: Any, size: float) -> None:
    import matplotlib.patheffects as pe

    t = ax.text(
        *xy, text, color=colour, fontsize=size, weight="bold", ha="center", va="bottom", zorder=10
    )
    t.set_path_effects([pe.withStroke(linewidth=2.5, foreground="white")])


def _top_view(ax: Axes, s: np.ndarray, copies: list[_Copy], missed: list[_Copy]) -> None:
    """From above: the scene, each copy's points with its footprint outlined and its number,
    and each missed true copy's footprint dashed."""
    ax.scatter(s[:, 0], s[:, 1], color=SCENE_GREY, s=_dot(len(s)), linewidths=0, rasterized=True)
    for k, c in enumerate(copies):
        ax.scatter(c.points[:, 0], c.points[:, 1], color=c.colour, s=1.5, linewidths=0)
        ring = _hull(c.points[:, :2])
        ax.plot(ring[:, 0], ring[:, 1], color=0.7 * c.colour, lw=1.4)
        _outlined(ax, str(k), (ring[:, 0].mean(), ring[:, 1].max()), 0.7 * c.colour, 11)
    for m in missed:
        ring = _hull(m.points[:, :2])
        ax.plot(ring[:, 0], ring[:, 1], color=MISSED, lw=1.4, ls="--", gid="missed")
    everything = np.concatenate([s[:, :2], *[c.points[:, :2] for c in copies + missed]])
    lo, hi = everything.min(0), everything.max(0)
    bar = _nice_length((hi - lo)[0] / 4)
    if bar > 0:
        y = lo[1] - 0.04 * (hi - lo).max()
        ax.plot([lo[0], lo[0] + bar], [y, y], color="k", lw=2)
        ax.text(lo[0] + bar / 2, y, f"{bar:g}", ha="center", va="top", fontsize=8)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_axis_off()
    ax.set_title("top", fontsize=10)


def _oblique_view(ax: Any, s: np.ndarray, copies: list[_Copy], missed: list[_Copy]) -> None:
    """A three-quarter view: the scene, each copy's points and number, each missed true copy
    as hollow points, with equal aspect."""
    kw = {"depthshade": False, "linewidths": 0}
    ax.scatter(*s.T, color=SCENE_GREY, s=_dot(len(s)), rasterized=True, **kw)
    for k, c in enumerate(copies):
        ax.scatter(*c.points.T, color=c.colour, s=2.0, **kw)
        # Above the copy's highest point, so its own points do not hide the number.
        top = c.points[np.argmax(c.points[:, 2])] + [0, 0, 0.02 * np.ptp(s[:, 2])]
        _outlined(ax, str(k), top, 0.7 * c.colour, 10)
    for m in missed:
        hollow = m.points[:: max(1, len(m.points) // 300)]
        ax.scatter(
            *hollow.T, facecolors="none", edgecolors=MISSED, s=8, linewidths=0.5, gid="missed"
        )
    everything = np.concatenate([s, *[c.points for c in copies + missed]])
    lo, hi = everything.min(0), everything.max(0)
    span = np.maximum(hi - lo, 1e-9 * max(float((hi - lo).max()), 1e-12))
    ax.set_xlim(lo[0], lo[0] + span[0])
    ax.set_ylim(lo[1], lo[1] + span[1])
    ax.set_zlim(lo[2], lo[2] + span[2])
    # Equal aspect without wasting the picture on a flat scene's empty height.
    ax.set_box_aspect(span / span.max(), zoom=1.25)
    ax.view_init(elev=35.0, azim=-60.0)
    ax.set_axis_off()
    ax.set_title("oblique", fontsize=10)


def _key(fig: Figure, n_scene: int, copies: list[_Copy], missed: list[_Copy]) -> float:
    """The legend under both views: the scene, one entry per copy, the missed true copies.
    Returns the height of the figure it takes."""
    from matplotlib.lines import Line2D

    def dot(colour: Any, label: str) -> Line2D:
        return Line2D([], [], ls="", marker="o", ms=7, color=colour, label=label)

    handles = [dot(SCENE_GREY, f"scene ({n_scene} points)")]
    handles += [dot(c.colour, c.label) for c in copies]
    if missed:
        handles.append(
            Line2D([], [], color=MISSED, ls="--", marker="o", mfc="none", label=missed[0].label)
        )
    ncol = min(3, len(handles))
    fig.legend(handles=handles, loc="lower center", ncol=ncol, frameon=False, fontsize=9)
    return 0.03 + 0.035 * int(np.ceil(len(handles) / ncol))


def _summary(n_found: int, n_missed: int, n_true: int | None) -> str:
    if n_found == 0:
        text = "no copy found"
    else:
        text = f"{n_found} {'copy' if n_found == 1 else 'copies'} found"
    if n_true is not None:
        text += f"; {n_true - n_missed} of {n_true} true copies matched"
    return text


def _no_copy(fig: Figure, reason: str | None) -> None:
    """Across both views: the result is empty, and why when the caller knows."""
    red = (0.7, 0.0, 0.0)
    box = {"facecolor": "white", "edgecolor": red, "alpha": 0.9, "pad": 8}
    fig.text(
        0.5,
        0.58,
        "no copy found",
        ha="center",
        va="bottom",
        fontsize=22,
        color=red,
        weight="bold",
        bbox=box,
        gid="no copy found",
    )
    if reason:
        fig.text(
            0.5,
            0.54,
            reason,
            ha="center",
            va="top",
            fontsize=12,
            color=red,
            wrap=True,
            bbox={**box, "pad": 5},
            gid="reason",
        )


def _new_figure() -> Figure:
    """A figure not managed by pyplot: no GUI backend, no global state, nothing to close."""
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise ImportError("the PNG needs matplotlib: pip install 'pointclm[viz]'") from None
    return Figure(figsize=(13, 6.5), dpi=110)


def draw_registration(
    scene: ArrayLike,
    model: ArrayLike,
    poses: ArrayLike,
    radius: float,
    title: str = "",
    *,
    fitness: ArrayLike | None = None,
    confidence: ArrayLike | None = None,
    ground_truth: ArrayLike | None = None,
    reason: str | None = None,
) -> Figure:
    """The picture of a result as a matplotlib figure: top and oblique views side by side.

    `scene` (N, 3) and `model` (M, 3) are the clouds, `poses` (K, 4, 4) the copies found
    (T_target_source). `fitness` and `confidence` (one per pose) go in the key; without
    `fitness`, the share of each placed model's points within `radius` of the scene.
    `ground_truth` (G, 4, 4): the true poses; those no found pose matches (rotation under 15
    degrees, translation under a tenth of the model's diagonal) are drawn hollow and dashed.
    `reason`: why nothing was found, shown when no pose is given.
    """
    fig = _new_figure()
    scene_pts = np.asarray(scene, dtype=np.float64).reshape(-1, 3)
    model_pts = np.asarray(model, dtype=np.float64).reshape(-1, 3)
    pose_arr = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    frame = _frame(scene_pts)
    copies = _copies(scene_pts, model_pts, pose_arr, radius, fitness, confidence, frame)
    missed, n_true = (
        ([], None) if ground_truth is None else _missed(model_pts, pose_arr, ground_truth, frame)
    )
    s = (scene_pts[:: max(1, len(scene_pts) // MAX_SCENE_POINTS)] - frame[0]) @ frame[1].T
    bottom = _key(fig, len(scene_pts), copies, missed)
    top = 0.86 if title else 0.9
    fig.subplots_adjust(left=0.01, right=0.99, top=top, bottom=bottom, wspace=0.02)
    _top_view(fig.add_subplot(1, 2, 1), s, copies, missed)
    # Drawn in call order, not sorted by depth: mplot3d sorts whole collections, which put the
    # scene over the copies and hid their numbers.
    _oblique_view(
        fig.add_subplot(1, 2, 2, projection="3d", computed_zorder=False), s, copies, missed
    )
    summary = _summary(len(copies), len(missed), n_true)
    fig.suptitle(f"{title}\n{summary}" if title else summary, fontsize=13)
    if not copies:
        _no_copy(fig, reason)
    return fig


def save_png(
    path: str | os.PathLike[str],
    scene: np.ndarray,
    model: np.ndarray,
    poses: np.ndarray,
    radius: float,
    title: str = "",
    *,
    fitness: ArrayLike | None = None,
    confidence: ArrayLike | None = None,
    ground_truth: ArrayLike | None = None,
    reason: str | None = None,
) -> None:
    """Save :func:`draw_registration`'s picture of a result to `path` (a PNG)."""
    fig = draw_registration(
        scene,
        model,
        poses,
        radius,
        title,
        fitness=fitness,
        confidence=confidence,
        ground_truth=ground_truth,
        reason=reason,
    )
    fig.savefig(path, format="png")


def _empty_reason(reg: Any) -> str | None:
    """Why a point-cloud registration found nothing, from what it carries."""
    given = getattr(reg, "diagnosis", None)
    if given:
        return str(given)
    proposed = len(reg.result) if getattr(reg, "result", None) is not None else 0
    if proposed:
        poses = "pose" if proposed == 1 else f"{proposed} poses"
        return f"the matches proposed {poses}; the scan supported none after refinement"
    return f"no consistent group among {len(reg.correspondences)} correspondences"


def save_registration_png(
    path: str | os.PathLike[str],
    reg: Any,
    *,
    ground_truth: ArrayLike | None = None,
    title: str = "",
) -> None:
    """Save the picture of a :class:`pointclm.PointCloudRegistration` (its downsampled
    clouds, every copy with its fitness and confidence, why nothing was found if so)."""
    insts = reg.instances
    save_png(
        path,
        reg.target_points,
        reg.source_points,
        reg.transformations,
        1.5 * reg.voxel_size,
        title,
        fitness=[i.fitness for i in insts],
        confidence=[i.confidence for i in insts],
        ground_truth=ground_truth,
        reason=None if insts else _empty_reason(reg),
    )

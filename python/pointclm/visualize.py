"""Pictures of a result: each instance found in its own colour, the rest of the scene grey.

The PLY (any viewer) needs nothing beyond numpy; the PNG needs matplotlib
(``pip install 'pointclm[viz]'``).
"""

from __future__ import annotations

import os

import numpy as np

from ._core import nearest_neighbours

__all__ = ["colour_scene", "palette", "save_png", "save_ply"]

GREY = np.array([0.6, 0.6, 0.6])


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


def _view(points: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Rotate so the scene's thinnest principal axis (the floor's normal, for a tabletop) is
    up, and return matplotlib's elevation and azimuth for a three-quarter view."""
    centred = points - points.mean(0)
    _, _, vt = np.linalg.svd(centred[:: max(1, len(points) // 20000)], full_matrices=False)
    rot = vt[[0, 1, 2]]
    if np.linalg.det(rot) < 0:
        rot[2] *= -1
    return rot, 35.0, -60.0


def save_png(
    path: str | os.PathLike[str],
    scene: np.ndarray,
    model: np.ndarray,
    poses: np.ndarray,
    radius: float,
    title: str = "",
) -> None:
    """A three-quarter view of the scene with the instances in colour."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise ImportError("the PNG needs matplotlib: pip install 'pointclm[viz]'") from None
    colours, cols, placed = colour_scene(scene, model, poses, radius)
    rot, elev, azim = _view(scene)
    centre = scene.mean(0)
    s = (scene - centre) @ rot.T
    fig = plt.figure(figsize=(8, 7), dpi=110)
    ax = fig.add_subplot(projection="3d")
    grey = (colours == GREY).all(1)
    ax.scatter(*s[grey].T, c=colours[grey], s=0.6, depthshade=False, linewidths=0)
    ax.scatter(*s[~grey].T, c=colours[~grey], s=1.5, depthshade=False, linewidths=0)
    for c, m in zip(cols, placed, strict=True):
        mm = (m - centre) @ rot.T
        ax.scatter(*mm[::4].T, color=0.6 * c, s=0.5, depthshade=False, linewidths=0)
    lo, hi = s.min(0), s.max(0)
    mid, half = (lo + hi) / 2, (hi - lo).max() / 2
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(mid[2] - half, mid[2] + half)
    ax.view_init(elev=elev, azim=azim)
    ax.set_axis_off()
    ax.set_title(title or f"{len(poses)} instance(s) found")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)

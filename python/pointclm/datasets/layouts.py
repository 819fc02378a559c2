"""Where the copies stand in a sensed scene: a few in a room, a loose pile in a bin, packed
grids and rows of touching copies, copies leaning on the bin's walls.

Each layout returns the copies' poses (world frame, z up, floor at z = 0), which product each
copy is, the flat surfaces around them (floor, bin walls and rims, kept in the scan), any
clutter, and where a camera should look from. Copies never interpenetrate: rooms keep
footprints apart, grids and rows place bounding boxes side by side with gaps of 0-1 mm, piles
drop copies on a height field of the pile (as :mod:`pointclm.datasets.bins` does), leaning
copies touch the floor and their wall.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bins import _HeightField, _random_rotations
from .cameras import Rectangle
from .parts import Part
from .scene_sensing import _rot_z

__all__ = ["CLUTTER", "FLOOR", "LAYOUTS", "WALL", "Layout", "make_layout"]

#: Owner labels of scan points on no copy.
CLUTTER, FLOOR, WALL = -1, -2, -3

#: The layouts; every one but ``room`` is in a bin whose walls and floor stay in the scan.
LAYOUTS: tuple[str, ...] = ("room", "pile", "grid", "row", "lean")


@dataclass(frozen=True)
class Layout:
    """Copies' poses (K, 4, 4, world from part), product index per copy, surfaces, clutter
    (world samples, normals, albedo), the point the camera looks at and its direction."""

    poses: np.ndarray
    product: np.ndarray
    rects: list[Rectangle]
    clutter: list[tuple[np.ndarray, np.ndarray, float]]
    target: np.ndarray
    direction: np.ndarray


def _pose(rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = rot, trans
    return t


def _rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def _bounds(part: Part, rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v = part.vertices @ rot.T
    return v.min(0), v.max(0)


def _bin_size(parts: list[Part]) -> tuple[float, float, float]:
    e = max(float(p.extent.max()) for p in parts)
    return max(0.4, 2.6 * e), max(0.3, 1.8 * e), 0.2


def _bin_rects(size: tuple[float, float, float], t: float = 0.01) -> list[Rectangle]:
    """Floor, inner and outer walls and rims of a bin centred on the origin, and the table."""
    length, width, height = size
    ex, ey, ez = np.eye(3)
    rects = [
        Rectangle(np.zeros(3), ex * length / 2, ey * width / 2, FLOOR, 0.3),
        Rectangle(np.array([0, 0, -0.003]), ex * 2.0, ey * 2.0, FLOOR, 0.4),
    ]
    for axis, half, side in ((0, length / 2, width / 2 + t), (1, width / 2, length / 2 + t)):
        n = np.eye(3)[axis]
        along = np.eye(3)[1 - axis]
        for sign in (-1.0, 1.0):
            for off in (0.0, t):
                c = sign * (half + off) * n + ez * height / 2
                rects.append(Rectangle(c, along * side, ez * height / 2, WALL, 0.25))
            rim = sign * (half + t / 2) * n + ez * height
            rects.append(Rectangle(rim, n * t / 2, along * side, WALL, 0.25))
    return rects


def _from_above(rng: np.random.Generator, max_tilt_deg: float = 15.0) -> np.ndarray:
    tilt = np.deg2rad(rng.uniform(0, max_tilt_deg))
    az = rng.uniform(0, 2 * np.pi)
    return np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])


def _counts(rng: np.random.Generator, n_products: int, copies: tuple[int, int]) -> list[int]:
    return [int(rng.integers(copies[0], copies[1] + 1)) for _ in range(n_products)]


def _room(
    rng: np.random.Generator, parts: list[Part], counts: list[int], clutter: list[Part]
) -> tuple[Layout, list[tuple[Part, np.ndarray]]]:
    """Copies upright at random yaws on a table, footprints apart, with clutter among them."""
    items = [(k, p) for k, (p, c) in enumerate(zip(parts, counts, strict=True)) for _ in range(c)]
    items += [(-1, p) for p in clutter]
    radii = [
        0.5 * float(np.linalg.norm(np.ptp(p.vertices @ p.rest.T, 0)[:2])) + 0.005 for _, p in items
    ]
    side = 2.2 * np.sqrt(len(items)) * max(radii)
    centres: list[np.ndarray] = []
    for r in radii:
        for _ in range(500):
            c = rng.uniform(-side / 2, side / 2, size=2)
            if all(
                np.linalg.norm(c - c2) >= r + r2 for c2, r2 in zip(centres, radii, strict=False)
            ):
                break
            side *= 1.01
        centres.append(c)
    poses, product, groups = [], [], []
    for (k, part), c in zip(items, centres, strict=True):
        rot = _rot_z(rng.uniform(0, 2 * np.pi)) @ part.rest
        lo, hi = _bounds(part, rot)
        t = np.array([c[0], c[1], 0.0]) - np.array(
            [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]]
        )
        if k >= 0:
            poses.append(_pose(rot, t))
            product.append(k)
        else:
            groups.append((part, _pose(rot, t)))
    ex, ey = np.eye(3)[:2]
    # A table top around the group (a scan cropped to the table, as a user would).
    c_all = np.array(centres)
    mid = (c_all.max(0) + c_all.min(0)) / 2
    half = (c_all.max(0) - c_all.min(0)) / 2 + max(radii) + 0.5 * max(p.diameter for p in parts)
    rects = [Rectangle(np.array([*mid, 0.0]), ex * half[0], ey * half[1], FLOOR, 0.4)]
    el, az = np.deg2rad(rng.uniform(35, 65)), rng.uniform(0, 2 * np.pi)
    direction = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    group = np.mean(centres[: len(poses)], axis=0)
    height = max(float(p.extent.max()) for p in parts) / 3
    return Layout(
        np.array(poses), np.array(product), rects, [], np.array([*group, height]), direction
    ), groups


def _pile(
    rng: np.random.Generator, parts: list[Part], counts: list[int], size: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Copies of every product poured in random order over the bin's middle, each trying four
    orientations and sliding downhill on the pile's height field (the bin scenes' heap)."""
    length, width, _ = size
    cell = min(p.diameter for p in parts) / 40
    field = _HeightField(length, width, cell)
    half = np.array([length / 2, width / 2])
    order = rng.permutation(np.repeat(np.arange(len(parts)), counts))
    dense = [p.vertices if len(p.vertices) > 200 else _corners_and_faces(p) for p in parts]
    poses, product = [], []
    for k in order:
        part, local = parts[k], dense[k]
        coarse = local[rng.choice(len(local), size=min(len(local), 800), replace=False)]
        steps = (
            part.diameter / 4 * np.array([[np.cos(a), np.sin(a)] for a in np.arange(8) * np.pi / 4])
        )
        drop = rng.normal(scale=np.array([length, width]) / 6)
        best = None
        for rot in _random_rotations(rng, 4):
            p = coarse @ rot.T
            flat = local @ rot[:2].T
            lo, hi = -half - flat.min(0), half - flat.max(0)
            xy = np.clip(drop, lo, np.maximum(lo, hi))
            z = field.rest_height(p + np.array([xy[0], xy[1], 0.0]))[0]
            for _ in range(4):
                moves = [np.clip(xy + s, lo, np.maximum(lo, hi)) for s in steps]
                heights = [field.rest_height(p + np.array([m[0], m[1], 0.0]))[0] for m in moves]
                j = int(np.argmin(heights))
                if heights[j] >= z - 1e-3 * part.diameter:
                    break
                xy, z = moves[j], heights[j]
            if best is None or z < best[0]:
                best = (z, rot, xy)
        assert best is not None
        _, rot, xy = best
        placed = local @ rot.T + np.array([xy[0], xy[1], 0.0])
        lift, cells = field.rest_height(placed)
        placed[:, 2] += lift
        field.add(placed, cells)
        poses.append(_pose(rot, np.array([xy[0], xy[1], lift])))
        product.append(k)
    return np.array(poses), np.array(product)


def _corners_and_faces(part: Part) -> np.ndarray:
    """Enough points on a few-triangle part for the height field (samples of its faces)."""
    from .parts import surface_samples

    return surface_samples(part, 3000, 1)[0]


def _packed(
    rng: np.random.Generator,
    parts: list[Part],
    counts: list[int],
    size: tuple[float, float, float],
    rows: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Copies side by side in their resting orientation (grid) or standing on edge (row),
    bounding boxes 0-1 mm apart, each product a block of rows from one corner of the bin."""
    length, width, _ = size
    # Row: shortest side along the row, longest across it, middle side up (books on a shelf).
    edge = np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]])
    poses, product = [], []
    y0 = -width / 2 + rng.uniform(0, 0.01)
    for k, (part, n) in enumerate(zip(parts, counts, strict=True)):
        base = (edge @ part.rest) if rows else part.rest
        lo, hi = _bounds(part, base)
        ext = hi - lo
        per_row = max(1, int((length - 0.01) // (ext[0] + 0.003)))
        x0 = -length / 2 + rng.uniform(0, max(0.0, length - per_row * (ext[0] + 0.003)) / 2)
        x, depth = x0, 0.0
        for i in range(n):
            if i and i % per_row == 0:
                y0 += depth + rng.uniform(0, 0.001)
                x, depth = x0, 0.0
            rot = _rot_z(np.deg2rad(rng.uniform(-1.0, 1.0))) @ base
            lo_r, hi_r = _bounds(part, rot)
            if y0 + (hi_r - lo_r)[1] > width / 2:
                break  # the bin is full
            poses.append(_pose(rot, np.array([x, y0, 0.0]) - lo_r))
            product.append(k)
            x += (hi_r - lo_r)[0] + rng.uniform(0, 0.001)
            depth = max(depth, float((hi_r - lo_r)[1]))
        y0 += depth + rng.uniform(0, 0.001)
    return np.array(poses), np.array(product)


def _lean(
    rng: np.random.Generator, parts: list[Part], counts: list[int], size: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Copies standing on end, tilted 10-30 degrees onto a bin wall, touching it and the floor."""
    length, width, _ = size
    # Longest side up, middle side along the wall, shortest towards it (a proper rotation).
    stand = np.array([[0.0, 0, 1], [0, -1, 0], [1, 0, 0]])
    walls = [
        (0.0, length / 2, width),
        (np.pi, length / 2, width),
        (np.pi / 2, width / 2, length),
        (-np.pi / 2, width / 2, length),
    ]
    used = {w: -walls[w][2] / 2 + 0.005 for w in range(4)}
    poses, product = [], []
    order = rng.permutation(np.repeat(np.arange(len(parts)), counts))
    for j, k in enumerate(order):
        part = parts[k]
        w = (j + int(rng.integers(2))) % 4
        angle, half, span = walls[w]
        rot = _rot_y(np.deg2rad(rng.uniform(10, 30))) @ stand @ part.rest
        lo, hi = _bounds(part, rot)
        if used[w] + (hi - lo)[1] > span / 2 - 0.005:
            continue
        local_t = np.array([half - hi[0], used[w] - lo[1], -lo[2]])
        used[w] += (hi - lo)[1] + rng.uniform(0.002, 0.02)
        turn = _rot_z(angle)
        poses.append(_pose(turn @ rot, turn @ local_t))
        product.append(k)
    return np.array(poses), np.array(product)


def make_layout(
    layout: str,
    rng: np.random.Generator,
    parts: list[Part],
    copies: tuple[int, int],
    clutter: list[Part] | None = None,
) -> tuple[Layout, list[tuple[Part, np.ndarray]]]:
    """The layout `layout` of :data:`LAYOUTS` with `copies` (lo, hi) copies of each product
    (`parts`); returns it and the clutter objects (part, pose), placed in rooms only."""
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}: use one of {list(LAYOUTS)}")
    counts = _counts(rng, len(parts), copies)
    if layout == "room":
        return _room(rng, parts, counts, clutter or [])
    size = _bin_size(parts)
    if layout == "pile":
        poses, product = _pile(rng, parts, counts, size)
    elif layout in ("grid", "row"):
        poses, product = _packed(rng, parts, counts, size, rows=layout == "row")
    else:
        poses, product = _lean(rng, parts, counts, size)
    rects = _bin_rects(size)
    return Layout(poses, product, rects, [], np.zeros(3), _from_above(rng)), []

"""The bin scene's depth sensor: a pinhole camera over the bin, the bin's own surfaces, the
z-buffered render of the heap, and the structured-light scan of that depth image.

Kept apart from :mod:`pointclm.datasets.bins`, which builds the heap and stores the scenes,
because this part only turns placed copies into what a sensor reports.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .bins import BinParams

#: Surface labels of scan points that lie on no copy.
FLOOR, WALL = -2, -3


@dataclass(frozen=True)
class _Camera:
    """A pinhole at (0, 0, height) looking down -z; image x along world x, image y along -y."""

    height: float
    focal: float
    cx: float
    cy: float
    width: int
    rows: int

    @classmethod
    def over_bin(cls, params: BinParams) -> _Camera:
        w, h = params.resolution
        length, width, _ = params.bin_size
        outer = np.array([length, width]) + 2 * params.wall_thickness
        focal = float(np.min(np.array([w, h]) * params.sensor_height / (1.02 * outer)))
        return cls(params.sensor_height, focal, w / 2, h / 2, w, h)

    @property
    def position(self) -> np.ndarray:
        return np.array([0.0, 0.0, self.height])

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Per pixel (rows x width), the ray's x and y slopes at the pixel centre."""
        u = (np.arange(self.width) + 0.5 - self.cx) / self.focal
        v = -(np.arange(self.rows) + 0.5 - self.cy) / self.focal
        return np.meshgrid(u, v)

    def project(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Depth (distance along -z) and the pixel index of each point (-1: off the image)."""
        depth = self.height - pts[:, 2]
        safe = np.where(depth > 1e-9, depth, np.inf)
        u = np.floor(self.focal * pts[:, 0] / safe + self.cx).astype(np.int64)
        v = np.floor(-self.focal * pts[:, 1] / safe + self.cy).astype(np.int64)
        ok = (depth > 1e-9) & (u >= 0) & (u < self.width) & (v >= 0) & (v < self.rows)
        return depth, np.where(ok, v * self.width + u, -1)


def _bin_depth(cam: _Camera, params: BinParams) -> tuple[np.ndarray, np.ndarray]:
    """The first bin surface along every pixel's ray (inf outside the rim) and its label."""
    sx, sy = cam.rays()
    length, width, wall = params.bin_size
    t = params.wall_thickness
    z_top = cam.height - wall
    xt, yt = sx * z_top, sy * z_top
    inside = (np.abs(xt) <= length / 2) & (np.abs(yt) <= width / 2)
    rim = ~inside & (np.abs(xt) <= length / 2 + t) & (np.abs(yt) <= width / 2 + t)
    with np.errstate(divide="ignore"):
        exit_x = np.where(sx != 0, (length / 2) / np.abs(sx), np.inf)
        exit_y = np.where(sy != 0, (width / 2) / np.abs(sy), np.inf)
    down = np.minimum(exit_x, exit_y)
    depth = np.full(sx.shape, np.inf)
    depth[inside] = np.minimum(cam.height, down[inside])
    depth[rim] = z_top
    label = np.where(inside & (down >= cam.height), FLOOR, WALL)
    return depth.ravel(), label.ravel()


#: Splat offsets (pixels): each sample covers 2 x 2 pixels so sparse spots do not leak.
_SPLAT = ((0, 0), (1, 0), (0, 1), (1, 1))


def _splat(cam: _Camera, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(depth, pixel) of every sample at every splat offset, off-image entries dropped."""
    depth = cam.height - pts[:, 2]
    safe = np.where(depth > 1e-9, depth, np.inf)
    fu = cam.focal * pts[:, 0] / safe + cam.cx - 0.5
    fv = -cam.focal * pts[:, 1] / safe + cam.cy - 0.5
    u0, v0 = np.floor(fu).astype(np.int64), np.floor(fv).astype(np.int64)
    ds, ps = [], []
    for du, dv in _SPLAT:
        u, v = u0 + du, v0 + dv
        ok = (depth > 1e-9) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.rows)
        ds.append(depth[ok])
        ps.append((v * cam.width + u)[ok])
    return np.concatenate(ds), np.concatenate(ps)


def _render(
    cam: _Camera, model: np.ndarray, poses: np.ndarray, params: BinParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Depth image, owner per pixel, and per copy its pixels in the heap and alone."""
    bin_depth, bin_label = _bin_depth(cam, params)
    n_pix = cam.width * cam.rows
    zbuf = bin_depth.copy()
    depths, pixels, owners = [], [], []
    alone = np.zeros(len(poses), dtype=np.int64)
    for k, pose in enumerate(poses):
        d, p = _splat(cam, model @ pose[:3, :3].T + pose[:3, 3])
        front = d < bin_depth[p]
        alone[k] = np.count_nonzero(np.bincount(p[front], minlength=n_pix))
        depths.append(d[front])
        pixels.append(p[front])
        owners.append(np.full(int(front.sum()), k))
    d = np.concatenate(depths)
    p = np.concatenate(pixels)
    o = np.concatenate(owners)
    np.minimum.at(zbuf, p, d)
    owner = bin_label.copy()
    win = d <= zbuf[p]
    owner[p[win]] = o[win]
    owner[~np.isfinite(zbuf)] = np.iinfo(np.int64).min
    seen = np.bincount(owner[owner >= 0], minlength=len(poses))[: len(poses)]
    assert n_pix == len(zbuf)
    return zbuf, owner, seen.astype(np.int64), alone


def _sense(
    cam: _Camera, zbuf: np.ndarray, owner: np.ndarray, params: BinParams, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """The structured-light scan of a depth image (module documentation, step 4)."""
    img = zbuf.reshape(cam.rows, cam.width)
    with np.errstate(invalid="ignore"):
        gy, gx = np.gradient(np.where(np.isfinite(img), img, np.nan))
        # Surface slope against the viewing direction: depth change per metre across.
        slope = np.hypot(gx, gy) * cam.focal / img
    angle = np.degrees(np.arctan(np.nan_to_num(slope, nan=np.inf))).ravel()
    lo, hi = params.grazing_deg
    p_drop = np.clip((angle - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    keep = np.isfinite(zbuf) & (rng.random(len(zbuf)) >= p_drop)
    z = zbuf[keep]
    z = z + rng.normal(size=len(z)) * params.noise_at_1m * z**2
    if params.disparity_step > 0:
        fb = cam.focal * params.baseline
        disparity = np.round(fb / z / params.disparity_step) * params.disparity_step
        z = fb / np.maximum(disparity, params.disparity_step)
    sx, sy = cam.rays()
    pts = np.column_stack([sx.ravel()[keep] * z, sy.ravel()[keep] * z, cam.height - z])
    ids = owner[keep].astype(np.int64)
    if params.crop_margin is not None:
        # The picking cell's region of interest: inside the walls, which it knows.
        half = np.array(params.bin_size[:2]) / 2 - params.crop_margin
        roi = np.all(np.abs(pts[:, :2]) < half, axis=1)
        pts, ids = pts[roi], ids[roi]
    return pts, ids

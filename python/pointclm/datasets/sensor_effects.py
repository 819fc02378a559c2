"""Depth sensor models: what a real sensor makes of the ideal depth frame.

Each effect follows how the sensor family measures depth:

- **Structured light** (an active stereo pair or a projector and a camera, baseline b):
  depth comes from a disparity ``f b / z`` found to a fraction of a pixel, so the noise grows
  as z^2 and depth is quantised in disparity steps; the projector does not light the strip
  beside a near edge (a shadow: no return), nor surfaces seen at grazing angles.
- **Time of flight**: noise roughly linear in depth; light bounced off a nearby surface
  lengthens the measured path (multipath: depth too far where the pixel sits in a concave
  corner, modelled as a share of how much deeper it is than its neighbourhood); a pixel
  straddling a depth edge averages both surfaces (a flying pixel between them).
- **Either**: dark surfaces seen obliquely from far return too little light (dropout with a
  probability rising as ``albedo * cos(incidence) / z^2`` falls), and the depth is stored as
  16-bit integers in units of 1/1000 or 1/8000 m (depths beyond 65535 units are lost).

:func:`sense` applies a :class:`SensorModel` to a :class:`pointclm.datasets.cameras.Rendered`
frame; :func:`frame_points` turns the depth into the organised (H, W, 3) frame of points in
the camera's frame, NaN where there is no return. Deterministic for a given generator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cameras import Camera, Rendered

__all__ = ["SENSORS", "SensorModel", "frame_points", "sense"]


@dataclass(frozen=True)
class SensorModel:
    """The effects of one sensor (lengths in metres; 0 turns an effect off).

    noise: ``"gaussian"`` (sigma ``sigma0``), ``"structured_light"`` (sigma ``sigma0 * z^2``,
    disparity steps of ``disparity_step`` px with baseline ``baseline``, shadows beside near
    edges) or ``"tof"`` (sigma ``sigma0 + sigma1 * z``, multipath share ``multipath``).
    grazing_deg: incidence angles over which returns fade out (linear from lo to hi).
    dark_level: ``albedo * cos / z^2`` below which returns start to fail (fully lost at a
    third of it). flying: probability that a pixel at a depth edge mixes both sides.
    depth_unit: metres per 16-bit unit (None: float depth). organised: whether the scan is
    handed over as the frame's valid pixels in order (True) or shuffled (an unorganised
    cloud).
    """

    noise: str = "gaussian"
    sigma0: float = 5e-4
    sigma1: float = 0.0
    baseline: float = 0.05
    disparity_step: float = 0.0
    shadows: bool = False
    multipath: float = 0.0
    grazing_deg: tuple[float, float] | None = None
    dark_level: float = 0.0
    flying: float = 0.0
    depth_unit: float | None = None
    organised: bool = True

    def __post_init__(self) -> None:
        if self.noise not in ("gaussian", "structured_light", "tof"):
            raise ValueError(f"noise must be gaussian, structured_light or tof, got {self.noise!r}")
        if min(self.sigma0, self.sigma1, self.multipath, self.flying, self.dark_level) < 0:
            raise ValueError("sensor noise levels and probabilities must be >= 0")
        if self.depth_unit is not None and not self.depth_unit > 0:
            raise ValueError(f"depth_unit must be positive or None, got {self.depth_unit}")


#: The matrix's sensors. Noise levels are those of common RGB-D cameras at 1 m (about 1 mm
#: for structured light, a few mm for time of flight).
SENSORS: dict[str, SensorModel] = {
    "gauss_0.5mm": SensorModel("gaussian", sigma0=5e-4),
    "structured_light": SensorModel(
        "structured_light",
        sigma0=1e-3,
        disparity_step=1 / 8,
        shadows=True,
        grazing_deg=(65.0, 85.0),
        dark_level=0.02,
        depth_unit=1e-3,
    ),
    "tof": SensorModel(
        "tof",
        sigma0=1.5e-3,
        sigma1=1.5e-3,
        multipath=0.25,
        grazing_deg=(70.0, 88.0),
        dark_level=0.03,
        flying=0.6,
        depth_unit=1 / 8000,
    ),
    "quantised_1mm": SensorModel("gaussian", sigma0=2e-4, depth_unit=1e-3),
    "flying_unorganised": SensorModel(
        "gaussian", sigma0=5e-4, flying=0.9, grazing_deg=(75.0, 89.0), organised=False
    ),
}


def _box_mean(a: np.ndarray, r: int) -> np.ndarray:
    """Mean over a (2r+1)^2 window of the finite values (NaN where none)."""
    ok = np.isfinite(a)
    v = np.where(ok, a, 0.0)
    pad_v = np.pad(v, r)
    pad_n = np.pad(ok.astype(np.float64), r)
    cs_v = pad_v.cumsum(0).cumsum(1)
    cs_n = pad_n.cumsum(0).cumsum(1)

    def window(cs: np.ndarray) -> np.ndarray:
        cs = np.pad(cs, ((1, 0), (1, 0)))
        k = 2 * r + 1
        return cs[k:, k:] - cs[:-k, k:] - cs[k:, :-k] + cs[:-k, :-k]

    n = window(cs_n)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, window(cs_v) / n, np.nan)


def _edge_neighbour(z: np.ndarray, jump: np.ndarray) -> np.ndarray:
    """Per pixel, the depth of a 4-neighbour across a depth edge (NaN where none): the
    neighbour whose depth differs most, when that exceeds `jump`."""
    best = np.full(z.shape, np.nan)
    gap = np.zeros(z.shape)
    zp = np.pad(z, 1, constant_values=np.nan)
    for dv, du in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        nb = zp[1 + dv : 1 + dv + z.shape[0], 1 + du : 1 + du + z.shape[1]]
        with np.errstate(invalid="ignore"):
            d = np.abs(nb - z)
            take = np.isfinite(d) & (d > jump) & (d > gap)
        best[take] = nb[take]
        gap[take] = d[take]
    return best


def _shadows(z: np.ndarray, focal: float, baseline: float) -> np.ndarray:
    """Pixels the projector (offset along the image's -u by `baseline`) cannot light: some
    pixel to their left is near enough to block the projector's ray."""
    shadow = np.zeros(z.shape, dtype=bool)
    fin = np.where(np.isfinite(z), z, np.inf)
    inv = np.where(np.isfinite(fin), 1.0 / fin, 0.0)
    widest = int(np.ceil(focal * baseline * float(inv.max() - inv[inv > 0].min(initial=1.0))))
    for k in range(1, min(widest, z.shape[1] - 1) + 1):
        near = np.full(z.shape, 0.0)
        near[:, k:] = inv[:, :-k]
        shadow |= focal * baseline * (near - inv) > k
    return shadow


def sense(
    frame: Rendered, cam: Camera, sensor: SensorModel, rng: np.random.Generator
) -> np.ndarray:
    """The measured depth (H, W), NaN where the sensor returns nothing (module docs)."""
    z = np.where(np.isfinite(frame.depth), frame.depth, np.nan)
    ideal = z.copy()
    h, w = z.shape
    lost = ~np.isfinite(z)
    rays = cam.rays()
    cos = np.abs(np.einsum("hwi,hwi->hw", frame.normal, rays)) / np.linalg.norm(rays, axis=-1)
    if sensor.grazing_deg is not None:
        lo, hi = sensor.grazing_deg
        angle = np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))
        lost |= rng.random((h, w)) < np.clip((angle - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    if sensor.dark_level > 0:
        with np.errstate(invalid="ignore", divide="ignore"):
            level = frame.albedo * cos / np.square(ideal)
            p = np.clip((sensor.dark_level - level) / (2 / 3 * sensor.dark_level), 0.0, 1.0)
        lost |= rng.random((h, w)) < np.nan_to_num(p, nan=1.0)
    if sensor.noise == "structured_light" and sensor.shadows:
        lost |= _shadows(ideal, cam.fx, sensor.baseline)
    if sensor.flying > 0:
        jump = np.maximum(0.01, 0.03 * np.nan_to_num(ideal, nan=np.inf))
        other = _edge_neighbour(ideal, jump)
        fly = np.isfinite(other) & (rng.random((h, w)) < sensor.flying)
        mix = rng.uniform(0.15, 0.85, size=(h, w))
        z = np.where(fly, z + mix * (other - z), z)
    if sensor.noise == "gaussian":
        z = z + rng.normal(scale=sensor.sigma0, size=(h, w))
    elif sensor.noise == "structured_light":
        z = z + rng.normal(size=(h, w)) * sensor.sigma0 * np.square(z)
        if sensor.disparity_step > 0:
            fb = cam.fx * sensor.baseline
            step = sensor.disparity_step
            with np.errstate(invalid="ignore", divide="ignore"):
                z = fb / np.maximum(np.round(fb / z / step) * step, step)
    else:
        if sensor.multipath > 0:
            deeper = np.clip(ideal - _box_mean(ideal, 3), 0.0, None)
            z = z + sensor.multipath * np.nan_to_num(deeper)
        z = z + rng.normal(size=(h, w)) * (sensor.sigma0 + sensor.sigma1 * z)
    if sensor.depth_unit is not None:
        units = np.round(z / sensor.depth_unit)
        lost |= units > 65535
        z = units * sensor.depth_unit
    lost |= ~(z > 0)
    return np.where(lost, np.nan, z)


def frame_points(depth: np.ndarray, cam: Camera) -> np.ndarray:
    """The organised frame (H, W, 3): each pixel's point in the camera frame, NaN where the
    depth is missing."""
    return cam.rays() * depth[..., None]

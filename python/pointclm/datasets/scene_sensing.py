"""Staging and sensing for realistic scenes: the rigid-motion helpers, the real bunny range
scans, and the virtual range sensor that places the instances, clutter and floor and keeps
what it sees.

Kept apart from :mod:`pointclm.datasets.scenes`, which chooses the models and layout and
matches descriptors, because this part is the scene's physics: it reads no descriptor and
draws from the caller's generator in the order the caller fixes.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .scenes import SceneParams

#: Real range scans of the bunny with their registration to the reconstruction's frame.
_BUNNY_SCANS = ("bun000.ply", "bun045.ply", "bun090.ply", "bun315.ply")
_BUNNY_SCAN_DIR = "stanford/bunny/data"


def _up_rotation(up: str) -> np.ndarray:
    """Rotation taking the model's up axis to +z."""
    if up == "y":
        return np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    if up == "x":
        return np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]])
    if up == "-z":
        return np.diag([1.0, -1, -1])
    return np.eye(3)


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _small_tilt(rng: np.random.Generator, max_deg: float) -> np.ndarray:
    """A rotation by at most `max_deg` about a random horizontal axis (Rodrigues)."""
    ang = np.deg2rad(rng.uniform(0, max_deg))
    phi = rng.uniform(0, 2 * np.pi)
    k = np.array([np.cos(phi), np.sin(phi), 0.0])
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(ang) * kx + (1 - np.cos(ang)) * kx @ kx


def _pose(rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = rot, trans
    return t


def _apply(t: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ t[:3, :3].T + t[:3, 3]


def _scan_frame(folder: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of the Stanford bunny range scan `name` in `folder`: ``bun.conf`` stores, per
    scan, a translation and a quaternion (x, y, z, w) with ``p_model = R^T p_scan + t``
    (checked in the data's SOURCES.md)."""
    for line in (folder / "bun.conf").read_text().splitlines():
        parts = line.split()
        if parts[:2] == ["bmesh", name]:
            tx, ty, tz, qx, qy, qz, qw = (float(v) for v in parts[2:9])
            return _quat_to_matrix(qx, qy, qz, qw), np.array([tx, ty, tz])
    raise KeyError(f"{name} is not in {folder / 'bun.conf'}")


def bunny_scan_pose(folder: str | Path, name: str) -> np.ndarray:
    """T_scan_model (4 x 4) of the Stanford bunny range scan `name` in `folder` (the folder
    of ``bun.conf``): ``p_scan = R (p_model - t)``."""
    rot, shift = _scan_frame(Path(folder), name)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rot, -rot @ shift
    return pose


@lru_cache(maxsize=1)
def _bunny_scans(data_dir: str) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """Each real scan in the reconstruction's frame (:func:`_scan_frame`), with its scanner
    direction there: the scanner looked along the scan frame's -z, so it sat towards
    ``R^T (0, 0, 1)``."""
    from ..io import load_points

    folder = Path(data_dir) / _BUNNY_SCAN_DIR
    out = []
    for name in _BUNNY_SCANS:
        r, t = _scan_frame(folder, name)
        pts = load_points(folder / name) @ r + t  # R^T p as rows
        out.append((pts, r.T @ np.array([0.0, 0.0, 1.0])))
    return tuple(out)


def _quat_to_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    n = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


# --- sensing ------------------------------------------------------------------------------


def _visible(points: np.ndarray, eye: np.ndarray, centre: np.ndarray, pixel: float) -> np.ndarray:
    """Mask of the points a pinhole range sensor at `eye` sees (z-buffer with a tolerance).

    Pixels subtend `pixel` radians; a point is kept when its depth is within one pixel's
    footprint of the nearest depth in its pixel (so a surface is not culled by its own
    sampling jitter, while anything behind it is).
    """
    fwd = centre - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    rel = points - eye
    depth = rel @ fwd
    ok = depth > 1e-9
    u = np.floor((rel @ right) / np.where(ok, depth, 1) / pixel).astype(np.int64)
    v = np.floor((rel @ up) / np.where(ok, depth, 1) / pixel).astype(np.int64)
    key = (u - u.min()) * (v.max() - v.min() + 1) + (v - v.min())
    key = np.where(ok, key, -1)
    zmin = np.full(key.max() + 2, np.inf)
    np.minimum.at(zmin, key[ok], depth[ok])
    tol = 2.0 * pixel * depth
    return ok & (depth <= zmin[key] + tol)


@dataclass(frozen=True)
class _Model:
    """The model's dense samples and the quantities every stage derives from them."""

    points: np.ndarray  # dense samples in the model's own frame
    diameter: float  # bounding-box diagonal
    voxel: float
    up_rot: np.ndarray  # rotation taking the model's up axis to +z
    base: np.ndarray  # upright footprint centre (x, y) and lowest z
    radius: float  # upright footprint radius


@dataclass(frozen=True)
class _Layout:
    """Where things stand on the floor: instances first, then clutter."""

    n_instances: int
    clutter: list[tuple[np.ndarray, float]]  # upright, scaled clutter points and radius
    radii: list[float]
    centres: list[np.ndarray]


@dataclass(frozen=True)
class _Sensor:
    eye: np.ndarray
    look: np.ndarray
    group: np.ndarray  # centre of the layout on the floor
    extent: float  # the layout's radius around `group`
    dist: float


@dataclass(frozen=True)
class _Scan:
    """What the sensor saw, with each point's owner (instance k, -1 clutter, -2 floor)."""

    cloud: np.ndarray
    owner: np.ndarray
    poses: np.ndarray
    real: np.ndarray


def _aim_sensor(
    rng: np.random.Generator, params: SceneParams, model: _Model, layout: _Layout
) -> _Sensor:
    """The sensor above the group at 25-60 degrees elevation, far enough to see all of it."""
    group = np.array([*np.mean(layout.centres, axis=0), 0.0])
    extent = max(
        float(
            np.max(
                [
                    np.linalg.norm(c - group[:2]) + r
                    for c, r in zip(layout.centres, layout.radii, strict=True)
                ]
            )
        ),
        model.radius,
    )
    az = rng.uniform(0, 2 * np.pi)
    el = np.deg2rad(rng.uniform(*params.elevation_deg))
    dist = 2.5 * extent + model.diameter
    eye = group + dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    look = group + np.array([0, 0, 0.3 * model.diameter])
    return _Sensor(eye, look, group, extent, dist)


def _sense(
    rng: np.random.Generator,
    params: SceneParams,
    model: _Model,
    layout: _Layout,
    sensor: _Sensor,
    dd: str | None,
) -> _Scan:
    """Stage 2: place instances, clutter and floor, keep what the sensor sees, add noise."""
    scans = None
    if params.model == "stanford/bunny" and dd is not None and params.real_scan_fraction > 0:
        scans = _bunny_scans(dd)
    parts: list[np.ndarray] = []
    ids: list[np.ndarray] = []
    poses = np.zeros((layout.n_instances, 4, 4))
    real = np.zeros(layout.n_instances, dtype=bool)
    for k in range(layout.n_instances):
        poses[k], pts_model, real[k] = _place_instance(
            rng, params, model, layout.centres[k], sensor.eye, scans
        )
        parts.append(_apply(poses[k], pts_model))
        ids.append(np.full(len(pts_model), k))
    for (pts, _), c in zip(layout.clutter, layout.centres[layout.n_instances :], strict=True):
        yaw = rng.uniform(0, 2 * np.pi)
        placed = pts @ (_small_tilt(rng, params.max_tilt_deg) @ _rot_z(yaw)).T
        placed[:, :2] += c
        placed[:, 2] -= placed[:, 2].min()
        parts.append(placed)
        ids.append(np.full(len(placed), -1))
    floor = _floor(rng, model, layout, sensor)
    parts.append(floor)
    ids.append(np.full(len(floor), -2))
    cloud = np.concatenate(parts)
    owner = np.concatenate(ids)
    seen = _visible(cloud, sensor.eye, sensor.look, 0.7 * model.voxel / sensor.dist)
    cloud, owner = cloud[seen], owner[seen]
    cloud = cloud + rng.normal(scale=params.noise_voxels * model.voxel, size=cloud.shape)
    return _Scan(cloud, owner, poses, real)


def _place_instance(
    rng: np.random.Generator,
    params: SceneParams,
    model: _Model,
    centre: np.ndarray,
    eye: np.ndarray,
    scans: tuple[tuple[np.ndarray, np.ndarray], ...] | None,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """One instance's pose (tilted, turned, standing on the floor at `centre`), the points
    it shows (the dense model, or a real range scan), and whether they are a real scan."""
    tilt = _small_tilt(rng, params.max_tilt_deg)
    use_scan = scans is not None and rng.random() < params.real_scan_fraction
    if use_scan:
        assert scans is not None
        pts_model, view = scans[int(rng.integers(len(scans)))]
        # Turn the instance so the scanner's direction points at our sensor (+-20 deg).
        d = model.up_rot @ view
        to_eye = eye[:2] - centre
        yaw = np.arctan2(to_eye[1], to_eye[0]) - np.arctan2(d[1], d[0])
        yaw += np.deg2rad(rng.uniform(-20, 20))
    else:
        pts_model, yaw = model.points, rng.uniform(0, 2 * np.pi)
    rot = tilt @ _rot_z(yaw) @ model.up_rot
    placed = model.points @ rot.T
    lift = -placed[:, 2].min()
    shift = np.array([*centre, 0.0]) - (tilt @ _rot_z(yaw) @ np.array([*model.base[:2], 0.0]))
    shift[2] = lift
    return _pose(rot, shift), pts_model, bool(use_scan)


def _floor(rng: np.random.Generator, model: _Model, layout: _Layout, sensor: _Sensor) -> np.ndarray:
    """The floor patch under and around the objects (as left by cropping a scan to a table
    or a bin), sampled at a third of a voxel."""
    margin = 0.25 * model.diameter
    flo = sensor.group[:2] - sensor.extent - margin
    fhi = sensor.group[:2] + sensor.extent + margin
    n_floor = int(np.prod((fhi - flo) / (model.voxel / 3)))
    fxy = rng.uniform(flo, fhi, size=(n_floor, 2))
    reach = np.zeros(n_floor, dtype=bool)
    for c, r in zip(layout.centres, layout.radii, strict=True):
        reach |= np.linalg.norm(fxy - c, axis=1) < r + margin
    fxy = fxy[reach]
    return np.column_stack([fxy, np.zeros(len(fxy))])

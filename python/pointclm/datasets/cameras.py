"""Pinhole depth cameras and the depth renderer the sensed scenes share.

A :class:`Camera` is a pinhole (OpenCV convention: x right, y down, z along the optical
axis) with its intrinsics and its pose in the world. :func:`render` casts every pixel's ray
at the scene: surfaces given as dense samples with normals (the parts; each sample covers
2 x 2 pixels, its depth taken where the pixel's ray meets the sample's tangent plane, so a
slanted face is not stepped) and flat rectangles cast exactly (floor, bin walls). It returns
the ideal depth image (z along the optical axis), who owns each pixel, the surface normal
and albedo there: what a sensor model (:mod:`pointclm.datasets.sensor_effects`) turns into
a measured frame.

Kept apart from the older bin and room sensors (:mod:`pointclm.datasets.bin_sensing`,
:mod:`pointclm.datasets.scene_sensing`), whose scenes the benchmarks already fix: this one
takes any intrinsics, any pose and any distance, which the validation matrix varies.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = ["CAMERAS", "NO_RETURN", "Camera", "Rectangle", "Rendered", "look_at", "render"]

#: Owner of a pixel whose ray meets nothing.
NO_RETURN = -9


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: image size, focal lengths and principal point in pixels, the
    distance it is placed at from what it looks at (metres), and its pose (4 x 4,
    world from camera; identity until :func:`look_at` places it)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distance: float = 1.0
    pose: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.width < 8 or self.height < 8:
            raise ValueError(
                f"image must be at least 8 x 8 pixels, got {self.width} x {self.height}"
            )
        if not (self.fx > 0 and self.fy > 0 and self.distance > 0):
            raise ValueError("fx, fy and distance must be positive")

    @property
    def world_from_camera(self) -> np.ndarray:
        return np.eye(4) if self.pose is None else self.pose

    @property
    def fov_deg(self) -> tuple[float, float]:
        """Horizontal and vertical field of view."""
        return (
            float(np.degrees(2 * np.arctan(self.width / (2 * self.fx)))),
            float(np.degrees(2 * np.arctan(self.height / (2 * self.fy)))),
        )

    def rays(self) -> np.ndarray:
        """(H, W, 3) ray through each pixel centre in the camera frame, scaled to z = 1."""
        u = (np.arange(self.width) + 0.5 - self.cx) / self.fx
        v = (np.arange(self.height) + 0.5 - self.cy) / self.fy
        uu, vv = np.meshgrid(u, v)
        return np.stack([uu, vv, np.ones_like(uu)], axis=-1)

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points in the camera frame."""
        t = np.linalg.inv(self.world_from_camera)
        return points @ t[:3, :3].T + t[:3, 3]


#: The matrix's cameras. Field of view from about 30 to 90 degrees, principal point centred
#: or far off centre, 0.35 to 2 m from what they look at. ``narrow_far`` is a rendered
#: camera of a user's report (1152 px focal length on a 506 x 474 image, principal point
#: at u = 139, 1.5 m above a heap).
CAMERAS: dict[str, Camera] = {
    "rgbd_0.6m": Camera(640, 480, 525.0, 525.0, 319.5, 239.5, 0.6),
    "wide_0.35m": Camera(848, 480, 425.0, 425.0, 424.0, 240.0, 0.35),
    "narrow_far": Camera(506, 474, 1152.0, 1152.0, 139.0, 237.0, 1.5),
    "offcentre_1m": Camera(640, 480, 600.0, 600.0, 420.0, 170.0, 1.0),
    "far_2m": Camera(960, 720, 900.0, 900.0, 480.0, 360.0, 2.0),
}


def _align(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector `a` to unit vector `b`."""
    v = np.cross(a, b)
    c = float(a @ b)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1 + c)


def look_at(camera: Camera, target: np.ndarray, direction: np.ndarray) -> Camera:
    """`camera` placed at ``target + distance * direction`` (world z up), its image centre
    aimed at `target` (so an off-centre principal point tilts the optical axis, as when a
    user centres the object in the picture), image rows running down the world's z."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    eye = np.asarray(target, dtype=np.float64) + camera.distance * d
    fwd = -d
    up = np.array([0.0, 0.0, 1.0]) if abs(fwd[2]) < 0.99 else np.array([0.0, 1.0, 0.0])
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    r0 = np.column_stack([right, down, fwd])  # camera axes in the world
    centre_ray = np.array(
        [
            (camera.width / 2 - camera.cx) / camera.fx,
            (camera.height / 2 - camera.cy) / camera.fy,
            1.0,
        ]
    )
    q = _align(centre_ray / np.linalg.norm(centre_ray), np.array([0.0, 0.0, 1.0]))
    pose = np.eye(4)
    pose[:3, :3] = r0 @ q
    pose[:3, 3] = eye
    return replace(camera, pose=pose)


@dataclass(frozen=True)
class Rectangle:
    """A flat rectangle (world frame): centre, two half-side vectors, owner label, albedo."""

    centre: np.ndarray
    half_u: np.ndarray
    half_v: np.ndarray
    owner: int
    albedo: float = 0.3


@dataclass(frozen=True)
class Rendered:
    """The ideal depth frame: depth (H, W; inf where nothing), owner (H, W), unit normals
    (H, W, 3, camera frame, facing the camera) and albedo (H, W); per surface group the
    pixels it owns and the pixels it would cover alone (before the other groups hide it)."""

    depth: np.ndarray
    owner: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    seen_pixels: np.ndarray
    alone_pixels: np.ndarray


def _rectangles(cam: Camera, rects: list[Rectangle], rays: np.ndarray) -> tuple[np.ndarray, ...]:
    """Depth, owner, normal and albedo of the nearest rectangle along every ray."""
    h, w = cam.height, cam.width
    depth = np.full(h * w, np.inf)
    owner = np.full(h * w, NO_RETURN, dtype=np.int64)
    normal = np.zeros((h * w, 3))
    albedo = np.zeros(h * w)
    r = rays.reshape(-1, 3)
    inv = np.linalg.inv(cam.world_from_camera)
    for rect in rects:
        c = inv[:3, :3] @ rect.centre + inv[:3, 3]
        hu, hv = inv[:3, :3] @ rect.half_u, inv[:3, :3] @ rect.half_v
        n = np.cross(hu, hv)
        n /= np.linalg.norm(n)
        denom = r @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (c @ n) / denom
        q = r * t[:, None] - c
        inside = (np.abs(q @ hu) <= hu @ hu) & (np.abs(q @ hv) <= hv @ hv)
        hit = inside & (t > 1e-6) & (t < depth)
        depth[hit] = t[hit]
        owner[hit] = rect.owner
        normal[hit] = np.where((denom[hit] > 0)[:, None], -n, n)
        albedo[hit] = rect.albedo
    return depth, owner, normal, albedo


#: Splat offsets (pixels): each sample covers 2 x 2 pixels so that surfaces stay closed.
_SPLAT = ((0, 0), (1, 0), (0, 1), (1, 1))


def _splat(
    cam: Camera, pts: np.ndarray, nrm: np.ndarray, bounded: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(depth, pixel, sample) of every sample (camera frame) at every splat offset. Depth is
    where the pixel's ray meets the sample's tangent plane (the sample's own depth when the
    plane is seen edge-on). Unbounded: pixels off the image keep a unique index too."""
    z = pts[:, 2]
    front = z > 1e-6
    safe = np.where(front, z, 1.0)
    fu = cam.fx * pts[:, 0] / safe + cam.cx - 0.5
    fv = cam.fy * pts[:, 1] / safe + cam.cy - 0.5
    u0, v0 = np.floor(fu).astype(np.int64), np.floor(fv).astype(np.int64)
    pad = 0 if bounded else 4 * max(cam.width, cam.height)
    span = cam.width + 2 * pad
    plane = np.einsum("ij,ij->i", nrm, pts)
    ds, ps, ss = [], [], []
    for du, dv in _SPLAT:
        u, v = u0 + du, v0 + dv
        ok = front & (u >= -pad) & (u < cam.width + pad) & (v >= -pad) & (v < cam.height + pad)
        idx = np.flatnonzero(ok)
        rx = (u[idx] + 0.5 - cam.cx) / cam.fx
        ry = (v[idx] + 0.5 - cam.cy) / cam.fy
        n = nrm[idx]
        along = rx * n[:, 0] + ry * n[:, 1] + n[:, 2]
        cos = np.abs(along) / np.sqrt(rx * rx + ry * ry + 1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = np.where(cos > 0.25, plane[idx] / along, z[idx])
        # A pixel whose ray meets the tangent plane far from the sample (a face seen nearly
        # edge-on, past its silhouette) is not covered by this sample.
        hit = np.column_stack([rx * d, ry * d, d]) - pts[idx]
        near = np.einsum("ij,ij->i", hit, hit) <= (1.25 * z[idx] / cam.fx) ** 2
        ds.append(d[near])
        ps.append(((v[idx] + pad) * span + (u[idx] + pad))[near])
        ss.append(idx[near])
    return np.concatenate(ds), np.concatenate(ps), np.concatenate(ss)


def _alone(
    cam: Camera, d: np.ndarray, p: np.ndarray, depth: np.ndarray
) -> tuple[int, np.ndarray, np.ndarray]:
    """Pixels a group's splats (unbounded indices `p`) would cover alone: in front of the
    rectangles' `depth` where on the image, anywhere off it; and per splat its image pixel
    and whether it is on the image in front of the rectangles."""
    pad = 4 * max(cam.width, cam.height)
    span = cam.width + 2 * pad
    u, v = p % span - pad, p // span - pad
    on = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    pix = np.where(on, v * cam.width + u, 0)
    front = ~on | (d < depth[pix])
    return len(np.unique(p[front])), pix, on & front


def render(
    cam: Camera,
    groups: list[tuple[np.ndarray, np.ndarray, float]],
    rects: list[Rectangle],
    labels: list[int] | None = None,
) -> Rendered:
    """The ideal depth frame of `groups` (per group: world samples (S, 3), their unit normals
    (S, 3) and the group's albedo; owner label ``labels[g]``, default g) and `rects`.

    ``seen_pixels[g]`` counts the pixels group g owns; ``alone_pixels[g]`` the pixels it
    would cover were it alone in front of the rectangles, on an image without borders (so a
    copy half out of the picture is half visible)."""
    labels = list(range(len(groups))) if labels is None else labels
    rays = cam.rays()
    depth, owner, normal, albedo = _rectangles(cam, rects, rays)
    inv = np.linalg.inv(cam.world_from_camera)
    n_pix = cam.width * cam.height
    all_d, all_p, all_g, all_n, alone = [], [], [], [], np.zeros(len(groups), dtype=np.int64)
    for g, (pts, nrm, _) in enumerate(groups):
        pc = pts @ inv[:3, :3].T + inv[:3, 3]
        nc = nrm @ inv[:3, :3].T
        d, p, s = _splat(cam, pc, nc, bounded=False)
        alone[g], pix, keep = _alone(cam, d, p, depth)
        all_d.append(d[keep])
        all_p.append(pix[keep])
        all_g.append(np.full(int(keep.sum()), g))
        all_n.append(nc[s[keep]])
    seen = np.zeros(len(groups), dtype=np.int64)
    if groups:
        dd, pp, gg = np.concatenate(all_d), np.concatenate(all_p), np.concatenate(all_g)
        nrm = np.concatenate(all_n)
        zbuf = depth.copy()
        np.minimum.at(zbuf, pp, dd)
        win = dd <= zbuf[pp]
        glab = np.asarray(labels, dtype=np.int64)
        depth = zbuf
        owner[pp[win]] = glab[gg[win]]
        normal[pp[win]] = nrm[win]
        albedo[pp[win]] = np.asarray([a for _, _, a in groups])[gg[win]]
        won = np.zeros(n_pix, dtype=np.int64) - 1
        won[pp[win]] = gg[win]
        seen = np.bincount(won[won >= 0], minlength=len(groups))[: len(groups)]
    rv = rays.reshape(-1, 3)
    facing = np.einsum("ij,ij->i", normal, rv) > 0
    normal[facing] *= -1  # normals face the camera
    return Rendered(
        depth=depth.reshape(cam.height, cam.width),
        owner=owner.reshape(cam.height, cam.width),
        normal=normal.reshape(cam.height, cam.width, 3),
        albedo=albedo.reshape(cam.height, cam.width),
        seen_pixels=seen.astype(np.int64),
        alone_pixels=alone,
    )

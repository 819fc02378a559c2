"""The parts of the sensed scenes, their symmetries, and the forms a user's model comes in.

A :class:`Part` is a triangle mesh in metres, centred on its bounding box, with its albedo
(dark parts lose returns), its resting orientation and its proper symmetries (4 x 4
transforms ``S`` with ``mesh = S mesh``: a pose ``T`` and ``T @ S`` look the same). Parts:

- organic: the Stanford bunny and dragon (data folder; the packaged coarse bunny without it);
- CAD: the fandisk and the rocker arm (common3d meshes of the data folder);
- boxes: cartons of three distinct sides (95 x 36 x 68 mm, 232 x 44 x 52 mm) and one with a
  near-square section (120 x 52 x 50 mm: a quarter turn about its long axis is *not* a
  symmetry, and a method that returns it is wrong);
- thin: an L-shaped bracket bent from 3 mm sheet, arms of unequal width.

:func:`model_form` gives the model as a user would hold it: ``fine_mesh`` (samples of the
mesh), ``coarse_mesh`` (samples of a decimated mesh: the bunny's own ``res4``, others
clustered to a twelfth of the diagonal), ``points`` (a sparse noisy point cloud of the part)
or ``scan`` (three range views of the part merged; the bunny's real range scans when the data
folder has them).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import cast

import numpy as np

from ..io.mesh import sample_mesh
from .procedural_shapes import _cuboid, _merge
from .scene_sensing import _up_rotation

__all__ = [
    "MODEL_FORMS",
    "PARTS",
    "Part",
    "box_symmetries",
    "load_part",
    "model_form",
    "surface_samples",
]

Mesh = tuple[np.ndarray, np.ndarray]

#: How the user's model of a part may come.
MODEL_FORMS: tuple[str, ...] = ("fine_mesh", "coarse_mesh", "points", "scan")

#: name -> (kind, source, size in metres, albedo): source is a data-folder mesh (scaled so
#: its bounding-box diagonal is `size`, with its up axis), or box side lengths.
PARTS: dict[str, tuple[str, object, float, float]] = {
    "bunny": ("organic", ("stanford/bunny/reconstruction/bun_zipper_res2.ply", "y"), 0.12, 0.6),
    "dragon": ("organic", ("stanford/dragon/dragon_spica_21790v.ply", "y"), 0.12, 0.5),
    "fandisk": ("cad", ("common3d/fandisk.ply", "-z"), 0.12, 0.45),
    "rocker_arm": ("cad", ("common3d/rocker-arm.ply", "x"), 0.12, 0.45),
    "box_95x36x68": ("box", (0.095, 0.036, 0.068), 0.0, 0.5),
    "box_232x44x52": ("box", (0.232, 0.044, 0.052), 0.0, 0.5),
    "box_120x52x50": ("box", (0.120, 0.052, 0.050), 0.0, 0.5),
    "bracket": ("thin", (0.10, 0.05, 0.035, 0.003), 0.0, 0.15),
}


def box_symmetries() -> np.ndarray:
    """The 4 proper symmetries of a box of three distinct sides centred on the origin:
    the identity and half turns about x, y and z."""
    out = np.tile(np.eye(4), (4, 1, 1))
    for k, d in enumerate(((1, -1, -1), (-1, 1, -1), (-1, -1, 1)), start=1):
        out[k, :3, :3] = np.diag(d)
    return out


@dataclass(frozen=True)
class Part:
    """A part's mesh (metres, centred on its bounding box), kind, albedo, the rotation that
    sets it down on its resting face (the box's largest face, the mesh's base), its symmetries
    and the coarse mesh of the ``coarse_mesh`` form."""

    name: str
    kind: str
    vertices: np.ndarray
    faces: np.ndarray
    albedo: float
    rest: np.ndarray
    symmetries: np.ndarray
    coarse: Mesh | None = None
    scans: tuple[np.ndarray, ...] = field(default_factory=tuple)

    @property
    def diameter(self) -> float:
        return float(np.linalg.norm(self.vertices.max(0) - self.vertices.min(0)))

    @property
    def extent(self) -> np.ndarray:
        return self.vertices.max(0) - self.vertices.min(0)

    @property
    def area(self) -> float:
        v = self.vertices[self.faces]
        return 0.5 * float(
            np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1).sum()
        )


def _box(sides: tuple[float, float, float]) -> Mesh:
    s = np.asarray(sides, dtype=np.float64)
    return _cuboid(-s / 2, s / 2)


def _bracket(length: float, a: float, b: float, t: float) -> Mesh:
    """An L profile (arms `a` and `b` wide, `t` thick) extruded along x over `length`."""
    base = _cuboid(np.array([0, 0, 0]), np.array([length, a, t]))
    wall = _cuboid(np.array([0, 0, t]), np.array([length, t, b]), open_bottom=True)
    v, f = _merge(base, wall)
    return v - (v.max(0) + v.min(0)) / 2, f


def _decimate(v: np.ndarray, f: np.ndarray, cell: float) -> Mesh:
    """Vertex clustering: vertices merged per grid cell (their mean), collapsed faces dropped."""
    key = np.floor((v - v.min(0)) / cell).astype(np.int64)
    _, cluster = np.unique(key, axis=0, return_inverse=True)
    cluster = cluster.ravel()
    n = int(cluster.max()) + 1
    verts = np.zeros((n, 3))
    np.add.at(verts, cluster, v)
    verts /= np.bincount(cluster, minlength=n)[:, None]
    g = cluster[f]
    ok = (g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 0] != g[:, 2])
    return verts, g[ok]


def _read(path: Path) -> Mesh:
    from ..io import read_mesh

    m = read_mesh(path)
    if m.triangles is None:
        raise ValueError(f"{path}: a mesh with faces is needed")
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.triangles, dtype=np.int64)


def _bunny_real_scans(data_dir: Path, shift: np.ndarray, scale: float) -> tuple[np.ndarray, ...]:
    from .scene_sensing import _bunny_scans

    try:
        scans = _bunny_scans(str(data_dir))
    except (OSError, KeyError, ValueError):
        return ()
    return tuple((pts - shift) * scale for pts, _ in scans)


@lru_cache(maxsize=16)
def load_part(name: str, data_dir: str | None = None) -> Part:
    """The part `name` of :data:`PARTS` (meshes from `data_dir`; the bunny falls back to the
    packaged coarse bunny without it)."""
    if name not in PARTS:
        raise ValueError(f"unknown part {name!r}: use one of {sorted(PARTS)}")
    kind, src, size, albedo = PARTS[name]
    scans: tuple[np.ndarray, ...] = ()
    coarse: Mesh | None = None
    if kind == "box":
        v, f = _box(cast(tuple[float, float, float], src))
        order = np.argsort(v.max(0) - v.min(0))[::-1]
        rest = np.eye(3)[order]  # longest side along x, shortest up
        if np.linalg.det(rest) < 0:
            rest[2] *= -1
        return Part(name, kind, v, f.astype(np.int64), albedo, rest, box_symmetries())
    if kind == "thin":
        v, f = _bracket(*cast(tuple[float, float, float, float], src))
        return Part(name, kind, v, f.astype(np.int64), albedo, np.eye(3), np.eye(4)[None])
    rel, up = cast(tuple[str, str], src)
    base = Path(data_dir) if data_dir else None
    if base is not None and (base / rel).is_file():
        v, f = _read(base / rel)
    elif name == "bunny":
        from .shapes import bunny_mesh

        v, f = bunny_mesh()
        v, f = np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)
    else:
        raise ValueError(
            f"part {name!r} needs the data folder (pass data_dir= or set POINTCLM_DATA_DIR)"
        )
    shift = (v.max(0) + v.min(0)) / 2
    scale = size / float(np.linalg.norm(v.max(0) - v.min(0)))
    v = (v - shift) * scale
    if name == "bunny" and base is not None:
        res4 = base / "stanford/bunny/reconstruction/bun_zipper_res4.ply"
        if res4.is_file():
            cv, cf = _read(res4)
            coarse = ((cv - shift) * scale, cf)
        scans = _bunny_real_scans(base, shift, scale)
    return Part(name, kind, v, f, albedo, _up_rotation(up), np.eye(4)[None], coarse, scans)


def surface_samples(part: Part, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """`n` area-uniform samples of the part's surface and their unit normals."""
    cloud = sample_mesh(part.vertices, part.faces, int(n), seed)
    assert cloud.normals is not None
    return cloud.points, cloud.normals


def model_form(part: Part, form: str, seed: int = 0) -> np.ndarray:
    """The part's model in its own frame as a user would hold it (module documentation)."""
    rng = np.random.default_rng([seed, 7])
    if form == "fine_mesh":
        return sample_mesh(part.vertices, part.faces, 20_000, seed).points
    if form == "coarse_mesh":
        v, f = part.coarse or _decimate(part.vertices, part.faces, part.diameter / 12)
        return sample_mesh(v, f, 10_000, seed).points
    if form == "points":
        pts = sample_mesh(part.vertices, part.faces, 3000, seed).points
        return pts + rng.normal(scale=0.002 * part.diameter, size=pts.shape)
    if form == "scan":
        if part.scans:
            return np.concatenate(part.scans)
        return _virtual_scan(part, rng)
    raise ValueError(f"unknown model form {form!r}: use one of {list(MODEL_FORMS)}")


def _virtual_scan(part: Part, rng: np.random.Generator) -> np.ndarray:
    """Three views of the part alone (30 degrees up, a third of a turn apart), merged in the
    part's frame: its underside unseen, as a part scanned on a table."""
    from .cameras import CAMERAS, look_at, render
    from .sensor_effects import SENSORS, frame_points, sense

    pts, nrm = surface_samples(part, 60_000, int(rng.integers(1 << 30)))
    up = part.rest.T @ np.array([0.0, 0.0, 1.0])  # the world's up in the part's frame
    # A frame whose z is the part's up, to aim the views.
    a = np.cross(up, [1.0, 0, 0] if abs(up[0]) < 0.9 else [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(up, a)
    base = np.column_stack([a, b, up])
    views = []
    for k in range(3):
        az = 2 * np.pi * k / 3 + rng.uniform(0, 0.5)
        d = np.array([np.cos(az) * np.cos(0.5), np.sin(az) * np.cos(0.5), np.sin(0.5)])
        cam = look_at(CAMERAS["rgbd_0.6m"], np.zeros(3), d)
        frame = render(cam, [(pts @ base, nrm @ base, part.albedo)], [])
        depth = sense(frame, cam, SENSORS["gauss_0.5mm"], rng)
        xyz = frame_points(depth, cam).reshape(-1, 3)
        xyz = xyz[np.isfinite(xyz).all(1)]
        w = cam.world_from_camera
        views.append((xyz @ w[:3, :3].T + w[:3, 3]) @ base.T)
    return np.concatenate(views)

"""Sensed scenes: any layout of any parts, seen by any camera through any sensor model.

The scenes of the validation matrix (``benchmarks/matrix/run.py``) and of the packed-box
generator (:func:`make_packed_boxes`). One scene is built in four steps, all drawn from one
generator seeded by the parameters and the seed (the same arguments give the same scene):

1. **Layout** (:mod:`pointclm.datasets.layouts`): the copies' poses in the world, the bin's
   walls and floor or a room's floor, clutter, and where the camera looks from.
2. **Camera** (:mod:`pointclm.datasets.cameras`): the preset's intrinsics at its distance
   from the layout's target, its image centre aimed there.
3. **Render**: dense samples of every copy (enough for about two samples per pixel at the
   nearest copy's depth) and the flat surfaces, z-buffered: the ideal depth frame.
4. **Sensor** (:mod:`pointclm.datasets.sensor_effects`): noise, dropouts, flying pixels and
   quantisation; the organised frame in the camera's frame (NaN: no return).

Everything is returned **in the camera's frame**, as a sensor delivers it: the sensor sits at
the origin, poses are ``T_camera_part``. A copy's **visible fraction** is the number of pixels
that see it in the scene over the number that would see it alone (in front of the floor and
walls, on an image without borders), both before the sensor's effects.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np

from .cameras import CAMERAS, Camera, look_at, render
from .layouts import CLUTTER, FLOOR, LAYOUTS, WALL, Layout, make_layout
from .parts import MODEL_FORMS, PARTS, Part, load_part, model_form, surface_samples
from .scenes import default_data_dir
from .sensor_effects import SENSORS, SensorModel, frame_points, sense

__all__ = [
    "CLUTTER",
    "FLOOR",
    "WALL",
    "SensedScene",
    "SensedSceneParams",
    "make_packed_boxes",
    "make_sensed_scene",
]

#: Box products of the packed-box generator's default mixed bin.
BOX_PRODUCTS: tuple[str, ...] = ("box_95x36x68", "box_232x44x52")


@dataclass(frozen=True)
class SensedSceneParams:
    """What a sensed scene holds and how it is seen: part names (one or more products, from
    :data:`pointclm.datasets.parts.PARTS`), the layout, copies per product (lo, hi), camera
    and sensor presets (or objects), the model form, and the data folder."""

    parts: tuple[str, ...] = ("bunny",)
    layout: str = "pile"
    copies: tuple[int, int] = (5, 10)
    camera: str | Camera = "rgbd_0.6m"
    sensor: str | SensorModel = "structured_light"
    form: str = "fine_mesh"
    clutter: int = 2
    data_dir: str | None = None

    def __post_init__(self) -> None:
        if not self.parts:
            raise ValueError("parts must name at least one part")
        unknown = [p for p in self.parts if p not in PARTS]
        if unknown:
            raise ValueError(f"unknown part(s) {unknown}: use names of {sorted(PARTS)}")
        if self.layout not in LAYOUTS:
            raise ValueError(f"unknown layout {self.layout!r}: use one of {list(LAYOUTS)}")
        if not 1 <= self.copies[0] <= self.copies[1]:
            raise ValueError(f"copies must be (lo, hi) with 1 <= lo <= hi, got {self.copies}")
        if isinstance(self.camera, str) and self.camera not in CAMERAS:
            raise ValueError(f"unknown camera {self.camera!r}: use one of {sorted(CAMERAS)}")
        if isinstance(self.sensor, str) and self.sensor not in SENSORS:
            raise ValueError(f"unknown sensor {self.sensor!r}: use one of {sorted(SENSORS)}")
        if self.form not in MODEL_FORMS:
            raise ValueError(f"unknown model form {self.form!r}: use one of {list(MODEL_FORMS)}")

    def key(self) -> str:
        cam = self.camera if isinstance(self.camera, str) else repr(self.camera)
        sen = self.sensor if isinstance(self.sensor, str) else repr(self.sensor)
        return "|".join(["+".join(self.parts), self.layout, str(self.copies), cam, sen, self.form])


@dataclass(frozen=True)
class SensedScene:
    """One sensed scene and its ground truth (camera frame; the sensor at the origin).

    Attributes
    ----------
    frame : (H, W, 3) the organised frame, NaN where the sensor returned nothing.
    frame_ids : (H, W) owner of each pixel: copy k, ``CLUTTER``, ``FLOOR``, ``WALL``, or
        :data:`pointclm.datasets.cameras.NO_RETURN`.
    scan, scan_ids : (N, 3) the frame's returns (in pixel order when the sensor is organised,
        shuffled otherwise) and their owners.
    models : per product, the model as the user holds it (the params' form), part frame.
    poses : (K, 4, 4) ``T_camera_part`` of each copy; ``product`` (K,) its product.
    visible_fraction : (K,) see the module documentation; ``visible_pixels`` and
        ``alone_pixels`` the two counts.
    symmetries : per product, (S, 4, 4) proper symmetries of the part (identity first).
    diameters : per product, the part's bounding-box diagonal.
    camera : the placed camera (its pose: world from camera).
    """

    frame: np.ndarray
    frame_ids: np.ndarray
    scan: np.ndarray
    scan_ids: np.ndarray
    models: list[np.ndarray]
    poses: np.ndarray
    product: np.ndarray
    visible_fraction: np.ndarray
    visible_pixels: np.ndarray
    alone_pixels: np.ndarray
    symmetries: list[np.ndarray]
    diameters: list[float]
    parts: tuple[str, ...]
    camera: Camera
    params: SensedSceneParams
    seed: int
    viewpoint: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def n_copies(self) -> int:
        return len(self.poses)

    def copies_of(self, product: int, min_visible: float = 0.0) -> np.ndarray:
        """Indices of the copies of `product` at least `min_visible` visible."""
        return np.flatnonzero((self.product == product) & (self.visible_fraction >= min_visible))


def _scene_rng(params: SensedSceneParams, seed: int) -> np.random.Generator:
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed!r}")
    return np.random.default_rng([zlib.crc32(params.key().encode()), int(seed)])


def _clutter_parts(params: SensedSceneParams, dd: str | None) -> list[Part]:
    pool = [p for p in ("bracket", "box_120x52x50", "fandisk", "dragon") if p not in params.parts]
    out = []
    for name in pool[: params.clutter]:
        try:
            out.append(load_part(name, dd))
        except ValueError:
            continue  # needs the data folder
    return out


def _samples_needed(part: Part, cam: Camera, nearest: float) -> int:
    """About 1.5 samples per pixel the part's surface covers at depth `nearest` (so that
    under one pixel in 300 of a face seen head-on gets no sample within its 2 x 2 splat)."""
    per_pixel = (nearest / cam.fx) ** 2
    return int(np.clip(1.5 * part.area / per_pixel, 2000, 300_000))


def _groups(
    layout: Layout,
    parts: list[Part],
    clutter: list[tuple[Part, np.ndarray]],
    cam: Camera,
    seed: int,
) -> tuple[list[tuple[np.ndarray, np.ndarray, float]], list[int]]:
    """Dense world samples, normals and albedo of every copy (then the clutter), with labels."""
    inv = np.linalg.inv(cam.world_from_camera)
    centres = layout.poses[:, :3, 3] @ inv[:3, :3].T + inv[:3, 3]
    depth_of = np.maximum(
        0.05, centres[:, 2] - np.array([parts[k].diameter for k in layout.product]) / 2
    )
    need = [
        _samples_needed(parts[k], cam, d) for k, d in zip(layout.product, depth_of, strict=True)
    ]
    most = [
        max([n for n, k in zip(need, layout.product, strict=True) if k == j], default=1)
        for j in range(len(parts))
    ]
    # One sample set per product; each copy takes a prefix of it (the samples are i.i.d.).
    samples = [surface_samples(p, m, seed + 11) for p, m in zip(parts, most, strict=True)]
    groups, labels = [], []
    for k, (pose, prod) in enumerate(zip(layout.poses, layout.product, strict=True)):
        pts, nrm = samples[prod][0][: need[k]], samples[prod][1][: need[k]]
        rot = pose[:3, :3]
        groups.append((pts @ rot.T + pose[:3, 3], nrm @ rot.T, parts[prod].albedo))
        labels.append(k)
    nearest = float(depth_of.min()) if len(depth_of) else 1.0
    for part, pose in clutter:
        pts, nrm = surface_samples(part, _samples_needed(part, cam, nearest), seed + 13)
        groups.append((pts @ pose[:3, :3].T + pose[:3, 3], nrm @ pose[:3, :3].T, part.albedo))
        labels.append(CLUTTER)
    return groups, labels


def make_sensed_scene(seed: int = 0, params: SensedSceneParams | None = None) -> SensedScene:
    """Build one seeded sensed scene (module documentation)."""
    params = params or SensedSceneParams()
    rng = _scene_rng(params, seed)
    data_dir = params.data_dir or default_data_dir()
    dd = str(data_dir) if data_dir else None
    parts = [load_part(name, dd) for name in params.parts]
    clutter = _clutter_parts(params, dd) if params.layout == "room" else []
    layout, placed_clutter = make_layout(params.layout, rng, parts, params.copies, clutter)
    cam0 = CAMERAS[params.camera] if isinstance(params.camera, str) else params.camera
    sensor = SENSORS[params.sensor] if isinstance(params.sensor, str) else params.sensor
    cam = look_at(cam0, layout.target, layout.direction)
    inv = np.linalg.inv(cam.world_from_camera)
    groups, labels = _groups(layout, parts, placed_clutter, cam, seed)
    frame = render(cam, groups, layout.rects, labels)
    depth = sense(frame, cam, sensor, rng)
    xyz = frame_points(depth, cam)
    ids = np.where(np.isfinite(depth), frame.owner, -9)
    valid = np.flatnonzero(np.isfinite(depth).ravel())
    if not sensor.organised:
        valid = rng.permutation(valid)
    n = len(layout.poses)
    seen, alone = frame.seen_pixels[:n], frame.alone_pixels[:n]
    return SensedScene(
        frame=xyz,
        frame_ids=ids,
        scan=xyz.reshape(-1, 3)[valid],
        scan_ids=ids.ravel()[valid],
        models=[model_form(p, params.form, seed) for p in parts],
        poses=inv @ layout.poses,
        product=layout.product.astype(np.int64),
        visible_fraction=np.where(alone > 0, seen / np.maximum(alone, 1), 0.0),
        visible_pixels=seen,
        alone_pixels=alone,
        symmetries=[p.symmetries for p in parts],
        diameters=[p.diameter for p in parts],
        parts=params.parts,
        camera=cam,
        params=params,
        seed=int(seed),
    )


def make_packed_boxes(
    seed: int = 0,
    products: tuple[str, ...] = BOX_PRODUCTS,
    layout: str = "grid",
    camera: str | Camera = "rgbd_0.6m",
    sensor: str | SensorModel = "structured_light",
    copies: tuple[int, int] = (5, 10),
    form: str = "fine_mesh",
) -> SensedScene:
    """A bin of touching boxes of two or three products: rows (``"row"``: standing on edge
    side by side), grids (``"grid"``: lying flat side by side) or piles (``"pile"``), with the
    bin's walls and floor kept in the scan, under the given camera and sensor.

    Returns the :class:`SensedScene`: the scan, one model per product (``models``), the true
    poses with each copy's product and visible fraction, and each product's symmetries (the
    four proper symmetries of a box with three distinct sides) for scoring."""
    if layout not in ("grid", "row", "pile"):
        raise ValueError(f"layout must be 'grid', 'row' or 'pile', got {layout!r}")
    if not 1 <= len(products) <= 3 or any(PARTS.get(p, ("",))[0] != "box" for p in products):
        boxes = sorted(k for k, v in PARTS.items() if v[0] == "box")
        raise ValueError(f"products must be one to three boxes of {boxes}, got {products}")
    params = SensedSceneParams(
        parts=tuple(products), layout=layout, copies=copies, camera=camera, sensor=sensor, form=form
    )
    return make_sensed_scene(seed, params)

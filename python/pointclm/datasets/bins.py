"""Bin-picking scenes: dozens of copies of one part heaped in a bin under a depth sensor.

Why: the first use named for pointclm is a robot picking parts from a bin. Such
a scan holds 20 to 80 copies of one part, many of them partly hidden by others, and the
picking robot needs the least-hidden ones first. Each scene is built as follows (units:
metres; the part is scaled to size, so every model gives the same scene geometry):

1. **Bin.** A box of inner size 0.4 x 0.3 m, walls 0.2 m high and 1 cm thick; the part is
   scaled so that its bounding-box diagonal is 1/4 of the bin's length (0.1 m).
2. **Heap.** 20-80 copies (uniform) are poured one after another over the bin's middle (x, y
   normal around the centre, sigma 1/6 of the bin's sides). Each drop tries ``candidates``
   uniformly random orientations; each is lowered on a height field of the heap (cells of
   1/40 of the part's diagonal holding the highest surface sample so far) until it touches
   the heap or the floor, then slides downhill in steps of a quarter diagonal (at most
   ``slide_steps``) while that lowers it; the orientation that comes to rest lowest is kept
   (a crude stand-in for tipping onto a stable face). Every column of the height field holds
   the copies in disjoint height intervals: copies touch but never interpenetrate.
3. **Sensor.** A pinhole depth sensor 0.8 m above the floor's centre looks straight down,
   640 x 480 pixels, its field of view just covering the bin (about 0.7 mm per pixel on the
   floor). A z-buffer of dense surface samples of every copy (40,000 per copy, each splatted
   over 2 x 2 pixels so that surfaces stay closed) and the bin's planes, cast exactly, gives
   the first surface along every pixel's ray: copies hide each other, the walls hide copies.
4. **Noise of a structured-light sensor.** Depth noise with sigma = ``noise_at_1m`` * z^2
   (0.5 mm at 1 m; z in metres), depth quantised as a disparity (focal length f pixels,
   baseline 7.5 cm, 1/16-pixel steps, so the step also grows as z^2), and dropouts: a pixel
   whose surface is seen at more than 60 degrees from the ray is lost with a probability
   rising linearly to 1 at 85 degrees (depth edges included, as real sensors lose them).
   The scan is then cropped to the bin's interior less ``crop_margin`` (the region of
   interest of a picking cell, which knows where its bin is): the floor stays, the walls go.

Ground truth per copy: its pose ``T_target_source`` (from the scaled model's frame, the
``model_points``, to the scan's), its **visible fraction** and its **visibility rank**. The
visible fraction is the number of pixels that see the copy in the heap over the number that
would see it at the same pose alone in the (empty) bin, both before noise, dropouts and the
crop: 1 for a copy nothing covers, 0 for a buried one, whatever the part's shape or how much
of it faces the sensor. The rank orders copies by visible fraction, most visible first (ties:
more pixels first): the copies a picking robot should take first.

The scan is the sensor's raw point cloud (about 200,000 points). ``voxel_size`` is
:func:`pointclm.register_point_clouds`' default, 1/40 of the part's diagonal (2.5 mm); at it
the scan keeps about 33,000 points. (A coarser voxel giving 20,000 points, 1/22 of the
diagonal, leaves too few points on the part for FPFH: on a fandisk scene no method found a
copy.)
"""

from __future__ import annotations

import json
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import PathNotFoundError
from .bin_sensing import FLOOR, WALL, _Camera, _render, _sense  # noqa: F401  (FLOOR, WALL: public here)
from .procedural import PROCEDURAL_FAMILIES, PROCEDURAL_SHAPES, is_procedural
from .scenes import HELDOUT_MODELS, MODEL_FILES, VALIDATION_MODELS, default_data_dir, dense_model

__all__ = [
    "BIN_MODELS_HELD_OUT",
    "BIN_MODELS_VALIDATION",
    "BinParams",
    "BinScene",
    "bin_scene_cached",
    "load_bin_scene",
    "make_bin_scene",
    "save_bin_scene",
]

#: The project's model split (:mod:`pointclm.datasets.scenes`): figures are reported on the
#: held-out models, thresholds and defaults chosen only on the validation ones.
BIN_MODELS_HELD_OUT: tuple[str, ...] = HELDOUT_MODELS
BIN_MODELS_VALIDATION: tuple[str, ...] = VALIDATION_MODELS

#: Bump when the generator changes, so that cached scenes are rebuilt.
_VERSION = 2


@dataclass(frozen=True)
class BinParams:
    """How bin scenes are built (defaults: the benchmark's; lengths in metres)."""

    model: str = "common3d/fandisk"
    copies: tuple[int, int] = (20, 80)
    bin_size: tuple[float, float, float] = (0.4, 0.3, 0.2)
    wall_thickness: float = 0.01
    part_fraction: float = 1 / 4
    candidates: int = 4
    pour_spread: float = 1 / 6
    slide_steps: int = 4
    sensor_height: float = 0.8
    resolution: tuple[int, int] = (640, 480)
    noise_at_1m: float = 5e-4
    baseline: float = 0.075
    disparity_step: float = 1 / 16
    grazing_deg: tuple[float, float] = (60.0, 85.0)
    crop_margin: float | None = 0.01
    voxel_fraction: float = 1 / 40
    data_dir: str | None = None

    def __post_init__(self) -> None:
        lo, hi = self.copies
        if not 1 <= lo <= hi:
            raise ValueError(f"copies must be (lo, hi) with 1 <= lo <= hi, got {self.copies}")
        if min(self.bin_size) <= 0 or self.wall_thickness < 0:
            raise ValueError(f"bin_size must be positive, got {self.bin_size}")
        if not 0 < self.part_fraction < 1:
            raise ValueError(f"part_fraction must lie in (0, 1), got {self.part_fraction}")
        if self.candidates < 1:
            raise ValueError(f"candidates must be at least 1, got {self.candidates}")
        if self.sensor_height <= self.bin_size[2]:
            raise ValueError("the sensor must sit above the bin's walls")
        if min(self.resolution) < 8:
            raise ValueError(f"resolution must be at least 8 x 8, got {self.resolution}")
        if self.noise_at_1m < 0 or self.baseline <= 0 or self.disparity_step < 0:
            raise ValueError("noise_at_1m and disparity_step must be >= 0, baseline > 0")
        if not 0 < self.grazing_deg[0] <= self.grazing_deg[1] <= 90:
            raise ValueError(f"grazing_deg must be 0 < lo <= hi <= 90, got {self.grazing_deg}")
        if not 0 < self.voxel_fraction < 1:
            raise ValueError(f"voxel_fraction must lie in (0, 1), got {self.voxel_fraction}")


@dataclass(frozen=True)
class BinScene:
    """One bin scene and its ground truth.

    Attributes
    ----------
    scan : (N, 3) float64, the sensor's points (world frame: floor z = 0, bin centred on
        the origin).
    scan_ids : (N,) int64, per scan point: the copy it lies on, or ``FLOOR`` (-2) / ``WALL``
        (-3, walls and rim).
    model_points : (S, 3) float64, dense samples of the model scaled to the part size, in the
        model's frame (the source cloud of every pose).
    poses : (K, 4, 4) float64, T_target_source of each copy (model frame -> scan frame).
    visible_fraction : (K,) pixels seeing the copy in the heap / pixels that would see it
        alone in the bin (0 where it would be seen by none).
    visible_pixels, alone_pixels : (K,) int64, those two counts.
    rank : (K,) int64, visibility rank (0: most visible copy).
    sensor : (3,) the sensor's position (the viewpoint of the scan's normals).
    voxel_size, diameter : float, the benchmark's voxel and the part's bounding-box diagonal.
    """

    scan: np.ndarray
    scan_ids: np.ndarray
    model_points: np.ndarray
    poses: np.ndarray
    visible_fraction: np.ndarray
    visible_pixels: np.ndarray
    alone_pixels: np.ndarray
    rank: np.ndarray
    sensor: np.ndarray
    voxel_size: float
    diameter: float
    model: str
    seed: int
    params: BinParams

    @property
    def n_copies(self) -> int:
        return len(self.poses)

    @property
    def max_translation(self) -> float:
        """The TE threshold: 10 % of the part's diagonal."""
        return 0.1 * self.diameter

    def least_hidden(self, k: int) -> np.ndarray:
        """Indices of the `k` most visible copies, most visible first."""
        return np.argsort(self.rank, kind="stable")[:k]


# --- model --------------------------------------------------------------------------------


def _model_points(name: str, data_dir: str | None) -> np.ndarray:
    """Dense samples of a model by name: the realistic scenes' models, procedural shapes, or
    ``common3d/<mesh>`` from the data folder."""
    if name in MODEL_FILES or is_procedural(name) or name == "bunny":
        return dense_model(name, data_dir)[0]
    if name.startswith("common3d/"):
        if data_dir is None:
            raise ValueError(
                f"model {name!r} lives in the data folder: pass data_dir= or set POINTCLM_DATA_DIR"
            )
        path = Path(data_dir) / f"{name}.ply"
        if not path.is_file():
            raise PathNotFoundError(f"model {name!r}: no mesh at {path}")
        return dense_model(str(path), data_dir)[0]
    raise ValueError(
        f"unknown model {name!r}: use one of {sorted(MODEL_FILES)}, common3d/<mesh> or a "
        f"procedural shape {list(PROCEDURAL_SHAPES)} or '<family>-<seed>' with <family> one "
        f"of {list(PROCEDURAL_FAMILIES)} (e.g. 'superquadric-17')"
    )


def _scene_rng(model: str, seed: int) -> np.random.Generator:
    """A stream per (model, seed): scene i of two models differ, and each is fixed."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed!r}")
    return np.random.default_rng([zlib.crc32(model.encode()), int(seed)])


def _random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    """`n` rotations uniform on SO(3) (unit quaternions from normal draws)."""
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )


# --- heap ---------------------------------------------------------------------------------


class _HeightField:
    """The heap's highest surface sample per cell of a grid over the bin's floor."""

    def __init__(self, length: float, width: float, cell: float) -> None:
        self.cell = cell
        self.origin = np.array([-length / 2, -width / 2])
        self.shape = (int(np.ceil(length / cell)), int(np.ceil(width / cell)))
        self.top = np.zeros(self.shape[0] * self.shape[1])

    def cells(self, xy: np.ndarray) -> np.ndarray:
        ij = np.floor((xy - self.origin) / self.cell).astype(np.int64)
        ij[:, 0] = np.clip(ij[:, 0], 0, self.shape[0] - 1)
        ij[:, 1] = np.clip(ij[:, 1], 0, self.shape[1] - 1)
        return ij[:, 0] * self.shape[1] + ij[:, 1]

    def rest_height(self, pts: np.ndarray) -> tuple[float, np.ndarray]:
        """The lift that sets `pts` down on the heap or the floor, and their cells."""
        cells = self.cells(pts[:, :2])
        need = np.max(self.top[cells] - pts[:, 2])
        return max(float(need), float(-pts[:, 2].min())), cells

    def add(self, pts: np.ndarray, cells: np.ndarray) -> None:
        np.maximum.at(self.top, cells, pts[:, 2])


def _heap(
    model: np.ndarray, n: int, params: BinParams, rng: np.random.Generator, diameter: float
) -> np.ndarray:
    """Poses of `n` copies dropped one by one into the bin (module documentation, step 2)."""
    length, width, _ = params.bin_size
    field = _HeightField(length, width, diameter / 40)
    centre = model.mean(0)
    local = model - centre
    # Where a copy comes to rest is searched on a subsample (fast); its final height is set
    # with every sample, so that the height field stays exact.
    coarse = local[rng.choice(len(local), size=min(len(local), 1000), replace=False)]
    half = np.array([length / 2, width / 2])
    steps = (
        diameter
        / 4
        * np.array([[np.cos(a), np.sin(a)] for a in np.linspace(0, 2 * np.pi, 8, endpoint=False)])
    )
    poses = np.zeros((n, 4, 4))
    for k in range(n):
        # Poured over the bin's middle; each candidate orientation then slides downhill.
        drop = rng.normal(scale=params.pour_spread * np.array([length, width]))
        best = None
        for rot in _random_rotations(rng, params.candidates):
            p = coarse @ rot.T
            # The footprint of every sample stays inside the walls.
            flat = local @ rot[:2].T
            lo, hi = -half - flat.min(0), half - flat.max(0)

            def rest(xy: np.ndarray, p: np.ndarray = p) -> float:
                return field.rest_height(p + np.array([xy[0], xy[1], 0.0]))[0]

            xy = np.clip(drop, lo, np.maximum(lo, hi))
            z = rest(xy)
            for _ in range(params.slide_steps):
                moves = [np.clip(xy + s, lo, np.maximum(lo, hi)) for s in steps]
                heights = [rest(m) for m in moves]
                j = int(np.argmin(heights))
                if heights[j] >= z - 1e-3 * diameter:
                    break
                xy, z = moves[j], heights[j]
            if best is None or z < best[0]:
                best = (z, rot, xy)
        assert best is not None
        _, rot, xy = best
        p = local @ rot.T + np.array([xy[0], xy[1], 0.0])
        lift, cells = field.rest_height(p)
        p[:, 2] += lift
        field.add(p, cells)
        poses[k] = np.eye(4)
        poses[k, :3, :3] = rot
        poses[k, :3, 3] = np.array([xy[0], xy[1], lift]) - rot @ centre
    return poses


# --- scenes -------------------------------------------------------------------------------


def make_bin_scene(seed: int = 0, params: BinParams | None = None) -> BinScene:
    """Build one seeded bin scene (see the module documentation)."""
    params = params or BinParams()
    rng = _scene_rng(params.model, seed)
    data_dir = params.data_dir or default_data_dir()
    raw = _model_points(params.model, str(data_dir) if data_dir else None)
    diameter = params.part_fraction * params.bin_size[0]
    model = raw * (diameter / float(np.linalg.norm(raw.max(0) - raw.min(0))))
    n = int(rng.integers(params.copies[0], params.copies[1] + 1))
    poses = _heap(model, n, params, rng, diameter)
    cam = _Camera.over_bin(params)
    zbuf, owner, seen, alone = _render(cam, model, poses, params)
    scan, ids = _sense(cam, zbuf, owner, params, rng)
    frac = np.where(alone > 0, seen / np.maximum(alone, 1), 0.0)
    order = np.lexsort((-seen, -frac))
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    return BinScene(
        scan=scan,
        scan_ids=ids,
        model_points=model,
        poses=poses,
        visible_fraction=frac,
        visible_pixels=seen,
        alone_pixels=alone,
        rank=rank,
        sensor=cam.position,
        voxel_size=diameter * params.voxel_fraction,
        diameter=diameter,
        model=params.model,
        seed=int(seed),
        params=params,
    )


def save_bin_scene(scene: BinScene, path: str | Path) -> None:
    """Write a scene as a compressed .npz (arrays and a JSON header; no pickle)."""
    header = {
        "version": _VERSION,
        "model": scene.model,
        "seed": scene.seed,
        "voxel_size": scene.voxel_size,
        "diameter": scene.diameter,
        "params": asdict(scene.params),
    }
    np.savez_compressed(
        path,
        header=np.array(json.dumps(header)),
        scan=scene.scan,
        scan_ids=scene.scan_ids,
        model_points=scene.model_points,
        poses=scene.poses,
        visible_fraction=scene.visible_fraction,
        visible_pixels=scene.visible_pixels,
        alone_pixels=scene.alone_pixels,
        rank=scene.rank,
        sensor=scene.sensor,
    )


def load_bin_scene(path: str | Path) -> BinScene:
    """Read a scene :func:`save_bin_scene` wrote."""
    with np.load(path, allow_pickle=False) as z:
        header = json.loads(str(z["header"]))
        if header.get("version") != _VERSION:
            raise ValueError(f"{path}: bin scene format {header.get('version')}, need {_VERSION}")
        p: dict[str, Any] = {
            k: tuple(v) if isinstance(v, list) else v for k, v in header["params"].items()
        }
        params = BinParams(**p)
        arrays = {k: z[k] for k in z.files if k != "header"}
    return BinScene(
        **arrays,
        voxel_size=float(header["voxel_size"]),
        diameter=float(header["diameter"]),
        model=header["model"],
        seed=int(header["seed"]),
        params=params,
    )


def bin_scene_cached(cache_dir: str | Path | None, seed: int, params: BinParams) -> BinScene:
    """The scene for (params, seed), read from `cache_dir` when built before with the same
    parameters, else built (and written there when a folder is given)."""
    if cache_dir is None:
        return make_bin_scene(seed, params)
    key = zlib.crc32(json.dumps([_VERSION, asdict(params)], sort_keys=True).encode())
    path = Path(cache_dir) / f"{params.model.replace('/', '_')}_{seed}_{key:08x}.npz"
    if path.is_file():
        return load_bin_scene(path)
    scene = make_bin_scene(seed, params)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_bin_scene(scene, path)
    return scene

"""Point clouds to correspondences: voxel downsampling, normals, FPFH and descriptor matching.

Thin, checked wrappers over the Rust core (parallel, GIL released). Conventions follow Open3D:
voxel downsampling averages each voxel; neighbourhoods are "hybrid" (at most `max_nn` points
within `radius`); FPFH is Open3D's 33-bin descriptor, equal to Open3D 0.20's output (a test
checks it), with ``variant="pcl"`` for PCL's form (no own-histogram term), which is what early
Open3D wrote to its feature files.

>>> import numpy as np, pointclm.preprocessing as pp   # doctest: +SKIP
>>> model = pp.describe(model_points, voxel_size=0.005, away_from=model_points.mean(0))
>>> scene = pp.describe(scan_points, voxel_size=0.005)            # normals towards the sensor
>>> m = pp.match_features(model.descriptors, scene.descriptors)  # top 10,000, sample 1000
>>> corr = np.hstack([model.points[m.source], scene.points[m.target]])
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from . import _core
from .errors import InputError
from .interop.open3d import open3d_points
from .registration import as_matrix, as_threads

__all__ = [
    "DescribedCloud",
    "DescriptorMatcher",
    "Matches",
    "FLIPPED_FPFH_BINS",
    "compute_fpfh",
    "describe",
    "estimate_normals",
    "estimate_viewpoint",
    "MAX_TERRACED_SHARE",
    "terraced_share",
    "point_spacing",
    "noise_level",
    "scan_scales",
    "flip_fpfh",
    "orient_towards",
    "match_features",
    "voxel_downsample",
]


def as_positive(value: float, name: str) -> float:
    # bool and str convert with float() but are not lengths: refused, as register refuses them.
    real = isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    )
    try:
        v = float(value) if real else math.nan
    except OverflowError:  # an int beyond float range
        v = math.inf
    if not real:
        raise InputError(f"{name} must be a number, got {value!r}")
    if not (math.isfinite(v) and v > 0):
        raise InputError(f"{name} must be a positive finite number, got {value!r}")
    return v


#: Largest count the core takes (its sizes are 64-bit); the core bounds what it allocates.
MAX_COUNT = 2**63 - 1


def as_count(value: int, name: str, minimum: int) -> int:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | np.integer)
        or not minimum <= value <= MAX_COUNT
    ):
        raise InputError(f"{name} must be an int in [{minimum}, 2**63 - 1], got {value!r}")
    return int(value)


def as_flag(value: bool, name: str) -> bool:
    if not isinstance(value, bool | np.bool_):
        raise InputError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def as_point(value: ArrayLike, name: str) -> tuple[float, float, float]:
    try:
        a = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{name} must be 3 finite numbers, got {value!r}") from None
    if a.shape != (3,) or not np.isfinite(a).all():
        raise InputError(f"{name} must be 3 finite numbers, got {value!r}")
    return (float(a[0]), float(a[1]), float(a[2]))


def as_points(x: ArrayLike, name: str) -> np.ndarray:
    # Open3D clouds and meshes are read where every entry point first checks its points.
    a = as_matrix(open3d_points(x, name), name, 3)
    if len(a) == 0:
        raise InputError(f"{name} is empty: need at least one point")
    return a


def rotation_deviation(rotations: np.ndarray) -> np.ndarray:
    """``||R^T R - I||_F`` of each of (K, 3, 3) finite `rotations`."""
    return np.linalg.norm(rotations.transpose(0, 2, 1) @ rotations - np.eye(3), axis=(1, 2))


def are_rotations(rotations: np.ndarray) -> np.ndarray:
    """Which of (K, 3, 3) finite `rotations` the core takes for rotations up to rounding (and
    replaces by the nearest one): within `_core.MAX_ROTATION_DEVIATION` of orthonormal
    (:func:`rotation_deviation`), with a positive determinant."""
    within = rotation_deviation(rotations) <= _core.MAX_ROTATION_DEVIATION
    return within & (np.linalg.det(rotations) > 0)


def voxel_downsample(points: ArrayLike, voxel_size: float) -> np.ndarray:
    """The centroid of the points in each occupied voxel (M, 3), ordered by voxel index."""
    return _core.voxel_downsample(
        as_points(points, "points"), as_positive(voxel_size, "voxel_size")
    )


def estimate_normals(
    points: ArrayLike,
    radius: float,
    max_nn: int = 30,
    *,
    towards: ArrayLike | None = None,
    away_from: ArrayLike | None = None,
    num_threads: int | None = None,
) -> np.ndarray:
    """Unit normals (N, 3) by PCA over at most `max_nn` neighbours within `radius`.

    The sign points `towards` a viewpoint (a scan's sensor; the default is the origin, where
    most scanners put it) or `away_from` an inner point (a complete model's centroid).
    """
    if towards is not None and away_from is not None:
        raise InputError("give towards= or away_from=, not both")
    t = None if towards is None else as_point(towards, "towards")
    a = None if away_from is None else as_point(away_from, "away_from")
    if t is None and a is None:
        t = (0.0, 0.0, 0.0)
    return _core.estimate_normals(
        as_points(points, "points"),
        as_positive(radius, "radius"),
        as_count(max_nn, "max_nn", 3),
        towards=t,
        away_from=a,
        num_threads=as_threads(num_threads),
    )


#: Above this :func:`terraced_share` pointclm fits a scan's normals within twice the radius.
MAX_TERRACED_SHARE: float = _core.MAX_TERRACED_SHARE


def terraced_share(
    points: ArrayLike,
    radius: float,
    viewpoint: ArrayLike = (0.0, 0.0, 0.0),
    *,
    num_threads: int | None = None,
) -> float:
    """How far a range scan's depth steps make flat terraces at `radius`, seen from
    `viewpoint` (its sensor; the origin for a scan in its sensor's frame).

    A depth sensor quantises depth in steps that grow with the square of the range; on a
    surface turned away from the sensor each step is a flat terrace facing it, and normals
    fitted within one terrace are the line of sight. This is the share of the points whose
    normals within `radius` turn towards the line of sight against those within twice it (by
    more than 30 degrees), less the share turning away, as noise turns them: about 0 for a
    scan without steps, up to 1. Above :data:`MAX_TERRACED_SHARE` (0.1) pointclm fits the
    scan's normals within twice `radius` (docs/concepts/point-clouds.md).
    """
    return float(
        _core.terraced_share(
            as_points(points, "points"),
            as_positive(radius, "radius"),
            as_point(viewpoint, "viewpoint"),
            num_threads=as_threads(num_threads),
        )
    )


def compute_fpfh(
    points: ArrayLike,
    normals: ArrayLike,
    radius: float,
    max_nn: int = 100,
    *,
    variant: str = "open3d",
    num_threads: int | None = None,
) -> np.ndarray:
    """FPFH descriptors (N, 33) over at most `max_nn` neighbours within `radius`.

    `variant` is "open3d" (current Open3D: the weighted neighbour histograms plus the point's
    own) or "pcl" (the neighbour part only).
    """
    if not isinstance(variant, str) or variant not in ("open3d", "pcl"):
        raise InputError(f"variant must be 'open3d' or 'pcl', got {variant!r}")
    p = as_points(points, "points")
    n = as_matrix(normals, "normals", 3)
    if len(n) != len(p):
        raise InputError(f"need one normal per point: {len(p)} points, {len(n)} normals")
    return _core.compute_fpfh(
        p,
        n,
        as_positive(radius, "radius"),
        as_count(max_nn, "max_nn", 2),
        variant=variant,
        num_threads=as_threads(num_threads),
    )


#: FPFH's 33 bins are three 11-bin histograms of the pair features (f1: the angle theta in
#: [-pi, pi], f2: alpha, f3: phi, both in [-1, 1]). Flipping every normal negates the
#: Darboux frame's u and v and keeps w, so f1 and f3 change sign and f2 does not (PCL's
#: ``computePairFeatures``; its swap rule compares absolute angles, so it is unchanged):
#: the first and last histograms run backwards. A cloud's descriptors under the opposite
#: orientation are thus a reindexing, with no second FPFH pass.
FLIPPED_FPFH_BINS = np.concatenate(
    [np.arange(10, -1, -1), np.arange(11, 22), np.arange(32, 21, -1)]
)


def flip_fpfh(descriptors: ArrayLike) -> np.ndarray:
    """The FPFH descriptors (N, 33) the same points would have with every normal flipped."""
    d = as_matrix(descriptors, "descriptors", 33)
    return np.ascontiguousarray(d[:, FLIPPED_FPFH_BINS])


#: Points scored per candidate eye by `estimate_viewpoint` (a stride through the cloud):
#: enough for a stable tenth percentile, and the cost stays bounded on large scans.
VIEWPOINT_SAMPLE = 2000


def _sphere(n: int) -> np.ndarray:
    """`n` nearly uniform unit vectors (a Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    a = np.pi * (1.0 + 5.0**0.5) * i
    return np.stack([r * np.cos(a), r * np.sin(a), z], axis=1)


def estimate_viewpoint(
    points: ArrayLike, normals: ArrayLike, n_directions: int = 256, num_threads: int | None = None
) -> np.ndarray:
    """A point from which one sign rule orients every normal consistently (3,).

    Unoriented normals get their sign from a line of sight; the sign of a normal seen
    edge-on is a coin toss. The eye chosen sees the fewest normals edge-on: the highest
    tenth percentile of ``|cos|`` between normal and line of sight. Candidates: the origin
    (sensor frames put the sensor there), the cloud's centroid (inside a closed or convex
    surface, which every normal faces), and points 2, 8 and 1000 cloud radii from the
    centroid in `n_directions` directions (a sensor near, at a usual distance, and as good
    as at infinity). A single range scan is seen head-on from its sensor, so the result is
    that sensor or a point that orients like it, up to one global sign (its mirror image
    behind the surface, or the inside of a convex object): which side is outside is left
    to the caller (:func:`pointclm.register_point_clouds` asks which sign makes the scan's
    descriptors look like the model's). The eyes are scored in Rust
    (:func:`pointclm._core.edge_on_scores`) on `num_threads` threads.
    """
    p = as_points(points, "points")
    n = as_matrix(normals, "normals", 3)
    if len(n) != len(p):
        raise InputError(f"need one normal per point: {len(p)} points, {len(n)} normals")
    step = max(1, math.ceil(len(p) / VIEWPOINT_SAMPLE))
    p, n = p[::step], n[::step]
    centre = p.mean(0)
    radius = max(float(np.linalg.norm(p - centre, axis=1).max()), np.finfo(float).tiny)
    dirs = _sphere(as_count(n_directions, "n_directions", 1))
    eyes = np.vstack(
        [np.zeros((1, 3)), centre[None]] + [centre + r * radius * dirs for r in (2.0, 8.0, 1e3)]
    )
    tenth = (len(p) - 1) // 10
    scores = _core.edge_on_scores(
        np.ascontiguousarray(p),
        np.ascontiguousarray(n),
        eyes,
        tenth,
        num_threads=as_threads(num_threads),
    )
    return np.asarray(eyes[int(np.argmax(scores))], dtype=np.float64)


def point_spacing(points: ArrayLike) -> float:
    """The median distance from a point to its nearest other point (0 for fewer than 2), over
    at most 5000 evenly strided points. About 50 ms for a 240,000-point frame: the index must
    hold every point, since a sample's spacing depends on how the cloud was sampled (a
    random fifth of a grid is spaced 0.47 x sqrt(5) grid steps, not sqrt(5)). Computed by the
    core (``pointclm::scene::voxel::point_spacing``), as the default voxel is."""
    return scan_scales(points)[0]


def scan_scales(points: ArrayLike, scale: float | None = None) -> tuple[float, float]:
    """:func:`point_spacing` and :func:`noise_level` (at `scale`) of one cloud, over one
    index (which dominates both for a large frame)."""
    p = as_points(points, "points")
    if scale is not None:
        scale = as_positive(scale, "scale")
    spacing, noise = _core.scan_scales(p, scale)
    return float(spacing), float(noise)


#: :func:`noise_level`'s neighbourhoods without a scale: planes fitted to each sampled point's
#: nearest `NOISE_NEIGHBOURS` points and to 4 times as many (twice the radius on a surface).
NOISE_NEIGHBOURS = 24


def noise_level(points: ArrayLike, scale: float | None = None) -> float:
    """The standard deviation of the points about their surface, estimated at (at most) 500
    evenly strided points; 0 for fewer than 8 points.

    At each sampled point, planes are fitted to its nearest points (`NOISE_NEIGHBOURS`, or with
    `scale` as many as a surface holds within that radius at the cloud's point spacing, 8 to
    48) and to 4 times as many. Each residual variance is the noise's plus the surface's
    curvature term, which grows with the fourth power of the neighbourhood's radius, so the
    two sizes separate them (``(v1 r2^4 - v2 r1^4) / (r2^4 - r1^4)``, r each neighbourhood's
    RMS radius); the median over the points is taken. Why two sizes: one plane's residual
    mixes noise with curvature (on the benchmark scans the curvature term is as large as the
    sensor's noise), and a neighbourhood as small as the noise fits a blob instead of a plane.
    Why a scale: on a sparse cloud a fixed count spans the object, beyond what curvature's
    fourth power describes. Computed by the core (``pointclm::scene::voxel::noise_level``)."""
    return scan_scales(points, scale)[1]


def orient_towards(points: ArrayLike, normals: ArrayLike, viewpoint: ArrayLike) -> np.ndarray:
    """`normals` with each sign flipped to face `viewpoint` (as `estimate_normals`' towards)."""
    p = as_points(points, "points")
    n = as_matrix(normals, "normals", 3)
    eye = np.asarray(as_point(viewpoint, "viewpoint"))
    facing = np.einsum("ij,ij->i", eye - p, n) >= 0.0
    return np.where(facing[:, None], n, -n)


@dataclass(frozen=True)
class DescribedCloud:
    """A cloud ready for matching: (downsampled) points, normals, FPFH, and stage seconds."""

    points: np.ndarray
    normals: np.ndarray
    descriptors: np.ndarray
    timings: dict[str, float] = field(default_factory=dict)


def describe(
    points: ArrayLike,
    voxel_size: float | None,
    *,
    normals: ArrayLike | None = None,
    towards: ArrayLike | None = None,
    away_from: ArrayLike | None = None,
    normal_radius: float | None = None,
    normal_max_nn: int = 30,
    feature_radius: float | None = None,
    feature_max_nn: int = 100,
    variant: str = "open3d",
    num_threads: int | None = None,
) -> DescribedCloud:
    """Downsample to `voxel_size` (None: keep the points), estimate normals (unless given, which
    needs ``voxel_size=None``) and compute FPFH, both over one k-d tree of the cloud.

    Radii default to the usual multiples of the voxel (Open3D's registration tutorials): 2 for
    normals, 5 for descriptors. Without a voxel size both radii must be given. Normals face
    `towards` a viewpoint (default: the origin) or away from `away_from`, as in
    :func:`estimate_normals`; the result equals :func:`voxel_downsample`,
    :func:`estimate_normals` and :func:`compute_fpfh` run one after the other.
    """
    pts = as_points(points, "points")
    threads = as_threads(num_threads)  # checked before any work
    v = None
    if voxel_size is not None:
        v = as_positive(voxel_size, "voxel_size")
        if normals is not None:
            raise InputError(
                "normals given with voxel_size: downsampling would leave them unaligned; "
                "pass voxel_size=None with normals, or drop the normals"
            )
        normal_radius = 2.0 * v if normal_radius is None else normal_radius
        feature_radius = 5.0 * v if feature_radius is None else feature_radius
    if normal_radius is None and normals is None or feature_radius is None:
        raise InputError("without voxel_size, give feature_radius (and normal_radius or normals)")
    if not isinstance(variant, str) or variant not in ("open3d", "pcl"):
        raise InputError(f"variant must be 'open3d' or 'pcl', got {variant!r}")
    if normals is None:
        assert normal_radius is not None
        nrm, estimate = None, _normal_args(towards, away_from, normal_radius, normal_max_nn)
    else:
        nrm, estimate = as_matrix(normals, "normals", 3), {}
        if len(nrm) != len(pts):
            raise InputError(f"need one normal per point: {len(pts)} points, {len(nrm)} normals")
    p, n, d, timings = _core.describe(
        pts,
        v,
        nrm,
        feature_radius=as_positive(feature_radius, "feature_radius"),
        feature_max_nn=as_count(feature_max_nn, "feature_max_nn", 2),
        variant=variant,
        num_threads=threads,
        **estimate,
    )
    return DescribedCloud(p, n, d, timings)


def _normal_args(
    towards: ArrayLike | None, away_from: ArrayLike | None, radius: float, max_nn: int
) -> dict[str, Any]:
    """`describe`'s checked arguments for estimating normals."""
    if towards is not None and away_from is not None:
        raise InputError("give towards= or away_from=, not both")
    return {
        "towards": None if towards is None else as_point(towards, "towards"),
        "away_from": None if away_from is None else as_point(away_from, "away_from"),
        "normal_radius": as_positive(radius, "normal_radius"),
        "normal_max_nn": as_count(max_nn, "normal_max_nn", 3),
    }


# Descriptor matching lives in its own module; these names stay reachable here.
from .matcher import (  # noqa: E402, F401
    WINDOW_CANDIDATES,
    DescriptorMatcher,
    Matches,
    match_features,
)

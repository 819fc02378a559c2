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
from .registration import as_matrix, as_seed, as_threads

__all__ = [
    "DescribedCloud",
    "DescriptorMatcher",
    "Matches",
    "FLIPPED_FPFH_BINS",
    "compute_fpfh",
    "describe",
    "estimate_normals",
    "estimate_viewpoint",
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
    a = as_matrix(x, name, 3)
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
    at most 5000 evenly strided points. About 50 ms for a 240,000-point frame: the tree must
    hold every point, since a sample's spacing depends on how the cloud was sampled (a
    random fifth of a grid is spaced 0.47 x sqrt(5) grid steps, not sqrt(5))."""
    p = as_points(points, "points")
    return _spacing(_tree(p), p) if len(p) >= 2 else 0.0


def scan_scales(points: ArrayLike, scale: float) -> tuple[float, float]:
    """:func:`point_spacing` and :func:`noise_level` (at `scale`) of one cloud, over one
    k-d tree (which dominates both for a large frame)."""
    p = as_points(points, "points")
    scale = as_positive(scale, "scale")
    if len(p) < 2:
        return 0.0, 0.0
    tree = _tree(p)
    return _spacing(tree, p), _noise(tree, p, scale) if len(p) >= 8 else 0.0


def _tree(p: np.ndarray) -> Any:
    from scipy.spatial import cKDTree

    return cKDTree(p, balanced_tree=False, compact_nodes=False)


def _spacing(tree: Any, p: np.ndarray) -> float:
    d, _ = tree.query(p[:: max(1, len(p) // 5000)], k=2)
    return float(np.median(d[:, 1]))


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
    fourth power describes."""
    p = as_points(points, "points")
    if scale is not None:
        scale = as_positive(scale, "scale")
    return _noise(_tree(p), p, scale) if len(p) >= 8 else 0.0


def _noise(tree: Any, p: np.ndarray, scale: float | None) -> float:
    queries = p[:: max(1, len(p) // 500)]
    k1 = NOISE_NEIGHBOURS
    if scale is not None:
        spacing = float(np.median(tree.query(queries, k=2)[0][:, 1]))
        k1 = int(np.clip(round(np.pi * (scale / max(spacing, 1e-300)) ** 2), 8, 48))
    k2 = min(4 * k1, len(p))
    k1 = max(4, k2 // 4)
    _, idx = tree.query(queries, k=k2)
    fits = []
    for k in (k1, k2):
        nb = p[idx[:, :k]]
        centred = nb - nb.mean(axis=1, keepdims=True)
        cov = np.einsum("mki,mkj->mij", centred, centred)
        radius2 = np.einsum("mki,mki->m", centred, centred) / k
        # A plane fitted to k points takes 3 of their degrees of freedom.
        fits.append((np.linalg.eigvalsh(cov)[:, 0] / (k - 3), radius2))
    (v1, r1), (v2, r2) = fits
    span = r2**2 - r1**2
    ok = span > 0.0
    if not ok.any():
        return float(np.sqrt(max(np.median(v1), 0.0)))
    variance = (v1[ok] * r2[ok] ** 2 - v2[ok] * r1[ok] ** 2) / span[ok]
    return float(np.sqrt(max(np.median(variance), 0.0)))


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


@dataclass(frozen=True)
class Matches:
    """Descriptor matches, most salient (smallest descriptor distance) first."""

    source: np.ndarray
    target: np.ndarray
    distance: np.ndarray

    def __len__(self) -> int:
        return len(self.source)

    def correspondences(self, source_points: ArrayLike, target_points: ArrayLike) -> np.ndarray:
        """(N, 6) rows (source xyz | target xyz) for these matches."""
        s = np.asarray(source_points, dtype=np.float64)
        t = np.asarray(target_points, dtype=np.float64)
        return np.ascontiguousarray(np.hstack([s[self.source], t[self.target]]))

    def normals(self, source_normals: ArrayLike, target_normals: ArrayLike) -> np.ndarray:
        """(N, 6) rows (source normal | target normal) for these matches: the ``normals=`` of
        :func:`pointclm.register`."""
        return self.correspondences(source_normals, target_normals)


def match_features(
    source: ArrayLike,
    target: ArrayLike,
    *,
    top_k: int = 10_000,
    mutual: bool = False,
    n_samples: int | None = 1000,
    seed: int = 0,
    num_threads: int | None = None,
    k: int = 1,
) -> Matches:
    """Each target descriptor's `k` nearest source descriptors (exact), the `top_k` closest
    matches kept (if `mutual`, only pairs where the target is also among the source's `k`
    nearest: mutual nearest neighbours for k = 1), then `n_samples` drawn at random with
    `seed` (None keeps all), as the paper's appendix builds its correspondences.

    k > 1 matters for several copies of a model in one scan: each scan point proposes its k
    best model points, so every copy gets matches, not only the one a model point likes best.
    """
    return DescriptorMatcher(source, target, k=k, num_threads=num_threads).match(
        top_k=top_k, mutual=mutual, n_samples=n_samples, seed=seed
    )


def _descriptor_pair(source: ArrayLike, target: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    s = as_matrix(source, "source descriptors", None)
    t = as_matrix(target, "target descriptors", None)
    if len(s) == 0 or len(t) == 0:
        raise InputError("need at least one source and one target descriptor")
    if s.shape[1] != t.shape[1]:
        raise InputError(f"descriptor lengths differ: source {s.shape[1]}, target {t.shape[1]}")
    return s, t


#: Nearest target rows per source row that a windowed mutual check (`DescriptorMatcher.match`'s
#: ``window``) looks at: a heap shows a few dozen copies, so a source point's true match on
#: each lies among its few dozen nearest; more cost time and found no more copies on the
#: validation bins (128: recall of half-visible copies 0.362 vs 0.356).
WINDOW_CANDIDATES = 64
#: The corner offsets (in cells) of the 8 cubes of `DescriptorMatcher`'s windows holding a cell.
_CUBE_CORNERS = np.array([(i, j, k) for i in (0, 1) for j in (0, 1) for k in (0, 1)])


class DescriptorMatcher:
    """:func:`match_features` for one model and one scan, matched whole or in parts.

    Each target row's `k` nearest source rows do not depend on the other target rows, so the
    matcher finds them once (on the first call that needs them) and every later
    :meth:`match` of a subset of the target rows reuses them; only the mutual check, which
    depends on which target rows take part, is redone. Peeling in
    :func:`pointclm.register_point_clouds` matches the scan points no accepted copy explains,
    pass after pass, this way. The results equal :func:`match_features` on the subset.
    """

    def __init__(
        self,
        source: ArrayLike,
        target: ArrayLike,
        *,
        k: int = 1,
        num_threads: int | None = None,
        target_points: ArrayLike | None = None,
    ) -> None:
        self.source, self.target = _descriptor_pair(source, target)
        self.k = as_count(k, "k", 1)
        self.num_threads = as_threads(num_threads)
        self.target_points = None
        if target_points is not None:
            self.target_points = as_matrix(target_points, "target_points", 3)
            if len(self.target_points) != len(self.target):
                raise InputError(
                    f"need one target point per target descriptor: {len(self.target)} "
                    f"descriptors, {len(self.target_points)} points"
                )
        self._nearest: tuple[np.ndarray, np.ndarray] | None = None
        self._nearest_targets: np.ndarray | None = None

    def match(
        self,
        rows: ArrayLike | None = None,
        *,
        top_k: int = 10_000,
        mutual: bool = False,
        n_samples: int | None = 1000,
        seed: int = 0,
        window: float | None = None,
        mutual_rank: int = 1,
    ) -> Matches:
        """Matches of the target rows `rows` (None: all; indices into the target); the
        returned target indices index the whole target.

        `window` (with `mutual`, ``k=1`` and the matcher's `target_points`) makes the mutual
        check local: the target points are covered by overlapping cubes of side `window` (a
        grid of stride `window` / 2), and a pair counts as mutual when the source point is
        the target point's nearest and the target point is the source point's nearest among
        the target rows of some cube (:data:`WINDOW_CANDIDATES` nearest looked at). Why: in a
        heap of identical parts a source point has one true match per visible copy, and the
        scene-wide mutual check keeps at most one of them; within a window about a part wide
        each copy keeps its own, while the check still drops most of the pairs a source point
        would not choose.

        `mutual_rank` (with `mutual` and ``k=1``, no `window`) relaxes the check by rank
        instead of place: a pair counts when the source point is the target point's nearest
        and the target point is among the source point's `mutual_rank` nearest target rows
        taking part (looked for among its :data:`WINDOW_CANDIDATES` nearest of the whole
        target, or `mutual_rank` if more). 1 is the mutual nearest neighbour check. Why: in a
        heap each copy holds one true match of a source point, and the copies compete for it;
        ranked, a source point keeps a match on as many copies as the rank allows, wherever
        they lie."""
        n = None if n_samples is None else as_count(n_samples, "n_samples", 1)
        rank = as_count(mutual_rank, "mutual_rank", 1)
        seed = as_seed(seed)
        kept, mutual_only = as_count(top_k, "top_k", 1), as_flag(mutual, "mutual")
        nearest = None
        if window is not None or rank > 1:
            picked = self._relaxed(rows, window, rank, mutual_only)
            if len(picked) == 0:
                empty = np.zeros(0, dtype=np.int64)
                return Matches(empty, empty.copy(), np.zeros(0))
            rows, mutual_only = picked, False  # the pairs left are the mutual ones
        elif rows is not None:
            picked = self._rows(rows)
        if rows is not None:
            near, d2 = self._nearest_sources()
            nearest = (near[picked], d2[picked])
        src, tgt, dist = _core.match_features(
            self.source,
            self.target if rows is None else self.target[picked],
            top_k=kept,
            mutual=mutual_only,
            n_samples=n,
            seed=seed,
            num_threads=self.num_threads,
            k=self.k,
            nearest=nearest,
        )
        return Matches(src, tgt if rows is None else picked[tgt], dist)

    def _rows(self, rows: ArrayLike) -> np.ndarray:
        picked = np.asarray(rows)
        if picked.dtype == bool:
            if picked.shape != (len(self.target),):
                raise InputError(
                    f"a boolean rows mask needs one entry per target row ({len(self.target)}), "
                    f"got shape {picked.shape}"
                )
            picked = np.flatnonzero(picked)
        if picked.ndim != 1 or not np.issubdtype(picked.dtype, np.integer):
            raise InputError("rows must be a 1-D array of target row indices or a boolean mask")
        if len(picked) == 0:
            raise InputError("rows is empty: need at least one target row to match")
        if picked.min() < 0 or picked.max() >= len(self.target):
            raise InputError(f"rows must index the {len(self.target)} target rows")
        return picked.astype(np.int64)

    def _window(self, window: float, mutual: bool) -> float:
        side = as_positive(window, "window")
        if not mutual or self.k != 1:
            raise InputError("window needs mutual=True and k=1: it makes the mutual check local")
        if self.target_points is None:
            raise InputError("window needs the matcher's target_points (the target's positions)")
        return side

    def _relaxed(
        self, rows: ArrayLike | None, window: float | None, rank: int, mutual: bool
    ) -> np.ndarray:
        """The target rows (of `rows`) in a pair the windowed or ranked mutual check keeps."""
        picked = np.arange(len(self.target)) if rows is None else self._rows(rows)
        if window is None:
            if not mutual or self.k != 1:
                raise InputError(
                    "mutual_rank needs mutual=True and k=1: it relaxes the mutual check"
                )
            return self._rank_mutual(picked, rank)
        if rank > 1:
            raise InputError("give window or mutual_rank, not both: each relaxes the check")
        return self._windowed_mutual(picked, self._window(window, mutual))

    def _nearest_targets_of_sources(self, k: int) -> np.ndarray:
        """Every source row's `k` (at least :data:`WINDOW_CANDIDATES`) nearest target rows of
        the whole target, nearest first; found once, again only for a larger `k`."""
        k = max(k, WINDOW_CANDIDATES)
        if self._nearest_targets is None or self._nearest_targets.shape[1] < min(
            k, len(self.target)
        ):
            self._nearest_targets, _ = _core.nearest_descriptors(
                self.target, self.source, k=k, num_threads=self.num_threads
            )
        return self._nearest_targets

    def _candidates(self, picked: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """`(source row, target row)` for each of the rows of `picked` among every source row's
        nearest target rows (:meth:`_nearest_targets_of_sources`, found once over the whole
        target; a call on fewer rows looks at those of the list among them), by source row,
        then nearest first."""
        nearest = self._nearest_targets_of_sources(k)
        taking_part = np.zeros(len(self.target), dtype=bool)
        taking_part[picked] = True
        src, col = np.nonzero(taking_part[nearest])
        return src, nearest[src, col]

    def _rank_mutual(self, picked: np.ndarray, rank: int) -> np.ndarray:
        """The rows of `picked` whose nearest source row counts them among its `rank`
        nearest rows of `picked` (:meth:`match`'s `mutual_rank`), in increasing order."""
        src, tgt = self._candidates(picked, rank)
        # The rank among the rows taking part: the position within the source row's run.
        place = np.arange(len(src)) - np.searchsorted(src, src)
        src, tgt = src[place < rank], tgt[place < rank]
        near, _ = self._nearest_sources()
        return np.unique(tgt[near[tgt, 0] == src])

    def _windowed_mutual(self, picked: np.ndarray, side: float) -> np.ndarray:
        """The rows of `picked` whose pair with their nearest source row is mutual within
        some cube of side `side` (:meth:`match`), in increasing order."""
        assert self.target_points is not None
        src, tgt = self._candidates(picked, WINDOW_CANDIDATES)
        # A point in cell c (of side / 2) lies in the cubes whose corner cells are c - {0, 1}^3.
        cells = np.floor((self.target_points - self.target_points.min(0)) / (side / 2))
        cells = cells.astype(np.int64) + 1
        shape = tuple(int(v) for v in cells.max(0) + 1)
        corners = cells[tgt][:, None, :] - _CUBE_CORNERS[None]
        cube = np.ravel_multi_index(tuple(np.moveaxis(corners, 2, 0)), shape)
        n_cubes = int(np.prod(shape))
        key = (np.repeat(src, 8) * n_cubes + cube.reshape(-1)).astype(np.int64)
        _, first = np.unique(key, return_index=True)  # each source row's best in each cube
        best_src, best_tgt = np.repeat(src, 8)[first], np.repeat(tgt, 8)[first]
        near, _ = self._nearest_sources()
        mutual = best_tgt[near[best_tgt, 0] == best_src]
        return np.unique(mutual)

    def _nearest_sources(self) -> tuple[np.ndarray, np.ndarray]:
        if self._nearest is None:
            self._nearest = _core.nearest_descriptors(
                self.source, self.target, k=self.k, num_threads=self.num_threads
            )
        return self._nearest

"""`register_point_clouds`: a model and a scan in, the pose of every copy out.

The one-call path for users who have clouds, not correspondences: load (arrays or files),
downsample, normals, FPFH, descriptor matching (:mod:`pointclm.preprocessing`), the
registration pipeline with lengths scaled to the voxel size, then ICP refinement and
verification of its poses on the clouds (:mod:`pointclm.refinement`), then peeling: further
passes over the scan points no accepted copy explains, until one adds no copy. Every stage is
timed.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from functools import cache, cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from . import _core
from . import preprocessing as pp
from ._core import Instance, RegistrationResult
from .config import Config
from .cues import similarity
from .docstrings import fill
from .embedding import Embedding, resolve
from .errors import InputError
from .refinement import (
    _KEEP_ALL,
    MAX_CONTRADICTION,
    MAX_SHARED,
    MIN_FITNESS,
    MIN_SEEN,
    MIN_VISIBLE_FITNESS,
    RefinedPoses,
    RefinementContext,
    explained_scan_points,
    fit_tightness,
    loose_poses,
    pose_stability,
    resolve_flips,
    stability_factor,
)
from .registration import as_config, as_threads, register

__all__ = [
    "REFINED_THRESHOLDS",
    "CloudInstance",
    "PointCloudRegistration",
    "HEAP_EMPTY_ROUNDS",
    "SCENE_EXTENT",
    "HEAP_MIN_COPIES",
    "HEAP_RANK",
    "HEAP_VOTED_POSES",
    "VOTED_MIN_RELATIVE_FITNESS",
    "HEAP_WINDOW",
    "MAX_PEEL_ROUNDS",
    "PEEL_CLUSTER_LEVEL",
    "PEEL_RADIUS_VOXELS",
    "Pass",
    "cloud_base_config",
    "cloud_config",
    "default_voxel_size",
    "file_viewpoint",
    "register_point_clouds",
    "scaled_config",
    "unexplained_points",
]

#: The default voxel is the model's bounding-box diagonal over this: about 1,500 points on a
#: typical object whatever its units, and an FPFH radius (5 voxels) of 1/8 of its size.
VOXELS_PER_DIAGONAL = 40

#: The training-free thresholds (synthetic units, scaled to the voxel) when the poses are
#: refined and verified on the clouds, as `register_point_clouds` does by default. Verification
#: rejects wrong poses far better than pruning does, so the correspondence stage should
#: propose every plausible group: almost no density pruning (tau_n 1) and small clusters.
#: Chosen on 200 realistic scenes of the five non-bunny models (armadillo, bed, dragon, happy,
#: bathtub) by ``benchmarks/realistic_thresholds.py --refine`` (BENCHMARKS.md). Without
#: refinement `Config()`'s thresholds stay: there every wrong pose is returned.
REFINED_THRESHOLDS: dict[str, Any] = {"tau_s": 0.8, "tau_n": 1, "min_cluster_size": 3}

#: With peeling, each pass clusters into at least as many groups as the normalised Laplacian
#: has eigenvalues below this (`Config.cluster_level`): with dozens of copies the largest
#: eigengap comes early, and the extra groups cost only verification, which peeling's
#: visibility test settles. Chosen against the eigengap alone and 0.5 on the validation models
#: only: bins of dragon, happy, armadillo, bathtub and bed (half-visible copies found 56 -> 77
#: of 187) and 30 realistic scenes of the same models through `register_point_clouds`
#: (F1 0.39 -> 0.45; 0.5: 0.36). Not used without peeling: on the correspondence benchmark's
#: refined row (no viewpoint, so no visibility test) the extra groups cost precision.
PEEL_CLUSTER_LEVEL = 0.7


#: The voxel is at least this many times the scan's point spacing (median distance to the
#: nearest other point): a voxel finer than the sensor's sampling leaves holes in the
#: downsampled scan, and the normal and FPFH radii (2 and 5 voxels) then hold too few points.
#: Chosen on the realistic validation scenes thinned to 30 % and 10 % of their points (spacing
#: 0.9 and 1.3 voxels): F1 0.38 and 0 with the model's voxel, 0.56 and 0.25 with 1.4 spacings
#: (sqrt 2); the full scans (0.66-0.72 voxel) keep the model's voxel and their F1 (0.76).
#: Only the scan's: growing the voxel for models sampled nearly as coarsely (0.83 voxel)
#: cost copies there (F1 0.67).
MIN_VOXEL_SPACINGS = 1.4
#: The voxel is at least this many times the scan's noise (standard deviation about its
#: surface, :func:`pointclm.preprocessing.noise_level`): normals are fitted over 2 voxels, and
#: noise above a fifth of that radius turns them (and FPFH with them) at random.
MIN_VOXEL_NOISES = 2.5
#: The noise is estimated at the scale of the normals, 2 model voxels.
NOISE_SCALE_VOXELS = 2.0
#: Stray points (a depth sensor's flying pixels, multipath): a downsampled scan point with fewer
#: than this many others within the normals' radius (2 voxels) cannot fit a plane; a surface
#: gives each about 12. When they are more than `MAX_STRAY_SHARE` of the scan they are dropped
#: before normals and FPFH, and so before verification, where they hid wrong poses' free space.
#: Below it the scan is left exactly as it is: real scans have isolated points too (0.01-0.1 %
#: on the realistic benchmark's, about 3 % on the bins', where a structured-light sensor keeps
#: a few pixels of steep faces), and those are surface, not strays. Chosen on the validation
#: sets (BENCHMARKS.md, issue 18, stop 31): strays up to 5 % of the scan cost nothing, 10 % and
#: 20 % cost a fifth of the F1 unless dropped.
STRAY_NEIGHBOURS = 3
MAX_STRAY_SHARE = 0.05


def default_voxel_size(model_points: ArrayLike, scan_points: ArrayLike | None = None) -> float:
    """The model's bounding-box diagonal / 40; with `scan_points`, at least
    :data:`MIN_VOXEL_SPACINGS` times the scan's point spacing
    (:func:`pointclm.preprocessing.point_spacing`) and :data:`MIN_VOXEL_NOISES` times its
    noise (:func:`pointclm.preprocessing.noise_level`)."""
    p = np.asarray(model_points, dtype=np.float64)
    voxel = float(np.linalg.norm(p.max(0) - p.min(0))) / VOXELS_PER_DIAGONAL
    if scan_points is None:
        return voxel
    spacing, noise = pp.scan_scales(scan_points, NOISE_SCALE_VOXELS * voxel)
    return max(voxel, MIN_VOXEL_SPACINGS * spacing, MIN_VOXEL_NOISES * noise)


#: A scan reaching beyond this many model radii from its centroid is a scene (surfaces behind
#: the copies), whose own occlusions tell the side its sensor stood on (`_spans_a_scene`):
#: more than one copy's extent, so that one object alone never counts.
SCENE_EXTENT = 2.0

#: Peeling: a scan point within this many voxels of an accepted copy's posed model is
#: explained (the inlier distance of verification, 1.5 voxels, plus the scan's noise at edges).
PEEL_RADIUS_VOXELS = 2.0
#: Peeling stops after this many rounds (each round must add a copy to go on; a bin of 80
#: parts with about half visible needs a few rounds of several copies each).
MAX_PEEL_ROUNDS = 20
#: Once a pass matches as in a heap (`HEAP_MIN_COPIES`, or ``heap=True``), peeling stops only
#: after this many rounds in a row add no copy (elsewhere after one). Why: a round that adds
#: none leaves the same scan points, but the next one samples its matches and its RANSAC
#: anew (each round has its own seed), and in a heap many copies are left, so an empty round
#: is often the luck of the draw. On the validation bins 1, 2 and 3 found 0.425, 0.462 and
#: 0.470 of the half-visible copies with ``heap=True``, at ADD-S precision 0.988, 0.984 and
#: 0.982, in 1, 1.08 and 1.15 times the time (stop 33, BENCHMARKS.md).
HEAP_EMPTY_ROUNDS = 2

#: Once peeling has accepted this many copies, the scan is taken for a heap of identical parts
#: and the later passes relax the mutual check: by rank (`HEAP_RANK`, the default) or, with
#: ``mutual_window="auto"``, within windows (`HEAP_WINDOW`). A count is the scale-free
#: evidence of many copies: with `n` copies in view, the scene-wide mutual check leaves each
#: about 1/n of a model point's true matches.
#: Chosen on the validation sets only (BENCHMARKS.md, bins): the realistic validation scenes
#: (2 to 8 copies among clutter) accept at most 7, so 8 or more leaves them as they were; on
#: the validation bins 8, 10 and 12 found the same share of half-visible copies (0.316-0.318),
#: and 10 keeps a margin above a room scan's few copies.
HEAP_MIN_COPIES = 10
#: The windowed check's cube side in model diagonals for a heap (``mutual_window="auto"``),
#: with every match kept: the best of the sizes tried on the validation bins.
HEAP_WINDOW = 2.0
#: In a heap (`HEAP_MIN_COPIES`), the later passes' mutual check keeps a pair when the scan
#: point's best model match is that model point and the scan point is among that model point's
#: `HEAP_RANK` most similar scan points still unexplained (``heap_rank``; the matcher's
#: ``mutual_rank``). Why: a model point has one true match per visible copy, and a heap shows
#: a few dozen copies; 64 is every candidate the matcher looks at
#: (`pointclm.preprocessing.WINDOW_CANDIDATES`). On the validation bins ranks 16 and 64 found
#: 0.31 and 0.34 of the half-visible copies against 0.28 (BENCHMARKS.md, bins).
HEAP_RANK = 64
#: In a scan said to be a heap (``heap=True``), each peeling round also proposes this many
#: poses by voting with point pair features (:class:`pointclm._core.PpfModel`, Drost et al.,
#: CVPR 2010) over the scan points still unexplained, beside its clusters of descriptor
#: matches; refinement and verification judge both alike. Why: in a heap, FPFH's radius takes
#: in the neighbouring copies, so a hidden copy keeps too few true descriptor matches to form a
#: cluster (stop 36: 370 of 399 missed copies had no candidate near them), while two points of
#: one copy give the model's pair feature whatever lies around it. On the validation bins
#: 40 / 100 poses a round raised the ADD-S recall of half-visible copies 0.676 -> 0.852 / 0.885
#: at precision 0.981 / 0.975 (0.993 before), the 10 most visible copies' 0.527 -> 0.609 /
#: 0.645, in 1 / 1.17 times the time of 40 (BENCHMARKS.md, bins, stop 37). Only with
#: ``heap=True``: in the default's heap rounds (`HEAP_MIN_COPIES`) voting cost about three
#: times the time for ADD-S recall 0.564 -> 0.656 at precision 1.000 -> 0.953.
HEAP_VOTED_POSES = 100
#: A voted pose is kept only if it explains at least this share of the model relative to the
#: median copy accepted so far (``fitness``). Why: a voted pose has no descriptor support, and
#: in a heap a pose buried among the copies shows the sensor a fifth of the model, which a
#: scan patch explains perfectly (visible fitness 0.9-0.99, no contradiction); the copies of
#: one part in one scan show the sensor alike, so the scene's own copies set the floor. On the
#: validation bins wrong voted poses explained 0.35 (median; 0.55 at the 90th percentile) of
#: the median accepted copy's share, right ones 0.83; 0.5 / 0.6 kept 785 / 736 right poses
#: and 53 / 15 wrong ones of 849 / 251 (BENCHMARKS.md, bins, stop 37).
VOTED_MIN_RELATIVE_FITNESS = 0.6


def scaled_config(voxel_size: float, base: Config | None = None) -> Config:
    """`Config.for_voxel(voxel_size, base)` (kept under this name for existing callers):
    `base` (default `Config()`, synthetic units) in the units of clouds downsampled at
    `voxel_size`; the rule and its reasons are there."""
    return Config.for_voxel(voxel_size, base)


def cloud_config(
    voxel_size: float,
    model: Any = None,
    refine: bool = True,
    peel: bool = False,
    overrides: Mapping[str, Any] | None = None,
) -> Config:
    """`register_point_clouds`' config when none is given, in the clouds' units:
    :func:`cloud_base_config` (synthetic units) scaled by :meth:`Config.for_voxel`. `evaluate`
    uses the same on realistic scenes."""
    return Config.for_voxel(voxel_size, cloud_base_config(model, refine, peel, overrides))


def cloud_base_config(
    model: Any = None,
    refine: bool = True,
    peel: bool = False,
    overrides: Mapping[str, Any] | None = None,
) -> Config:
    """:func:`cloud_config` before its scaling to the voxel, in synthetic units: the
    thresholds for refined poses (`REFINED_THRESHOLDS`) or raw ones (`Config()`), or those
    recommended with `model` (:meth:`pointclm.embedding.Embedding.recommended_config`), with
    `peel` a cluster count of at least `PEEL_CLUSTER_LEVEL`'s, then `overrides` (field values
    in synthetic units, as the CLI's method flags give them)."""
    base = Config(**REFINED_THRESHOLDS) if refine else Config()
    if model is not None:
        emb = resolve(model)
        recommended = emb.recommended_config("point_clouds" if refine else "point_clouds_no_refine")
        base = recommended or base
    if refine:
        # Verification on the clouds judges every proposal far better than a count of
        # correspondences can, so the correspondence stage's a-contrario test would only
        # drop copies before they are looked at (on the validation scenes it left one
        # candidate where verification keeps several).
        base = replace(base, max_nfa=None)
        if peel and base.cluster_level is None:
            base = replace(base, cluster_level=PEEL_CLUSTER_LEVEL)
    return base.with_overrides(overrides)


@dataclass(frozen=True)
class CloudInstance:
    """One copy of the model in the scan, refined and verified on the clouds.

    ``fitness`` and ``inlier_rmse`` follow Open3D's ``evaluate_registration``: the share of the
    (downsampled) model's points with a scan point within 1.5 voxels, and their RMS distance.
    ``confidence`` in [0, 1] says how sure the pose is (instances come surest first): with a
    trusted viewpoint, the share of what the sensor could see of the copy at that pose that the
    scan explains, times one minus the share where the sensor saw free space
    (``visible_fitness``, ``contradiction``); without one, ``fitness``
    (:func:`pointclm.refinement.refine_poses`). With ``flips``, it is divided by one plus the
    number of turns of the pose that the scan supports as well (a near-symmetric part whose
    differing side the sensor did not see, :func:`pointclm.refinement.resolve_flips`).
    ``visible_rmse`` is the RMS distance of the explained model points the sensor could see (NaN
    without a trusted viewpoint): copies whose visible side fits more than 1.3 times as loosely
    as the scene's median copy are not returned (:func:`pointclm.refinement.loose_poses`), and
    among three or more, ``confidence`` is multiplied by ``min(1, median / visible_rmse)``
    (:func:`pointclm.refinement.fit_tightness`) and by how firmly the scan pins the pose down
    against the median copy (:func:`pointclm.refinement.stability_factor` of
    :func:`pointclm.refinement.pose_stability`).
    ``matches`` is the correspondence-stage instance the pose was refined from (its ``inliers``
    index the correspondences of the pass that proposed it,
    ``PointCloudRegistration.passes[pass_index].correspondences``; pass 0's are
    ``PointCloudRegistration.correspondences``), or None when the pose was proposed by point
    pair voting in a heap (`HEAP_VOTED_POSES`; no correspondence inliers).
    """

    transformation: np.ndarray
    fitness: float
    inlier_rmse: float
    matches: Instance | None
    confidence: float = float("nan")
    visible_fitness: float = float("nan")
    contradiction: float = float("nan")
    pass_index: int = 0
    visible_rmse: float = float("nan")

    @property
    def inliers(self) -> np.ndarray:
        if self.matches is None:
            return np.empty(0, dtype=np.int64)
        return np.asarray(self.matches.inliers)

    def __len__(self) -> int:
        return 0 if self.matches is None else len(self.matches)

    def __repr__(self) -> str:
        # One line a person reads: the scores and where the copy sits, not the 4 x 4 matrix.
        t = ", ".join(f"{v:.4g}" for v in np.asarray(self.transformation)[:3, 3])
        return (
            f"CloudInstance(fitness={self.fitness:.3f}, confidence={self.confidence:.3f}, "
            f"inlier_rmse={self.inlier_rmse:.3g}, pass_index={self.pass_index}, "
            f"matches={len(self)}, translation=[{t}])"
        )


@dataclass(frozen=True)
class Pass:
    """One pass of the correspondence stage over the scan points no accepted copy explained
    yet (pass 0: the whole scan)."""

    #: (N, 6) rows: downsampled model point | downsampled scan point.
    correspondences: np.ndarray
    result: RegistrationResult
    #: Indices into ``PointCloudRegistration.target_points`` of the scan points matched.
    scan_points: np.ndarray
    #: Copies this pass added to the accepted ones.
    added: int
    #: (K, 4, 4) poses proposed by point pair voting over ``scan_points`` (heap passes,
    #: `HEAP_VOTED_POSES`; empty otherwise), judged beside ``result``'s: an accepted pose's
    #: ``CloudInstance.matches`` is None when it came from here.
    voted: np.ndarray = field(default_factory=lambda: np.empty((0, 4, 4)))
    #: (D, 4, 4) poses of this pass that passed verification on a copy already accepted
    #: (peeling's duplicate check); their rotations relative to that copy's pose are the
    #: scene's own alternatives for :func:`pointclm.refinement.resolve_flips`.
    duplicates: np.ndarray = field(default_factory=lambda: np.empty((0, 4, 4)))

    def __repr__(self) -> str:
        return (
            f"Pass(correspondences={len(self.correspondences)}, candidates={len(self.result)}, "
            f"voted={len(self.voted)}, scan_points={len(self.scan_points)}, added={self.added}, "
            f"duplicates={len(self.duplicates)})"
        )


@dataclass(frozen=True)
class PointCloudRegistration:
    """The result of :func:`register_point_clouds`; ``print`` shows a summary.

    ``instances`` are the refined and verified copies, surest first (``confidence``).
    ``result`` is the correspondence stage's :class:`pointclm.RegistrationResult` over
    ``correspondences`` (rows: downsampled model point | downsampled scene point), before
    refinement.
    ``passes`` holds every pass of the correspondence stage: pass 0 over the whole scan, then
    one per peeling round over what the accepted copies leave unexplained.
    ``timings`` holds seconds per stage (load, downsample, normals, fpfh, matching, embedding,
    pruning, clustering, poses, refinement: pass 0's; peeling: every later pass; flips: the
    half-turned alternatives; total).
    ``viewpoint`` is the sensor position verification judged by (given, or a PCD file's
    ``VIEWPOINT``; None: none known, poses judged by the share of the model explained), and
    ``orientation`` says how the scan's normals were oriented. ``diagnosis`` explains an
    empty or doubtful result and what to try ("" when there is nothing to say).
    """

    result: RegistrationResult
    correspondences: np.ndarray
    source_points: np.ndarray
    target_points: np.ndarray
    voxel_size: float
    config: Config
    instances: list[CloudInstance] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    passes: list[Pass] = field(default_factory=list)
    viewpoint: np.ndarray | None = None
    orientation: str = ""
    diagnosis: str = ""

    @property
    def transformations(self) -> np.ndarray:
        """(M, 4, 4) T_target_source of every instance found."""
        if not self.instances:
            return np.zeros((0, 4, 4))
        return np.stack([inst.transformation for inst in self.instances])

    def __repr__(self) -> str:
        # A summary, not the arrays: what was found, how it was judged, where time went.
        lines = [
            f"PointCloudRegistration({len(self.instances)} instance(s) in "
            f"{len(self.target_points)} scan points at voxel {self.voxel_size:.4g}, "
            f"{len(self.passes)} pass(es), {self.timings.get('total', float('nan')):.2f} s)"
        ]
        lines += [f"  [{i}] {inst!r}" for i, inst in enumerate(self.instances)]
        if self.diagnosis:
            lines.append(f"  note: {self.diagnosis}")
        if self.orientation:
            lines.append(f"  scan normals: {self.orientation}")
        judged = "none known" if self.viewpoint is None else _xyz(self.viewpoint)
        lines.append(f"  verification viewpoint: {judged}")
        stages = ", ".join(f"{k} {v:.3f}" for k, v in self.timings.items() if k != "total")
        lines.append(f"  timings (s): {stages}")
        return "\n".join(lines)


def _xyz(p: ArrayLike) -> str:
    return "(" + ", ".join(f"{v:.4g}" for v in np.asarray(p, dtype=np.float64)) + ")"


def _load(cloud: Any, name: str) -> np.ndarray:
    if isinstance(cloud, str | os.PathLike):
        from .io import load_points

        return load_points(cloud)
    return pp.as_points(cloud, name)


def file_viewpoint(path: str | os.PathLike[str]) -> np.ndarray | None:
    """The sensor position a scan file records, or None: a PCD file's ``VIEWPOINT``
    translation (:func:`pointclm.io.pcd.read_pcd_viewpoint`; PCL's default, the origin with
    no rotation, counts as none, since PCL writes it for every cloud whatever its sensor).
    Other formats record none."""
    if not str(path).lower().endswith(".pcd"):
        return None
    from .io.pcd import read_pcd_viewpoint

    return read_pcd_viewpoint(path)


@fill
def register_point_clouds(
    source: ArrayLike | str | os.PathLike[str],
    target: ArrayLike | str | os.PathLike[str],
    voxel_size: float | None = None,
    config: Config | dict[str, Any] | None = None,
    seed: int = 0,
    *,
    model: Any = None,
    viewpoint: ArrayLike | None = None,
    top_k: int = 10_000,
    mutual: bool = True,
    n_samples: int | None = 1000,
    k: int = 1,
    mutual_window: float | str | None = None,
    heap_rank: int | None = HEAP_RANK,
    heap: bool | None = None,
    normals: bool = False,
    refine: bool = True,
    peel: bool = True,
    flips: bool = True,
    num_threads: int | None = None,
) -> PointCloudRegistration:
    """Find every copy of `source` (a complete model) in `target` (a scan).

    Parameters
    ----------
    source, target : array_like or path
        (N, 3) points, or a file :func:`pointclm.io.load_points` reads (meshes are sampled).
    %(voxel_size)s
    %(cloud_config)s
    %(cloud_seed)s
    %(cloud_model)s
    %(viewpoint)s
    %(matching)s
    %(mutual_window)s
    %(heap_rank)s
    %(heap)s
    %(cloud_normals)s
    %(refine)s
    %(peel)s
    %(flips)s
    %(num_threads)s

    %(cloud_returns)s
    """
    t0 = time.perf_counter()
    embedding, view = _checked_arguments(num_threads, refine, mutual, model, viewpoint, flips)
    window, rank = _heap_arguments(mutual_window, heap_rank, heap, mutual, k)
    src, tgt = _load(source, "source"), _load(target, "target")
    view = _recorded_viewpoint(target) if view is None else view
    t_load = time.perf_counter() - t0
    voxel = _voxel_size(src, tgt, voxel_size)
    src_d = pp.describe(src, voxel, away_from=src.mean(0), num_threads=num_threads)
    scan = _describe_target(tgt, voxel, view, viewpoint is None, src_d, num_threads)
    tgt_d, orientation, view, guessed = scan
    matching, heaped = _matchings(top_k, mutual, n_samples, k, window, src, rank, heap)
    args = (src_d, tgt_d, voxel, view, matching, _matcher(src_d, tgt_d, k, num_threads))
    run = _Run(*args, normals, seed, embedding, num_threads, heaped, guessed, heap)
    reg = _register(run, config, refine, peel, flips)
    return replace(reg, orientation=orientation, timings=reg.timings | _total(t_load, t0))


def _total(t_load: float, t0: float) -> dict[str, float]:
    """The timings of reading the files and of the whole call (started at `t0`)."""
    return {"load": t_load, "total": time.perf_counter() - t0}


def _matching(
    top_k: int, mutual: bool, n_samples: int | None, window: float | None, src: np.ndarray
) -> dict[str, Any]:
    """The matcher's arguments of every pass; a window (in model diagonals) in the clouds'
    units."""
    matching: dict[str, Any] = {"top_k": top_k, "mutual": mutual, "n_samples": n_samples}
    if window is not None:
        matching["window"] = window * float(np.linalg.norm(src.max(0) - src.min(0)))
    return matching


def _matchings(
    top_k: int,
    mutual: bool,
    n_samples: int | None,
    k: int,
    window: float | str | None,
    src: np.ndarray,
    rank: int | None = None,
    heap: bool | None = None,
) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """The matcher's arguments of the first passes, and those once a heap is recognised
    (None: no switch)."""
    fixed = None if isinstance(window, str) else window  # "auto" starts scene-wide
    matching = _matching(top_k, mutual, n_samples, fixed, src)
    if not mutual or k != 1 or heap is False:
        return matching, None  # only the mutual check can be relaxed
    if window == "auto":
        return matching, _matching(top_k, True, None, HEAP_WINDOW, src)
    if window is None and rank is not None and rank > 1:
        return matching, dict(matching, mutual_rank=rank)
    return matching, None


def _matcher(
    src_d: pp.DescribedCloud, tgt_d: pp.DescribedCloud, k: int, num_threads: int | None
) -> pp.DescriptorMatcher:
    """The run's matcher: the scan's positions come along for a windowed mutual check."""
    return pp.DescriptorMatcher(
        src_d.descriptors,
        tgt_d.descriptors,
        k=k,
        num_threads=num_threads,
        target_points=tgt_d.points,
    )


def _checked_arguments(
    num_threads: int | None,
    refine: bool,
    mutual: bool,
    model: Any,
    viewpoint: ArrayLike | None,
    flips: bool = False,
) -> tuple[Embedding | None, tuple[float, float, float] | None]:
    """What of `register_point_clouds`' arguments can be checked before the files are read:
    the model resolved (a bad model fails before the work) and the viewpoint as a point."""
    as_threads(num_threads)
    pp.as_flag(refine, "refine")
    pp.as_flag(mutual, "mutual")
    pp.as_flag(flips, "flips")
    embedding = None if model is None else resolve(model)
    view = None if viewpoint is None else pp.as_point(viewpoint, "viewpoint")
    return embedding, view


def _heap_arguments(
    window: float | str | None, rank: int | None, heap: bool | None, mutual: bool, k: int
) -> tuple[float | str | None, int | None]:
    """`mutual_window`, `heap_rank` and `heap` checked before the files are read."""
    if heap is not None:
        pp.as_flag(heap, "heap")
    return _window_diagonals(window, mutual, k), (
        None if rank is None else pp.as_count(rank, "heap_rank", 1)
    )


def _window_diagonals(window: float | str | None, mutual: bool, k: int) -> float | str | None:
    """`mutual_window` checked before the files are read."""
    if window is None or window == "auto":
        return window
    if isinstance(window, str):
        raise InputError(f'mutual_window must be a number, "auto" or None, got {window!r}')
    side = pp.as_positive(window, "mutual_window")
    if not mutual or k != 1:
        raise InputError("mutual_window needs mutual=True and k=1: it makes the check local")
    return side


def _recorded_viewpoint(target: Any) -> tuple[float, float, float] | None:
    """The sensor position a `target` file records (:func:`file_viewpoint`), or None."""
    if not isinstance(target, str | os.PathLike):
        return None
    found = file_viewpoint(target)
    return None if found is None else pp.as_point(found, "viewpoint")


def _voxel_size(src: np.ndarray, tgt: np.ndarray, voxel_size: float | None) -> float:
    """The given voxel, checked, or the clouds' default (:func:`default_voxel_size`)."""
    voxel = (
        default_voxel_size(src, tgt)
        if voxel_size is None
        else pp.as_positive(voxel_size, "voxel_size")
    )
    if not voxel > 0:
        raise ValueError("the source model has zero extent: give voxel_size")
    return voxel


@dataclass(frozen=True)
class _Run:
    """What every pass of one `register_point_clouds` call shares."""

    src_d: pp.DescribedCloud
    tgt_d: pp.DescribedCloud
    voxel: float
    #: The sensor position verification judges by; None: none known.
    viewpoint: tuple[float, float, float] | None
    matching: dict[str, Any]
    #: Matches scan points to the model; finds each scan point's nearest model descriptors
    #: once for every pass.
    matcher: pp.DescriptorMatcher
    normals: bool
    seed: int
    #: The learned embedding, resolved once for every pass; None: training-free.
    model: Embedding | None
    num_threads: int | None
    #: The matching of the passes once the accepted copies show a heap (``heap_rank`` or
    #: ``mutual_window="auto"``); None: every pass uses `matching`.
    heap_matching: dict[str, Any] | None = None
    #: The viewpoint is the origin of a scan in its sensor's frame, not given: the first
    #: pass confirms it (:func:`_confirm_viewpoint`).
    guessed_viewpoint: bool = False
    #: Whether the scan is a heap (``heap``): None once `HEAP_MIN_COPIES` copies are
    #: accepted, True in every pass.
    heap: bool | None = None

    @cached_property
    def refiner(self) -> RefinementContext:
        """Refinement against this scan, its cloud-only part built once for every pass."""
        return RefinementContext(
            self.src_d.points,
            self.tgt_d.points,
            self.voxel,
            viewpoint=self.viewpoint,
            target_normals=self.tgt_d.normals,
            num_threads=self.num_threads,
        )

    @cached_property
    def scan_tree(self) -> Any:
        """A scipy k-d tree of the scan, built once for peeling and the final ranking."""
        from scipy.spatial import cKDTree

        return cKDTree(self.tgt_d.points)

    @cached_property
    def voter(self) -> _core.PpfModel:
        """The model's point pair features tabled for voting, built once for every pass; its
        diameter is the model's bounding-box diagonal."""
        pts = self.src_d.points
        diameter = float(np.linalg.norm(pts.max(0) - pts.min(0)))
        return _core.PpfModel(pts, self.src_d.normals, diameter, max_poses=HEAP_VOTED_POSES)

    def voted_poses(self, rows: np.ndarray, offset: int) -> np.ndarray:
        """Poses voted by point pairs among the scan points `rows`, most voted first (the
        references start at `offset`, so that each round votes from other points)."""
        poses, _ = self.voter.poses(
            self.tgt_d.points, self.tgt_d.normals, rows, offset, num_threads=self.num_threads
        )
        return poses

    def features(
        self,
        corr: np.ndarray,
        cfg: Config,
        normals: np.ndarray | None = None,
        sims: np.ndarray | None = None,
    ) -> np.ndarray | None:
        """The learned embedding of `corr` (in the units of `cfg`) with the cues its network
        takes, or None without one."""
        if self.model is None:
            return None
        return self.model.embed(
            corr, cfg.sigma_d, num_threads=self.num_threads, normals=normals, similarity=sims
        )


def _describe_target(
    tgt: np.ndarray,
    voxel: float,
    view: tuple[float, float, float] | None,
    not_given: bool,
    src_d: pp.DescribedCloud,
    num_threads: int | None,
) -> tuple[pp.DescribedCloud, str, tuple[float, float, float] | None, bool]:
    """:func:`_describe_scan`, and the viewpoint of the run: `view` (given, or recorded in the
    file when `not_given`), else a guess the first pass confirms (the last value True): the
    origin of a scan in its sensor's frame, or the sensor position estimated from the scan."""
    tgt_d, orientation, guess = _describe_scan(tgt, voxel, view, src_d, num_threads)
    if view is not None and not_given:
        orientation += " (the file's VIEWPOINT)"
    guessed = view is None and guess is not None
    return tgt_d, orientation, guess if guessed else view, guessed


def _describe_scan(
    tgt: np.ndarray,
    voxel: float,
    view: tuple[float, float, float] | None,
    src_d: pp.DescribedCloud,
    num_threads: int | None,
) -> tuple[pp.DescribedCloud, str, tuple[float, float, float] | None]:
    """The scan downsampled, with normals and FPFH, how its normals were oriented, and where
    its sensor likely stood (None: unknown), for the first pass to confirm: the origin when the
    scan is in its sensor's frame, else the position estimated from the scan
    (:func:`pointclm._core.estimate_sensor` on both sides, :func:`_side_by_sight`).

    With a viewpoint the normals face it. A scan in its sensor's frame (one view from the
    origin, :func:`pointclm._core.looks_like_one_view`, and :func:`_in_front` of it) has its
    sensor at the origin, and the normals face that. Otherwise they are oriented from the
    origin when the scan is one view from it, else from a point that orients them consistently
    (:func:`pointclm.preprocessing.estimate_viewpoint`); either fixes them up to one global
    sign; the model's normals face outwards, and so do those of surfaces a sensor saw, so the
    sign kept is the one whose descriptors lie nearer the model's (median distance from each
    scan descriptor to its nearest model descriptor).
    Flipping every normal only reindexes FPFH (:func:`pointclm.preprocessing.flip_fpfh`),
    so both signs cost one FPFH pass.
    """
    t0 = time.perf_counter()
    pts = _without_strays(pp.voxel_downsample(tgt, voxel), voxel, num_threads)
    t1 = time.perf_counter()
    if view is not None:
        radii: dict[str, Any] = {"normal_radius": 2.0 * voxel, "feature_radius": 5.0 * voxel}
        described = pp.describe(pts, None, towards=view, num_threads=num_threads, **radii)
        described.timings["downsample"] = t1 - t0
        return described, f"towards the viewpoint {_xyz(view)}", None
    raw = pp.estimate_normals(pts, 2.0 * voxel, num_threads=num_threads)
    # One view from the origin orients the normals consistently (up to one sign); with every
    # point in front of it, the sign too (see `_in_front`).
    one_view = bool(_core.looks_like_one_view(pts, (0.0, 0.0, 0.0), voxel))
    sensor_frame = one_view and _in_front(pts)
    eye = np.zeros(3) if one_view else pp.estimate_viewpoint(pts, raw, num_threads=num_threads)
    nrm = pp.orient_towards(pts, raw, eye)
    t2 = time.perf_counter()
    desc = pp.compute_fpfh(pts, nrm, 5.0 * voxel, num_threads=num_threads)
    t3 = time.perf_counter()
    guess: tuple[float, float, float] | None = (0.0, 0.0, 0.0) if sensor_frame else None
    if sensor_frame:
        text = (
            "no viewpoint: towards the origin, a sensor's position (the scan is one view from it)"
        )
    elif one_view:
        nrm, desc, text, _ = _signed_by_descriptors(src_d, nrm, desc, eye, num_threads)
    else:
        nrm, desc, text, guess = _signed_by_sight(src_d, pts, voxel, nrm, desc, eye, num_threads)
    timings = {
        "downsample": t1 - t0,
        "normals": t2 - t1 + time.perf_counter() - t3,
        "fpfh": t3 - t2,
    }
    return pp.DescribedCloud(pts, nrm, desc, timings), text, guess


def _signed_by_sight(
    src_d: pp.DescribedCloud,
    pts: np.ndarray,
    voxel: float,
    nrm: np.ndarray,
    desc: np.ndarray,
    eye: np.ndarray,
    num_threads: int | None,
) -> tuple[np.ndarray, np.ndarray, str, tuple[float, float, float] | None]:
    """The scan's normals (oriented towards `eye`) and descriptors with the sign of the side its
    sensor stood on, how they were oriented, and the sensor position estimated there (None
    when the scan does not look like one view from it). The side: where the scan hides fewer
    of its own points (:func:`_side_by_sight`), else the sign whose descriptors lie nearer the
    model's (:func:`_signed_by_descriptors`), which alone decides for a scan of about one
    model's extent (`_spans_a_scene`)."""
    towards = (eye, 2 * pts.mean(0) - eye)
    sides = [_core.estimate_sensor(pts, voxel, pp.as_point(p, "towards")) for p in towards]

    @cache
    def one_view(side: int) -> bool:
        return bool(_core.looks_like_one_view(pts, sides[side][0], voxel))

    seen_from = _side_by_sight(sides, one_view) if _spans_a_scene(pts, src_d.points) else None
    if seen_from is None:
        nrm, desc, text, flipped = _signed_by_descriptors(src_d, nrm, desc, eye, num_threads)
        seen_from = int(flipped)
    else:
        if seen_from == 1:
            nrm, desc = -nrm, pp.flip_fpfh(desc)
        text = (
            f"no viewpoint: towards the estimated sensor position {_xyz(sides[seen_from][0])}, "
            "from which the scan hides the fewest of its own points"
        )
    return nrm, desc, text, sides[seen_from][0] if one_view(seen_from) else None


def _spans_a_scene(scan: np.ndarray, model: np.ndarray) -> bool:
    """Whether the scan reaches beyond `SCENE_EXTENT` model radii from its centroid: a scene
    with surfaces behind the copies, not one object alone. Why: the side a sensor stood on
    shows in what the scan's surfaces hide of one another, which needs depth behind them; a
    single object seen from behind hides little of itself, and on the Stanford bunny scans the
    count favoured the wrong side (BENCHMARKS.md, stop 35)."""
    reach = float(np.linalg.norm(scan - scan.mean(0), axis=1).max())
    size = float(np.linalg.norm(model - model.mean(0), axis=1).max())
    return reach > SCENE_EXTENT * size


def _side_by_sight(
    sides: list[tuple[tuple[float, float, float], float, int]], one_view: Callable[[int], bool]
) -> int | None:
    """Which of two sensor estimates (:func:`pointclm._core.estimate_sensor` on each side of
    the scan) is its sensor: the one the scan looks like one view from (`one_view`, by index),
    hiding fewer of its
    points by more than two standard errors; None when that does not decide (a flat scene
    looks alike from both sides, a merged scan like one view from neither). Why: from its
    mirror image behind the surfaces, a single view's foreground hides its background, and
    that count picked the right side on the 15 realistic validation scans wherever it decided
    (the flat beds tie), where the descriptors' sign test erred in 2 (BENCHMARKS.md)."""
    (_, h0, n0), (_, h1, n1) = sides
    low = min(h0, h1)
    noise = 2.0 * np.sqrt(low * (1.0 - low) / max(min(n0, n1), 1))
    if abs(h0 - h1) <= noise:
        return None
    best = 0 if h0 < h1 else 1
    return best if one_view(best) else None


def _signed_by_descriptors(
    src_d: pp.DescribedCloud,
    nrm: np.ndarray,
    desc: np.ndarray,
    eye: np.ndarray,
    num_threads: int | None,
) -> tuple[np.ndarray, np.ndarray, str, bool]:
    """The scan's normals (oriented towards `eye`) and descriptors with the sign whose
    descriptors lie nearer the model's, how they were oriented, and whether they were flipped
    (they then face away from `eye`)."""
    flipped = pp.flip_fpfh(desc)
    towards = _median_distance(src_d.descriptors, desc, num_threads)
    away = _median_distance(src_d.descriptors, flipped, num_threads)
    side = "away from" if away < towards else "towards"
    text = (
        f"no viewpoint: {side} the estimated point {_xyz(eye)}, the sign whose descriptors "
        f"match the model's (median distance {min(towards, away):.3g} vs "
        f"{max(towards, away):.3g})"
    )
    if away < towards:
        return -nrm, flipped, text, True
    return nrm, desc, text, False


def _without_strays(points: np.ndarray, voxel: float, num_threads: int | None) -> np.ndarray:
    """The downsampled scan without its stray points (fewer than `STRAY_NEIGHBOURS` others
    within the normals' radius, 2 voxels) when they are more than `MAX_STRAY_SHARE` of it;
    else as it is."""
    stray = _core.isolated_points(points, 2.0 * voxel, STRAY_NEIGHBOURS, num_threads=num_threads)
    if stray.all():
        # Nothing would be left to fit a normal to, nor to register.
        raise InputError(
            f"the scan shows no surface at voxel {voxel:.4g}: each of its {len(points)} "
            f"downsampled point(s) has fewer than {STRAY_NEIGHBOURS} others within "
            f"{2.0 * voxel:.4g} (2 voxels). Pass a denser scan, or a larger voxel_size"
        )
    return points[~stray] if stray.mean() > MAX_STRAY_SHARE else points


def _in_front(points: np.ndarray) -> bool:
    """Whether every point lies in front of the origin (within an open half-space). A scan that
    is one view from the origin and in front of it is in its sensor's frame: the sensor saw
    the outer side of every surface, so normals facing it need no sign test. Points all around
    the origin may be a scan from inside a room or a closed object about its centre, which
    want opposite signs: the descriptors decide there (the median-distance test, which a scan
    made mostly of planes leaves close to a coin toss: 32.4 against 32.6 on PCL's Kinect
    frame)."""
    r = np.linalg.norm(points, axis=1)
    if len(points) < 3 or not np.all(r > 0.0):
        return False
    unit = points / r[:, None]
    return bool(np.all(unit @ unit.mean(0) > 0.0))


def _median_distance(reference: np.ndarray, queries: np.ndarray, num_threads: int | None) -> float:
    """Median distance from (a stride of at most `pp.VIEWPOINT_SAMPLE` of) `queries` to their
    nearest `reference` descriptors."""
    rows = queries[:: max(1, -(-len(queries) // pp.VIEWPOINT_SAMPLE))]
    _, dist2 = _core.nearest_descriptors(reference, rows, k=1, num_threads=num_threads)
    return float(np.median(np.sqrt(np.maximum(dist2, 0.0))))


def _register(
    run: _Run, config: Config | dict[str, Any] | None, refine: bool, peel: bool, flips: bool = False
) -> PointCloudRegistration:
    """The correspondence stage, refinement and verification, then peeling: every stage
    after the clouds are described."""
    t1 = time.perf_counter()
    everything = np.arange(len(run.tgt_d.points))
    first = run.heap_matching if _is_heap(run, []) else None
    corr, pair_normals, sims = _match(run, everything, run.seed, first)
    t2 = time.perf_counter()
    if len(corr) < 3:
        raise ValueError(
            f"only {len(corr)} correspondences survived matching: the clouds share too few "
            "similar local shapes (try mutual=False, a smaller voxel_size, or check the units)"
        )
    cfg = _config(config, run.voxel, run.model, refine, peel)
    features = run.features(corr, cfg, pair_normals, sims)
    t3 = time.perf_counter()
    result = register(
        corr, features, cfg, run.seed, num_threads=run.num_threads, normals=pair_normals
    )
    t4 = time.perf_counter()
    run, refined, tags = _verify(run, result, refine)
    passes = [Pass(corr, result, everything, len(tags))]
    t5 = time.perf_counter()
    if refine and peel and len(tags):
        refined, tags = _peel(run, refined, tags, passes, cfg)
    t6 = time.perf_counter()
    refined, tags = _settle(run, refined, tags, refine and flips, passes)
    t7 = time.perf_counter()
    stage = dict(result.timings)
    timings = {
        "load": 0.0,
        "downsample": run.src_d.timings["downsample"] + run.tgt_d.timings["downsample"],
        "normals": run.src_d.timings["normals"] + run.tgt_d.timings["normals"],
        "fpfh": run.src_d.timings["fpfh"] + run.tgt_d.timings["fpfh"],
        "matching": t2 - t1,
        "embedding": t3 - t2,
        **{s: stage.get(s, 0.0) for s in ("pruning", "clustering", "poses")},
        "registration": t4 - t3,
        "refinement": t5 - t4,
        "peeling": t6 - t5,
        "flips": t7 - t6,
        "total": 0.0,
    }
    return PointCloudRegistration(
        result=result,
        correspondences=corr,
        source_points=run.src_d.points,
        target_points=run.tgt_d.points,
        voxel_size=run.voxel,
        config=cfg,
        instances=_instances(refined, tags, passes),
        timings=timings,
        passes=passes,
        viewpoint=None if run.viewpoint is None else np.array(run.viewpoint),
        diagnosis=_diagnose(run, refined, passes, refine),
    )


def _confirm_viewpoint(
    run: _Run, result: RegistrationResult
) -> tuple[_Run, RefinedPoses, list[tuple[int, int]]]:
    """Pass 0 of a run whose viewpoint is a guess (the origin of a scan in its sensor's
    frame, or the sensor position estimated from the scan): the run with it, when verification
    from there keeps the pose that the model share ranks first, else the run without a
    viewpoint; pass 0's poses verified accordingly.

    Why: a scan looks like one view from many points near its sensor (at most 12 % of it
    hidden from there), which is enough to orient normals but not to judge poses, where 1 %
    of a model in free space rejects them. A Stanford range scan 0.06-0.19 m from the origin
    looks like one view from it, and every pose fails there; a depth camera's frame keeps
    its surest copy. An estimate 10 degrees off costs about a twentieth of the realistic F1,
    20 degrees a fifth (BENCHMARKS.md, stop 35). ICP does not depend on the viewpoint, so the
    poses are refined once and judged both ways."""
    blind_run = replace(run, viewpoint=None, guessed_viewpoint=False)
    fitted = blind_run.refiner.refine(
        np.asarray(result.transformations).reshape(-1, 4, 4),
        **_KEEP_ALL,
        max_shared=1.0,
        num_threads=run.num_threads,
    )
    # Back in the input order, so that both verdicts break ties as one refinement would.
    order = np.argsort(fitted.origin, kind="stable")
    poses, source = fitted.transformations[order], fitted.origin[order]
    seen, seen_tags = _judge(run, poses, source)
    blind, blind_tags = _judge(blind_run, poses, source)
    kept = set(seen.origin.tolist())
    if kept and (len(blind.origin) == 0 or int(blind.origin[0]) in kept):
        return run, seen, seen_tags
    # Nothing either way confirms nothing: the run goes on (and explains) without a viewpoint.
    return blind_run, blind, blind_tags


def _judge(
    run: _Run, poses: np.ndarray, source: np.ndarray
) -> tuple[RefinedPoses, list[tuple[int, int]]]:
    """Pass 0's poses, refined already (`source`: the correspondence stage's instance of each),
    verified by the run's rules without ICP."""
    judged = run.refiner.refine(poses, icp=False, num_threads=run.num_threads)
    judged = judged._replace(origin=source[judged.origin])
    return judged, [(0, int(o)) for o in judged.origin]


def _verify(
    run: _Run, result: RegistrationResult, refine: bool
) -> tuple[_Run, RefinedPoses, list[tuple[int, int]]]:
    """Pass 0's poses refined and verified (or, without `refine`, only scored, in the
    correspondence stage's order), each with its (pass, instance of that pass's result), and
    the run that goes on (:func:`_confirm_viewpoint` settles a guessed viewpoint)."""
    if run.guessed_viewpoint and refine:
        return _confirm_viewpoint(run, result)
    refined = run.refiner.refine(
        np.asarray(result.transformations).reshape(-1, 4, 4),
        icp=refine,
        **({} if refine else {**_KEEP_ALL, "max_shared": 1.0}),
        num_threads=run.num_threads,
    )
    tags = [(0, int(o)) for o in refined.origin]
    if not refine:
        # Unverified poses keep the correspondence stage's order (most inliers first).
        keep = np.argsort(refined.origin)
        refined, tags = _take(refined, keep), [tags[i] for i in keep]
    return run, refined, tags


def _instances(
    refined: RefinedPoses, tags: list[tuple[int, int]], passes: list[Pass]
) -> list[CloudInstance]:
    def matches(tag: tuple[int, int]) -> Instance | None:
        found = passes[tag[0]].result
        return found.instances[tag[1]] if tag[1] < len(found) else None

    return [
        CloudInstance(
            refined.transformations[i],
            float(refined.fitness[i]),
            float(refined.inlier_rmse[i]),
            matches(tags[i]),
            float(refined.confidence[i]),
            float(refined.visible_fitness[i]),
            float(refined.contradiction[i]),
            tags[i][0],
            float(refined.visible_rmse[i]),
        )
        for i in range(len(tags))
    ]


def _diagnose(run: _Run, refined: RefinedPoses, passes: list[Pass], refine: bool) -> str:
    """Why the result is empty or doubtful, and what to try; "" when there is nothing to say."""
    first = passes[0]
    no_view = (
        " The scan's normals were oriented without a sensor position: if you know it, pass "
        "viewpoint=."
        if run.viewpoint is None
        else ""
    )
    if len(refined.origin) and run.viewpoint is not None and refine and not refined.by_visibility:
        return (
            f"the scan does not look like one view from the viewpoint {_xyz(run.viewpoint)} "
            "(too much of it lies behind other scan points seen from there), so poses were "
            "judged by the share of the model they explain; if that is not where the sensor "
            "stood, pass its position, or viewpoint=None to orient the normals without one."
        )
    if len(refined.origin):
        return ""
    if len(first.result) == 0:
        return (
            f"nothing found: no consistent group among the {len(first.correspondences)} "
            "descriptor correspondences, so no candidate pose. The scan may not hold the "
            f"model, or its local shapes differ at voxel {run.voxel:.3g}: try a smaller "
            "voxel_size, mutual=False or n_samples=None." + no_view
        )
    return _rejected(run, first) + no_view


def _rejected(run: _Run, first: Pass) -> str:
    """Why verification rejected every candidate pose: the best one's scores against the
    rules (one more ICP of the candidates, only when nothing was found)."""
    scores = run.refiner.refine(
        np.asarray(first.result.transformations).reshape(-1, 4, 4),
        **_KEEP_ALL,
        max_shared=1.0,
        num_threads=run.num_threads,
    )
    n = len(first.result)
    head = f"nothing found: verification rejected all {n} candidate pose(s)"
    if not scores.by_visibility:
        best = float(scores.fitness.max()) if len(scores.fitness) else 0.0
        return (
            f"{head}: the best explains {best:.0%} of the model (needs {MIN_FITNESS:.0%}). "
            "A partial or occluded view explains little of a model."
        )
    i = int(np.argmax(scores.confidence))
    return (
        f"{head} as seen from the viewpoint {_xyz(run.viewpoint or (0, 0, 0))}: the best "
        f"explains {scores.visible_fitness[i]:.0%} of what the sensor could see of it (needs "
        f"{MIN_VISIBLE_FITNESS:.0%}), {scores.contradiction[i]:.0%} of it lies where the "
        f"sensor saw free space (at most {MAX_CONTRADICTION:.0%}), and the sensor could see "
        f"{scores.seen[i]:.0%} of the model (needs {MIN_SEEN:.0%}). If that is not where the "
        "sensor stood, pass its position, or viewpoint=None to orient the normals without one."
    )


def _match(
    run: _Run, rows: np.ndarray, seed: int, matching: dict[str, Any] | None = None
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Correspondences between the model and the scan points `rows`, by the run's
    :class:`pointclm.preprocessing.DescriptorMatcher` with `matching` (the run's own when
    None); the normals at their ends when the run uses normals or its network takes them,
    and their descriptor similarity when the network takes it (else None)."""
    m = run.matcher.match(rows, seed=seed, **(run.matching if matching is None else matching))
    corr = m.correspondences(run.src_d.points, run.tgt_d.points)
    inputs = () if run.model is None else run.model.inputs
    normals = None
    if run.normals or "normals" in inputs:
        normals = m.normals(run.src_d.normals, run.tgt_d.normals)
    sims = similarity(m.distance) if "similarity" in inputs and len(corr) else None
    return corr, normals, sims


def unexplained_points(
    target_points: np.ndarray,
    source_points: np.ndarray,
    transformations: np.ndarray,
    radius: float,
    *,
    num_threads: int | None = None,
) -> np.ndarray:
    """Mask of the target points farther than `radius` from every posed source point, searched
    on `num_threads` threads (None: every core)."""
    from scipy.spatial import cKDTree

    if len(transformations) == 0:
        return np.ones(len(target_points), dtype=bool)
    posed = np.concatenate([source_points @ T[:3, :3].T + T[:3, 3] for T in transformations])
    tree = cKDTree(posed)
    d, _ = tree.query(target_points, distance_upper_bound=radius, workers=_workers(num_threads))
    return ~np.isfinite(d)


def _unexplained(run: _Run, transformations: np.ndarray) -> np.ndarray:
    """Mask of the scan points no copy at `transformations` explains (within
    `PEEL_RADIUS_VOXELS`)."""
    radius = PEEL_RADIUS_VOXELS * run.voxel
    return unexplained_points(
        run.tgt_d.points, run.src_d.points, transformations, radius, num_threads=run.num_threads
    )


def _workers(num_threads: int | None) -> int:
    """scipy's ``workers`` for `num_threads` (None: every core, as the core's pool)."""
    threads = as_threads(num_threads)
    return -1 if threads is None else threads


def _peel(
    run: _Run,
    refined: RefinedPoses,
    tags: list[tuple[int, int]],
    passes: list[Pass],
    cfg: Config,
) -> tuple[RefinedPoses, list[tuple[int, int]]]:
    """Peeling rounds: match the scan points no accepted copy explains, register them, refine
    the new poses and verify them together with the accepted ones; stop when a round adds no
    copy. Once the passes match as in a heap (:func:`_is_heap`: `_Run.heap_matching`), peeling
    stops only after `HEAP_EMPTY_ROUNDS` such rounds in a row.

    Why: in a heap of identical parts, the copies accepted first hold most of the mutual
    descriptor matches and of the sampled correspondences, so the others keep too few true
    matches to form a cluster. Once their points are set aside, the next copies' points become
    mutual best matches and fill the sample. Each round's poses are verified on the whole scan,
    so a pose that slides onto an accepted copy is a duplicate and is dropped.
    """
    scan_tree = run.scan_tree
    unexplained = _unexplained(run, refined.transformations)
    empty = 0  # rounds in a row that added no copy
    for round_ in range(1, MAX_PEEL_ROUNDS + 1):
        # Judged before every round on the copies accepted so far.
        matching = run.heap_matching if _is_heap(run, tags) else run.matching
        free = np.flatnonzero(unexplained)
        if len(free) < 3:
            break
        step = _peel_round(run, refined, tags, cfg, round_, free, matching, scan_tree, unexplained)
        if step is None:
            break
        refined, tags, unexplained, done = step
        passes.append(done)
        empty = 0 if done.added else empty + 1
        if empty >= (HEAP_EMPTY_ROUNDS if matching is run.heap_matching else 1):
            break
    return refined, tags


def _is_heap(run: _Run, tags: list[tuple[int, int]]) -> bool:
    """Whether a pass matches as in a heap: the user said the scan is one (``heap=True``:
    every pass), or the copies accepted before it show one (`HEAP_MIN_COPIES`)."""
    if run.heap_matching is None:
        return False
    return bool(run.heap) or len(tags) >= HEAP_MIN_COPIES


def _peel_round(
    run: _Run,
    refined: RefinedPoses,
    tags: list[tuple[int, int]],
    cfg: Config,
    round_: int,
    free: np.ndarray,
    matching: dict[str, Any] | None,
    scan_tree: Any,
    unexplained: np.ndarray,
) -> tuple[RefinedPoses, list[tuple[int, int]], np.ndarray, Pass] | None:
    """One peeling round over the scan points `free`, matched with `matching`: the accepted
    poses, tags and unexplained mask after it, and its pass; None when matching leaves fewer
    than 3 correspondences."""
    stage = _clustered_and_voted(run, cfg, round_, free, matching)
    if stage is None:
        return None
    corr, result, voted = stage
    reach = _within_reach(run, voted, refined)
    candidates = np.concatenate(
        [np.asarray(result.transformations).reshape(-1, 4, 4), voted[reach]]
    )
    new = run.refiner.refine(candidates, max_shared=1.0, num_threads=run.num_threads)
    # A voted pose's origin names its row of `voted` (past len(result)), screened or not.
    rows = np.concatenate([np.arange(len(result)), len(result) + reach])
    new = _without_weak_votes(new._replace(origin=rows[new.origin]), len(result), refined)
    duplicates = np.empty((0, 4, 4))
    if len(new.origin) and new.by_visibility and refined.by_visibility:
        refined, tags, duplicates = _add_seen(
            run, scan_tree, refined, tags, new, round_, unexplained
        )
    elif len(new.origin):
        refined, tags = _reverify(run, refined, tags, new, round_)
        # Re-verification may also drop accepted poses: recompute what is explained.
        unexplained = _unexplained(run, refined.transformations)
    added = sum(t[0] == round_ for t in tags)  # the copies this round added
    return refined, tags, unexplained, Pass(corr, result, free, added, voted, duplicates)


def _clustered_and_voted(
    run: _Run, cfg: Config, round_: int, free: np.ndarray, matching: dict[str, Any] | None
) -> tuple[np.ndarray, RegistrationResult, np.ndarray] | None:
    """A peeling round's candidates over the scan points `free`: its correspondences and
    their registration, and the poses voted by point pairs when the round matches as in a
    heap (else none); None when matching leaves fewer than 3 correspondences.

    Why voting runs on a second Python thread: it does not depend on the round's clusters,
    and their spectral clustering (the eigenvectors, the k-means seedings) runs on one
    thread, so voting keeps the pool's other threads busy meanwhile. Both calls share the
    core's pool for `run.num_threads`, and each gives the same result however its work is
    scheduled."""
    seed = run.seed + round_
    heap_round = run.heap and matching is run.heap_matching
    with ThreadPoolExecutor(max_workers=1) as beside:
        votes = beside.submit(run.voted_poses, free, round_) if heap_round else None
        corr, pair_normals, sims = _match(run, free, seed, matching)
        if len(corr) < 3:
            return None
        features = run.features(corr, cfg, pair_normals, sims)
        result = register(
            corr, features, cfg, seed, num_threads=run.num_threads, normals=pair_normals
        )
        # Voted poses follow the clusters' (tags past len(result) name them).
        voted = np.empty((0, 4, 4)) if votes is None else votes.result()
    return corr, result, voted


#: Model points (evenly strided) the screen of voted poses counts (:func:`_within_reach`),
#: as many as ICP's coarse stages use: a share of the model is known to a few hundredths.
_SCREEN_POINTS = 500


def _within_reach(run: _Run, voted: np.ndarray, accepted: RefinedPoses) -> np.ndarray:
    """Rows of `voted` worth refining: those that, as voted, already bring
    `VOTED_MIN_RELATIVE_FITNESS` times the median accepted copy's share of the model within
    ICP's first radius (3 voxels) of the scan; every row while no copy is accepted.

    Why: ICP moves a pose by a few voxels and degrees, within radii of 3 down to 1.5 voxels,
    so a pose must hold loosely before it what :func:`_without_weak_votes` asks of its result
    at 1.5 voxels. Refining a pose costs about as much as voting for all of them. On the
    validation bins this left out 44 % of the voted poses (85 % on the dragon) and 8 % of the
    time, for the same accepted copies but a few (ADD-S recall 0.885 -> 0.884; BENCHMARKS.md,
    bins, stop 38)."""
    rows = np.arange(len(voted))
    if len(voted) == 0 or len(accepted.fitness) == 0:
        return rows
    model = run.src_d.points[:: -(-len(run.src_d.points) // _SCREEN_POINTS)]
    near = run.refiner.near_shares(voted, model, 3.0 * run.voxel, num_threads=run.num_threads)
    return rows[near >= _vote_floor(accepted.fitness)]


def _without_weak_votes(new: RefinedPoses, clustered: int, accepted: RefinedPoses) -> RefinedPoses:
    """`new` without the voted poses (origin at or past `clustered`) that explain less of the
    model than `VOTED_MIN_RELATIVE_FITNESS` times the median accepted copy (the copies
    accepted before this round and this round's clustered ones; with none, the best voted)."""
    voted = new.origin >= clustered
    if not voted.any():
        return new
    peers = np.concatenate([accepted.fitness, new.fitness[~voted]])
    floor = _vote_floor(peers if len(peers) else new.fitness[voted].max(keepdims=True))
    return _take(new, np.flatnonzero(~voted | (new.fitness >= floor)))


def _vote_floor(fitness: np.ndarray) -> float:
    """The share of the model a voted pose must explain: `VOTED_MIN_RELATIVE_FITNESS` times
    the median of the copies' `fitness`."""
    return VOTED_MIN_RELATIVE_FITNESS * float(np.median(fitness))


def _add_seen(
    run: _Run,
    scan_tree: Any,
    refined: RefinedPoses,
    tags: list[tuple[int, int]],
    new: RefinedPoses,
    round_: int,
    unexplained: np.ndarray,
) -> tuple[RefinedPoses, list[tuple[int, int]], np.ndarray]:
    """A round's poses judged by visibility joined to the accepted ones: such a verdict does
    not depend on the other poses, so only duplicates of accepted copies are dropped, then
    the lists are merged; and the dropped duplicates' poses. The new copies' points leave
    `unexplained` (in place)."""
    taken = ~unexplained
    keep = _not_duplicates(scan_tree, run.src_d.points, new.transformations, run.voxel, taken)
    duplicates = np.delete(new.transformations, keep, axis=0)
    if not keep:
        return refined, tags, duplicates
    kept = _take(new, keep)
    refined, tags = _merge(refined, tags, kept, [(round_, int(new.origin[i])) for i in keep])
    # The accepted set only grew: the new copies' points join the explained ones.
    unexplained &= _unexplained(run, kept.transformations)
    return refined, tags, duplicates


def _reverify(
    run: _Run,
    refined: RefinedPoses,
    tags: list[tuple[int, int]],
    new: RefinedPoses,
    round_: int,
) -> tuple[RefinedPoses, list[tuple[int, int]]]:
    """Accepted and new poses verified together (without visibility a pose's verdict
    depends on the best fitness among them)."""
    pool = np.concatenate([refined.transformations, new.transformations])
    pool_tags = tags + [(round_, int(o)) for o in new.origin]
    both = run.refiner.refine(pool, icp=False, num_threads=run.num_threads)
    return both, [pool_tags[int(o)] for o in both.origin]


def _settle(
    run: _Run,
    refined: RefinedPoses,
    tags: list[tuple[int, int]],
    flips: bool,
    passes: list[Pass],
) -> tuple[RefinedPoses, list[tuple[int, int]]]:
    """The scene's accepted poses, final: half turns resolved (if asked), then, when the
    sensor judged them, those that fit loosely against the others dropped
    (:func:`pointclm.refinement.loose_poses`) and the rest made less sure the looser they fit
    (:func:`pointclm.refinement.fit_tightness`) and the less firmly the scan pins them down
    (:func:`pointclm.refinement.stability_factor`) than the median, surest first. Why only at
    the end: the comparison needs every copy the scan shows, and peeling needs the dropped poses'
    scan points explained."""
    if flips and len(tags):
        refined, tags = _resolve_flips(run, refined, tags, _duplicate_turns(run, refined, passes))
    if not refined.by_visibility:
        return refined, tags
    keep = np.flatnonzero(~loose_poses(refined.visible_rmse))
    refined, tags = _take(refined, keep), [tags[int(i)] for i in keep]
    stability = pose_stability(
        run.src_d.points,
        run.src_d.normals,
        run.scan_tree,
        refined.transformations,
        1.5 * run.voxel,
        workers=_workers(run.num_threads),
    )
    sureness = fit_tightness(refined.visible_rmse) * stability_factor(stability)
    refined = refined._replace(confidence=refined.confidence * sureness)
    order = np.argsort(-refined.confidence, kind="stable")
    return _take(refined, order), [tags[int(i)] for i in order]


def _duplicate_turns(run: _Run, refined: RefinedPoses, passes: list[Pass]) -> np.ndarray:
    """(D, 3, 3) each duplicate the passes dropped (``Pass.duplicates``), as a rotation of the
    model relative to the accepted pose whose copy it lies on (the nearest by the posed
    model's centroid)."""
    duplicates = np.concatenate([p.duplicates for p in passes]).reshape(-1, 4, 4)
    accepted = refined.transformations
    if len(duplicates) == 0 or len(accepted) == 0:
        return np.empty((0, 3, 3))
    centre = run.src_d.points.mean(0)
    homes = accepted[:, :3, :3] @ centre + accepted[:, :3, 3]
    posed = duplicates[:, :3, :3] @ centre + duplicates[:, :3, 3]
    home = np.argmin(np.linalg.norm(posed[:, None] - homes[None], axis=2), axis=1)
    # R_home^T R_duplicate: the duplicate's rotation in the home pose's model frame.
    return accepted[home, :3, :3].transpose(0, 2, 1) @ duplicates[:, :3, :3]


def _resolve_flips(
    run: _Run, refined: RefinedPoses, tags: list[tuple[int, int]], rotations: np.ndarray
) -> tuple[RefinedPoses, list[tuple[int, int]]]:
    """The accepted poses with half-turned alternatives the scan supports better
    (:func:`pointclm.refinement.resolve_flips`), surest first."""
    flipped, order = resolve_flips(
        run.src_d.points,
        run.tgt_d.points,
        refined,
        run.voxel,
        viewpoint=run.viewpoint,
        target_normals=run.tgt_d.normals,
        num_threads=run.num_threads,
        context=run.refiner,
        rotations=rotations,
    )
    return flipped, [tags[int(i)] for i in order]


def _not_duplicates(
    scan_tree: Any, source: np.ndarray, poses: np.ndarray, voxel: float, taken: np.ndarray
) -> list[int]:
    """Indices of `poses` (surest first) whose explained scan points (within 1.5 voxels, as
    verification counts them) are at most half `taken` by accepted copies or by a surer pose of
    the list (`refine_poses`' ``max_shared`` rule); marks the kept poses' points taken."""
    keep = []
    for i, T in enumerate(poses):
        hits = explained_scan_points(scan_tree, source, T, 1.5 * voxel)
        if len(hits) == 0 or taken[hits].mean() > MAX_SHARED:
            continue
        taken[hits] = True
        keep.append(i)
    return keep


def _take(poses: RefinedPoses, rows: list[int] | np.ndarray) -> RefinedPoses:
    idx = np.asarray(rows, dtype=np.int64)
    return poses._replace(
        **{f: getattr(poses, f)[idx] for f in RefinedPoses._fields if f != "by_visibility"}
    )


def _merge(
    a: RefinedPoses, a_tags: list[tuple[int, int]], b: RefinedPoses, b_tags: list[tuple[int, int]]
) -> tuple[RefinedPoses, list[tuple[int, int]]]:
    """Two lists of verified poses as one, surest first (`a` first among equals)."""
    joined: dict[str, Any] = {
        f: np.concatenate([getattr(a, f), getattr(b, f)])
        for f in RefinedPoses._fields
        if f != "by_visibility"
    }
    both = a._replace(**joined)
    order = np.argsort(-both.confidence, kind="stable")
    tags = a_tags + b_tags
    return _take(both, order), [tags[i] for i in order]


def _config(
    config: Config | dict[str, Any] | None, voxel: float, model: Any, refine: bool, peel: bool
) -> Config:
    """The caller's config as given (already in the clouds' units), else `cloud_config`."""
    if isinstance(config, Config):
        return config
    if isinstance(config, dict):
        return Config(**as_config(config))  # unknown keys: a ValueError naming them
    if config is not None:
        raise ValueError(f"config must be a pointclm.Config, a dict or None, got {type(config)}")
    return cloud_config(voxel, model, refine, peel)

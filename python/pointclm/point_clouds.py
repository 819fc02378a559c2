"""`register_point_clouds`: a model and a scan in, the pose of every copy out.

The one-call path for users who have clouds, not correspondences: load (arrays or files),
downsample, normals, FPFH, descriptor matching, the correspondence stage with lengths scaled to
the voxel size, ICP refinement and verification of its poses on the clouds, peeling (further
passes over the scan points no accepted copy explains, until one adds no copy), turned
alternatives and ranking. Every stage is timed.

Without a learned model the whole pipeline runs in the Rust core in one call
(``pointclm::scene::register_point_clouds``, :mod:`pointclm.clouds.core_path`); with one, and
for the few options the core does not take, the same stages run from Python
(:mod:`pointclm.clouds`), each callable on its own.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from . import _core
from . import preprocessing as pp
from . import symmetry as symmetries
from .clouds.core_path import CoreCall, in_core, register_in_core
from .clouds.diagnosis import _diagnose
from .clouds.peeling import _is_heap, _peel, unexplained_points
from .clouds.ranking import _settle
from .clouds.results import CloudInstance, Pass, PointCloudRegistration
from .clouds.run import _match, _matcher, _matchings, _Run
from .clouds.sensor import (  # noqa: F401 (the scan's stray and side rules, re-exported)
    DescribedScan,
    _describe_target,
    _spans_a_scene,
    _voxel_size,
    _without_strays,
    default_voxel_size,
)
from .clouds.verification import _covariances, _instances, _verify
from .config import Config
from .covariance import pose_covariances
from .docstrings import fill
from .embedding import Embedding, resolve
from .errors import InputError
from .refinement import RefinementContext  # noqa: F401 (re-exported: peeling refines with it)
from .registration import as_config, as_threads, register
from .scene_rules import SCENE_DEFAULTS, SceneRules

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


#: The training-free thresholds (synthetic units, scaled to the voxel) when the poses are
#: refined and verified on the clouds, as `register_point_clouds` does by default: almost no
#: density pruning and small clusters, since verification judges every proposal. Declared in
#: the core (``pointclm::scene::cloud_base_config``, where the reason and the data they were
#: chosen on are written). Without refinement `Config()`'s thresholds stay.
REFINED_THRESHOLDS: dict[str, Any] = {
    name: _core.cloud_base_config()[name] for name in ("tau_s", "tau_n", "min_cluster_size")
}


# The scene-wide rules' defaults, as the Rust core declares them (`pointclm::scene::SceneRules`,
# where each one's reason and the data it was chosen on are written; `help(SceneRules)`).
VOXELS_PER_DIAGONAL = SCENE_DEFAULTS.voxels_per_diagonal
PEEL_CLUSTER_LEVEL = SCENE_DEFAULTS.peel_cluster_level
MIN_VOXEL_SPACINGS = SCENE_DEFAULTS.min_voxel_spacings
MIN_VOXEL_NOISES = SCENE_DEFAULTS.min_voxel_noises
NOISE_SCALE_VOXELS = SCENE_DEFAULTS.noise_scale_voxels
STRAY_NEIGHBOURS = SCENE_DEFAULTS.stray_neighbours
MAX_STRAY_SHARE = SCENE_DEFAULTS.max_stray_share
SCENE_EXTENT = SCENE_DEFAULTS.scene_extent
PEEL_RADIUS_VOXELS = SCENE_DEFAULTS.peel_radius_voxels
MAX_PEEL_ROUNDS = SCENE_DEFAULTS.max_peel_rounds
HEAP_EMPTY_ROUNDS = SCENE_DEFAULTS.heap_empty_rounds
HEAP_MIN_COPIES = SCENE_DEFAULTS.heap_min_copies
HEAP_WINDOW = SCENE_DEFAULTS.heap_window
HEAP_VOTED_POSES = SCENE_DEFAULTS.heap_voted_poses
VOTED_MIN_RELATIVE_FITNESS = SCENE_DEFAULTS.voted_min_relative_fitness
#: The default of ``heap_rank``: in a heap, the later passes' mutual check keeps a pair when
#: the scan point is among the model point's this many most similar scan points still
#: unexplained. Why: a model point has one true match per visible copy, and a heap shows a few
#: dozen copies; 64 is every candidate the matcher looks at
#: (`pointclm.preprocessing.WINDOW_CANDIDATES`). On the validation bins ranks 16 and 64 found
#: 0.31 and 0.34 of the half-visible copies against 0.28 (BENCHMARKS.md, bins).
HEAP_RANK = 64


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
    cluster_level: float = PEEL_CLUSTER_LEVEL,
) -> Config:
    """`register_point_clouds`' config when none is given, in the clouds' units:
    :func:`cloud_base_config` (synthetic units) scaled by :meth:`Config.for_voxel`. `evaluate`
    uses the same on realistic scenes."""
    base = cloud_base_config(model, refine, peel, overrides, cluster_level)
    return Config.for_voxel(voxel_size, base)


def cloud_base_config(
    model: Any = None,
    refine: bool = True,
    peel: bool = False,
    overrides: Mapping[str, Any] | None = None,
    cluster_level: float = PEEL_CLUSTER_LEVEL,
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
            base = replace(base, cluster_level=cluster_level)
    return base.with_overrides(overrides)


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
    scene: SceneRules | Mapping[str, Any] | None = None,
    symmetry: Any = None,
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
    %(scene)s
    %(symmetry)s

    %(cloud_returns)s
    """
    t0 = time.perf_counter()
    emb, view = _checked_arguments(num_threads, refine, mutual, model, viewpoint, flips)
    window, rank, sc = _heap_arguments(mutual_window, heap_rank, heap, mutual, k, scene)
    src, tgt, view = _loaded(source, target, view)
    t_load, voxel = time.perf_counter() - t0, _voxel_size(src, tgt, voxel_size, sc)
    call = CoreCall(voxel, config, seed, view, top_k, mutual, n_samples, rank, heap, peel,
                    flips, sc, num_threads, viewpoint is None, emb, normals, symmetry)  # fmt: skip
    if in_core(refine=refine, k=k, window=window):
        return _finished(register_in_core(src, tgt, call.checked()), None, t_load, t0)
    run, scan = _python_run(src, tgt, call.checked(), k, window)
    return _finished(_register(run, config, refine, peel, flips), scan, t_load, t0, call)


def _canonical(reg: PointCloudRegistration, sym: Any, num_threads: int | None) -> Any:
    """The Python stages' result with every pose the canonical one of the model's symmetry
    (`sym`: "auto", the core's dict, or None), its covariance recomputed there."""
    if sym is None:
        return reg
    model = reg.source_points
    found = symmetries.Symmetry._from_core(
        _core.resolve_model_symmetry(model, model, sym, num_threads=num_threads)
    )
    if not reg.instances:
        return replace(reg, symmetry=found)
    poses = found.canonical(reg.transformations)
    rows = zip(reg.instances, poses, strict=True)
    instances = [replace(inst, transformation=pose) for inst, pose in rows]
    if reg.instances[0].covariance is not None:  # computed at the poses before
        cov = pose_covariances(model, reg.target_points, poses, reg.voxel_size,
                               num_threads=num_threads)  # fmt: skip
        instances = [
            replace(
                inst,
                information=cov.information[i],
                covariance=cov.covariance[i],
                unobservable=int(cov.unobservable[i]),
            )  # fmt: skip
            for i, inst in enumerate(instances)
        ]
    return replace(reg, instances=instances, symmetry=found)


def _python_run(
    src: np.ndarray, tgt: np.ndarray, call: CoreCall, k: int, window: float | str | None
) -> tuple[_Run, DescribedScan]:
    """The Python stages' run (for the options the core does not take): both clouds
    described, the matcher and its arguments (`call`'s, with `k` and the mutual `window`);
    and the scan as described."""
    voxel, threads, sc, embedding = call.voxel, call.num_threads, call.scene, call.model
    src_d = pp.describe(src, voxel, away_from=src.mean(0), num_threads=threads)
    scan = _describe_target(tgt, voxel, call.viewpoint, call.recorded, src_d, threads, sc)
    matching, heaped = _matchings(call.top_k, call.mutual, call.n_samples, k, window, src,
                                  call.heap_rank, call.heap, sc)  # fmt: skip
    tgt_d, matcher = scan.cloud, _matcher(src_d, scan.cloud, k, threads)
    run = _Run(src_d, tgt_d, voxel, scan.viewpoint, matching, matcher, call.normals, call.seed,
               embedding, threads, heap_matching=heaped, guessed_viewpoint=scan.guessed,
               heap=call.heap, scene=sc)  # fmt: skip
    return run, scan


def _loaded(
    source: Any, target: Any, view: tuple[float, float, float] | None
) -> tuple[np.ndarray, np.ndarray, tuple[float, float, float] | None]:
    """The clouds (arrays or files) and the viewpoint: `view`, else the one a scan file
    records."""
    src, tgt = _load(source, "source"), _load(target, "target")
    return src, tgt, _recorded_viewpoint(target) if view is None else view


def _finished(
    reg: PointCloudRegistration,
    scan: DescribedScan | None,
    t_load: float,
    t0: float,
    call: CoreCall | None = None,
) -> PointCloudRegistration:
    """`reg` with how the scan's normals were oriented and whether the scan disputes the
    given viewpoint (`scan`; None: as `reg` says), its poses canonical by `call`'s symmetry
    (the Python stages'), and the timings of reading the files and of the whole call (started
    at `t0`)."""
    if call is not None:
        reg = _canonical(reg, call.symmetry, call.num_threads)
    total = {"load": t_load, "total": time.perf_counter() - t0}
    orientation = reg.orientation if scan is None else scan.orientation
    disputed = reg.viewpoint_disputed if scan is None else scan.disputed
    note = reg.diagnosis
    if disputed:
        note = (
            "the scan does not look like one view from the viewpoint given; poses were judged "
            "from it all the same." + (" " + note if note else "")
        )
    return replace(
        reg,
        orientation=orientation,
        timings=reg.timings | total,
        viewpoint_disputed=disputed,
        diagnosis=note,
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
    window: float | str | None,
    rank: int | None,
    heap: bool | None,
    mutual: bool,
    k: int,
    scene: SceneRules | Mapping[str, Any] | None = None,
) -> tuple[float | str | None, int | None, SceneRules]:
    """`mutual_window`, `heap_rank`, `heap` and the scene's rules checked before the files are
    read."""
    if heap is not None:
        pp.as_flag(heap, "heap")
    rank = None if rank is None else pp.as_count(rank, "heap_rank", 1)
    return _window_diagonals(window, mutual, k), rank, SceneRules.resolve(scene)


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
    cfg = _config(config, run.voxel, run.model, refine, peel, run.scene.peel_cluster_level)
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
    refined, tags = _settle(run, refined, tags, flips, passes) if refine else (refined, tags)
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
        instances=_instances(refined, tags, passes, _covariances(run, refined)),
        timings=timings,
        passes=passes,
        viewpoint=None if run.viewpoint is None else np.array(run.viewpoint),
        diagnosis=_diagnose(run, len(refined.origin), refined.by_visibility, passes, refine),
    )


def _config(
    config: Config | dict[str, Any] | None,
    voxel: float,
    model: Any,
    refine: bool,
    peel: bool,
    cluster_level: float = PEEL_CLUSTER_LEVEL,
) -> Config:
    """The caller's config as given (already in the clouds' units), else `cloud_config`."""
    if isinstance(config, Config):
        return config
    if isinstance(config, dict):
        return Config(**as_config(config))  # unknown keys: a ValueError naming them
    if config is not None:
        raise ValueError(f"config must be a pointclm.Config, a dict or None, got {type(config)}")
    return cloud_config(voxel, model, refine, peel, cluster_level=cluster_level)

"""`register_point_clouds`: a model and a scan in, the pose of every copy out.

The one-call path for users who have clouds, not correspondences: load (arrays or files),
downsample, normals, FPFH, descriptor matching, the correspondence stage with lengths scaled to
the voxel size, ICP refinement and verification of its poses on the clouds, peeling (further
passes over the scan points no accepted copy explains, until one adds no copy), turned
alternatives and ranking. Every stage is timed.

The whole pipeline runs in the Rust core in one call (``pointclm::scene::register_point_clouds``,
:mod:`pointclm.clouds.core_path`); a learned model's embedding is called back from there for
every pass.
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
from .clouds.core_path import CoreCall, register_in_core
from .clouds.results import CloudInstance, Pass, PointCloudRegistration
from .clouds.scans import file_viewpoint, load_cloud, read_scan
from .clouds.sensor import _voxel_size, default_voxel_size
from .config import Config
from .descriptors import descriptor_choice
from .docstrings import fill
from .embedding import Embedding, resolve
from .errors import InputError
from .registration import as_config, as_threads
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
    proposals: str = "auto",
    descriptor: str | os.PathLike[str] = "auto",
) -> PointCloudRegistration:
    """Find every copy of `source` (a complete model) in `target` (a scan).

    Parameters
    ----------
    %(clouds_in)s
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
    %(proposals)s

    %(cloud_returns)s
    """
    t0, (weights, kind) = time.perf_counter(), descriptor_choice(descriptor)
    emb, view = _checked_arguments(num_threads, refine, mutual, model, viewpoint, flips, proposals)
    window, rank, sc = _heap_arguments(mutual_window, heap_rank, heap, mutual, k, scene)
    src, scan = load_cloud(source, "source"), read_scan(target, view)
    t_load, voxel = time.perf_counter() - t0, _voxel_size(src, scan.points, voxel_size, sc)
    call = CoreCall(voxel, config, seed, scan.viewpoint, top_k, mutual, n_samples, rank, heap,
                    peel, flips, sc, num_threads, scan.stated_by, emb, normals, refine, k,
                    window, symmetry, proposals, weights, kind)  # fmt: skip
    return _finished(register_in_core(src, scan.points, call.checked()), t_load, t0)


def unexplained_points(
    target_points: np.ndarray,
    source_points: np.ndarray,
    transformations: np.ndarray,
    radius: float,
    *,
    num_threads: int | None = None,
) -> np.ndarray:
    """Mask of the target points farther than `radius` from every posed source point, searched
    on `num_threads` threads (None: every core): what peeling's next pass matches."""
    poses = np.asarray(transformations, dtype=np.float64).reshape(-1, 4, 4)
    return _core.unexplained_points(
        pp.as_points(target_points, "target_points"),
        pp.as_points(source_points, "source_points"),
        np.ascontiguousarray(poses),
        radius,
        num_threads=as_threads(num_threads),
    )


def _finished(reg: PointCloudRegistration, t_load: float, t0: float) -> PointCloudRegistration:
    """`reg` with the note that the scan disputes the given viewpoint (when it does), and the
    timings of reading the files and of the whole call (started at `t0`)."""
    total = {"load": t_load, "total": time.perf_counter() - t0}
    note = reg.diagnosis
    if reg.viewpoint_disputed:
        note = (
            "the scan does not look like one view from the viewpoint given; poses were judged "
            "from it all the same." + (" " + note if note else "")
        )
    return replace(reg, timings=reg.timings | total, diagnosis=note)


def _checked_arguments(
    num_threads: int | None,
    refine: bool,
    mutual: bool,
    model: Any,
    viewpoint: ArrayLike | None,
    flips: bool = False,
    proposals: str = "auto",
) -> tuple[Embedding | None, tuple[float, float, float] | None]:
    """What of `register_point_clouds`' arguments can be checked before the files are read:
    the model resolved (a bad model fails before the work) and the viewpoint as a point."""
    _proposals(proposals)
    as_threads(num_threads)
    pp.as_flag(refine, "refine")
    pp.as_flag(mutual, "mutual")
    pp.as_flag(flips, "flips")
    embedding = None if model is None else resolve(model)
    view = None if viewpoint is None else pp.as_point(viewpoint, "viewpoint")
    return embedding, view


#: The values of ``proposals``.
PROPOSALS = ("auto", "descriptors", "faces")


def _proposals(value: Any) -> str:
    """`proposals` checked before the files are read."""
    if not isinstance(value, str) or value not in PROPOSALS:
        raise InputError(f'proposals must be "auto", "descriptors" or "faces", got {value!r}')
    return value


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

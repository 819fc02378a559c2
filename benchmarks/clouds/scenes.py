"""The realistic scenes the point-cloud suites share: their seeds, parameters and data folder,
and a cache of built scenes (``.npz``, no pickle) so that each is built once.

Model ``m``'s benchmark scenes are ``make_realistic_scene(seed)`` for the seeds
``benchmark_seeds(m, n)`` = 1,000,000 + 1000 x slot(m) + k, its threshold-sweep scenes
``threshold_seeds(m, n)`` = 2,000,000 + 1000 x slot(m) + k (see `realistic_models`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from pointclm.datasets.procedural import PROCEDURAL_FAMILIES, is_procedural

from benchmarks.common.report import ROOT

#: First seed of each model's benchmark scenes, and of the threshold sweep's scenes.
BENCHMARK_SEED_BASE = 1_000_000
THRESHOLD_SEED_BASE = 2_000_000
#: Seeds per model in a range (model slots follow HELDOUT_MODELS then VALIDATION_MODELS;
#: append new models at the end so that the others keep their seeds); a range holds 1000.
SCENES_PER_SLOT = 1000
SEED_RANGE = 1_000_000

#: Bump when the cached arrays change meaning.
CACHE_VERSION = 3


def benchmark_seeds(model: str, n: int) -> list[int]:
    """Seeds of `model`'s first `n` benchmark scenes."""
    return _seeds(BENCHMARK_SEED_BASE, model, n)


def threshold_seeds(model: str, n: int) -> list[int]:
    """Seeds of `model`'s first `n` threshold-sweep scenes (``realistic_thresholds``)."""
    return _seeds(THRESHOLD_SEED_BASE, model, n)


def _seeds(base: int, model: str, n: int) -> list[int]:
    """``base + 1000 * slot + k``: each model its own block of seeds, so that models do not
    share layouts (a seed fixes the copies' count, the clutter and the sensor)."""
    from pointclm.datasets.scenes import HELDOUT_MODELS, VALIDATION_MODELS

    models = (*HELDOUT_MODELS, *VALIDATION_MODELS)
    if model not in models and not is_procedural(model):
        raise ValueError(
            f"unknown model {model!r}: one of {', '.join(models)} or a random procedural "
            "shape ('superquadric-<seed>', ...)"
        )
    if not 0 <= n <= SCENES_PER_SLOT:
        raise ValueError(f"scenes per model must lie in [0, {SCENES_PER_SLOT}], got {n}")
    first = base + SCENES_PER_SLOT * _slot(model, models)
    return list(range(first, first + n))


def _slot(model: str, models: tuple[str, ...]) -> int:
    """A model's block of seeds: its place among the named models, or for a random procedural
    shape a block after them fixed by its family and seed (two shapes may share one: they
    then share layouts, not shapes)."""
    if model in models:
        return models.index(model)
    family, seed = model.rsplit("-", 1)
    free = SEED_RANGE // SCENES_PER_SLOT - len(models)
    return len(models) + (3 * int(seed) + PROCEDURAL_FAMILIES.index(family)) % free


def data_folder(given: str | None) -> str:
    """The data folder of the point-cloud benchmarks: `given` (``--data-dir``), else
    ``$POINTCLM_DATA_DIR``, else ``../shared/data`` beside the repository."""
    return given or os.environ.get("POINTCLM_DATA_DIR") or str(ROOT.parent / "shared" / "data")


def cloud_scenes(split: str, scenes_per_model: int, cache: Path, data_dir: str) -> list[Any]:
    """The scenes the point-cloud benchmarks register from their clouds (N = 1000 parameters):
    `split` "heldout" gives the held-out models' benchmark seeds, "validation" the validation
    models' with data files (not the procedural shapes) and their threshold seeds."""
    from pointclm.datasets.scenes import HELDOUT_MODELS, VALIDATION_MODELS

    held = split == "heldout"
    models = [m for m in (HELDOUT_MODELS if held else VALIDATION_MODELS) if "/" in m]
    seeds = benchmark_seeds if held else threshold_seeds
    jobs = [
        (m, s, scene_params(m, 1000, data_dir)) for m in models for s in seeds(m, scenes_per_model)
    ]
    return load_scenes(jobs, cache, 1)


def scene_params(model: str, n: int, data_dir: str | None, descriptor: str = "fpfh") -> Any:
    """The benchmark's scene parameters for `model` at `n` correspondences of `descriptor`."""
    from pointclm.datasets.scenes import SceneParams

    if n < 1:
        raise ValueError(f"n must be positive, got {n}")
    if n <= 1000:
        return SceneParams(
            model=model, data_dir=data_dir, n_correspondences=n, descriptor=descriptor
        )
    # Past 1000 the mutual filter leaves too few: keep the top n of every scene point's match.
    return SceneParams(
        model=model,
        data_dir=data_dir,
        mutual=False,
        top_k=n,
        n_correspondences=None,
        descriptor=descriptor,
    )


def scale_params(model: str, n: int, data_dir: str | None) -> Any:
    """A crowded, finely sampled scene with `n` realistic correspondences (top n, no mutual)."""
    from pointclm.datasets.scenes import SceneParams

    return SceneParams(
        model=model,
        data_dir=data_dir,
        instances=(8, 8),
        clutter=(3, 3),
        voxel_fraction=1 / 80,
        mutual=False,
        top_k=n,
        n_correspondences=None,
    )


# --- scene cache --------------------------------------------------------------------------

_ARRAYS = (
    "correspondences",
    "labels",
    "poses",
    "source_points",
    "target_points",
    "target_ids",
    "real_scan",
)
#: Kept when the scene has them (cues of networks that take more than coordinates).
_OPTIONAL_ARRAYS = ("pair_normals", "match_distance")


def cache_path(cache: Path, model: str, seed: int, params: Any) -> Path:
    """Where the scene of (`model`, `seed`, `params`) is kept; the data folder is not part
    of the key (the same files wherever they are)."""
    key = repr((CACHE_VERSION, dataclasses.replace(params, data_dir=None)))
    digest = hashlib.sha1(key.encode()).hexdigest()[:12]
    return cache / f"{model.replace('/', '__')}-{seed}-{digest}.npz"


def save_scene(path: Path, scene: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + f".tmp{os.getpid()}.npz")
    np.savez_compressed(
        tmp,
        **{k: getattr(scene, k) for k in _ARRAYS},
        **{k: getattr(scene, k) for k in _OPTIONAL_ARRAYS if getattr(scene, k) is not None},
        voxel_size=scene.voxel_size,
        diameter=scene.diameter,
        model=np.array(scene.model),
        seed=np.array(scene.seed, dtype=np.int64),
        timing_keys=np.array(list(scene.timings)),
        timing_values=np.array(list(scene.timings.values()), dtype=np.float64),
        # The sensor's position: point-cloud benchmarks orient normals and verify by it.
        viewpoint=np.full(3, np.nan) if scene.viewpoint is None else np.asarray(scene.viewpoint),
    )
    tmp.replace(path)  # atomic: a killed run leaves no half-written scene behind


def load_scene(path: Path) -> Any:
    from pointclm.datasets.scenes import RealisticScene

    with np.load(path, allow_pickle=False) as z:
        return RealisticScene(
            **{k: z[k] for k in _ARRAYS},
            **{k: z[k] for k in _OPTIONAL_ARRAYS if k in z.files},
            voxel_size=float(z["voxel_size"]),
            diameter=float(z["diameter"]),
            model=str(z["model"]),
            seed=int(z["seed"]),
            timings=dict(zip(z["timing_keys"].tolist(), z["timing_values"].tolist(), strict=True)),
            viewpoint=_viewpoint(z),
        )


def _viewpoint(z: Any) -> np.ndarray | None:
    v = np.asarray(z["viewpoint"], dtype=np.float64) if "viewpoint" in z.files else None
    return None if v is None or not np.isfinite(v).all() else v


def _build(job: tuple[str, int, Any, str]) -> str:
    from pointclm.datasets.scenes import make_realistic_scene

    model, seed, params, path = job
    save_scene(Path(path), make_realistic_scene(seed, params))
    return path


def load_scenes(
    jobs: Sequence[tuple[str, int, Any]], cache: Path, workers: int, progress: bool = True
) -> list[Any]:
    """The scenes of `jobs` (model, seed, params), built in `workers` processes where the
    cache lacks them."""
    paths = [cache_path(cache, m, s, p) for m, s, p in jobs]
    todo = [(m, s, p, str(path)) for (m, s, p), path in zip(jobs, paths, strict=True)]
    todo = [j for j in todo if not Path(j[3]).exists()]
    if todo:
        if progress:
            print(f"building {len(todo)} scenes ({workers} workers) into {cache}", flush=True)
        if workers > 1:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            # spawn: a forked child of a process whose thread pools already run can deadlock.
            with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as pool:
                for i, _ in enumerate(pool.map(_build, todo)):
                    if progress and (i + 1) % 10 == 0:
                        print(f"  {i + 1}/{len(todo)}", flush=True)
        else:
            for job in todo:
                _build(job)
    return [load_scene(p) for p in paths]

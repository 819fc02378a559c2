"""The realistic benchmark over every model: pointclm vs sequential robust solvers on the same
correspondences, per model and pooled, at N = 1000 or 5000, and one timed N = 50,000 run.

    pip install ".[bench]"      # the peers, KISS-Matcher and Open3D (benchmarks/peers.py)
    python benchmarks/realistic_models.py                              # N = 1000, all models
    python benchmarks/realistic_models.py --n 5000 --scenes-per-model 4 --scale 0 \\
        --out benchmarks/results/realistic_models_n5000.md
    python benchmarks/realistic_models.py --quick                      # CI-sized

**Models and the split** (``pointclm.datasets.scenes``): the HEADLINE pools the HELD-OUT models
(``HELDOUT_MODELS``: the Stanford bunny with its real range scans, and the six common3d
meshes), which never pick a threshold. The VALIDATION models (``VALIDATION_MODELS``: dragon,
happy, armadillo, bathtub, bed and the procedural shapes) are where thresholds and defaults
are chosen (``realistic_thresholds.py``); they are reported apart, as in-sample figures.
Pooled rows weight every scene alike (the same count per model).

**Seeds.** Model ``m``'s benchmark scenes are ``make_realistic_scene(seed)`` for the seeds
``benchmark_seeds(m, n)`` = 1,000,000 + 1000 x slot(m) + k, k = 0..n - 1, where slot(m) is
m's place in ``HELDOUT_MODELS + VALIDATION_MODELS`` (so models do not share layouts).
Disjoint from every other scene source: ``realistic_thresholds.py`` uses
``threshold_seeds`` = 2,000,000 + 1000 x slot + k; the training and training-time
validation banks use ``training.realistic.scene_seed`` (62-bit hashes; a test checks that
the banks' default seeds miss both ranges); the bunny benchmark (``realistic.py``) and the
tests use small seeds (0..99). The N = 5000 scenes are the same scenes (same seeds, same
layout) matched differently.

**Correspondences.** N = 1000: the scenes' default (FPFH, mutual nearest neighbours, top
10,000, at most 1000 drawn; a median of about 400 survive the mutual filter). N > 1000: the
mutual filter off and the top N matches by descriptor distance kept, none drawn away.
An instance is registered when RE < 15 deg and TE < 10 % of the model's diagonal.

**Methods**, all on the same correspondences of a scene, pointclm on one thread:
- pointclm, training-free, correspondence stage alone: ``pointclm.register`` with the
  default config scaled to the voxel, no clouds (the headline row);
- the same with its poses refined and verified on the clouds (``refine_poses``, with the
  thresholds for refined poses, as ``register_point_clouds`` does);
- ``--model NAME``: a learned embedding, raw and refined (optional);
- an upper bound, not a method: an embedding from the true labels (``realistic.py``'s oracle);
- sequential KISS-Matcher and sequential Open3D RANSAC (``peers.py``): inlier radius 2 voxels
  (the scenes' inlier definition), stop below pointclm's ``min_cluster_size`` inliers or at
  10 poses. ``--quick`` leaves RANSAC out (seconds per scene), ``--no-ransac`` and
  ``--no-kiss`` leave either out. A peer that is not installed stops the run before any
  scene is built, naming the package; ``--skip-missing-peers`` leaves it out instead (said
  at the start, and its row is then absent from the report).
Times are per scene, wall clock, everything a method does (refinement included).

**N = 50,000** (``--scale``, default 50,000; 0 skips): realistic correspondences, not planted:
one bunny scene and one common3d scene, 8 copies and 3 clutter objects, voxel = diagonal /
80 so that the scan has enough points, the mutual filter off, the top N matches kept. Each is
registered training-free (correspondences alone) in a fresh child process, which reports the
time and the peak RSS (``ru_maxrss``; baseline after loading the scene), on 1 thread and on
all cores, under an 8 GB address-space limit.

**Cache.** Built scenes are kept as ``.npz`` (no pickle) under ``--cache`` (default
``out/realistic_scenes``), keyed by model, seed and scene parameters; delete the folder
when ``datasets/scenes.py`` or the FPFH code changes.

Results: a markdown report (``--out``, default ``out/realistic_models.md``, not committed;
``--out benchmarks/results/realistic_models.md`` replaces the committed one) with date,
command, hardware, git commit, and a JSON file beside it holding every scene's score and time
per method.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import hashlib
import json
import os
import platform
import resource
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from pointclm.datasets.procedural import PROCEDURAL_FAMILIES, is_procedural

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

#: First seed of each model's benchmark scenes, and of the threshold sweep's scenes.
BENCHMARK_SEED_BASE = 1_000_000
THRESHOLD_SEED_BASE = 2_000_000
#: Seeds per model in a range (model slots follow HELDOUT_MODELS then VALIDATION_MODELS;
#: append new models at the end so that the others keep their seeds); a range holds 1000.
SCENES_PER_SLOT = 1000
SEED_RANGE = 1_000_000

#: Bump when the cached arrays change meaning.
CACHE_VERSION = 3

QUICK_MODELS = ("stanford/bunny", "common3d/spot", "stanford/armadillo", "torus")
#: The N = 50,000 scenes: one held-out model with real scans, one mesh.
SCALE_MODELS = ("stanford/bunny", "common3d/teapot")
#: Runs of each method per scene; the fastest is its time (see `run_methods`).
TIMED_RUNS = 2


def benchmark_seeds(model: str, n: int) -> list[int]:
    """Seeds of `model`'s first `n` benchmark scenes."""
    return _seeds(BENCHMARK_SEED_BASE, model, n)


def threshold_seeds(model: str, n: int) -> list[int]:
    """Seeds of `model`'s first `n` threshold-sweep scenes (``realistic_thresholds.py``)."""
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
    return (
        given or os.environ.get("POINTCLM_DATA_DIR") or str(HERE.parent.parent / "shared" / "data")
    )


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


def scene_params(model: str, n: int, data_dir: str | None) -> Any:
    """The benchmark's scene parameters for `model` at `n` correspondences."""
    from pointclm.datasets.scenes import SceneParams

    if n < 1:
        raise ValueError(f"n must be positive, got {n}")
    if n <= 1000:
        return SceneParams(model=model, data_dir=data_dir, n_correspondences=n)
    # Past 1000 the mutual filter leaves too few: keep the top n of every scene point's match.
    return SceneParams(
        model=model, data_dir=data_dir, mutual=False, top_k=n, n_correspondences=None
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


# --- methods ------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Method:
    """A row: `run(scene)` returns the predicted poses."""

    key: str
    label: str
    run: Callable[[Any], np.ndarray]


def _poses(x: Any) -> np.ndarray:
    return np.asarray(x, dtype=np.float64).reshape(-1, 4, 4)


def _refine(scene: Any, poses: np.ndarray) -> np.ndarray:
    import pointclm

    return _poses(
        pointclm.refine_poses(
            scene.source_points, scene.target_points, poses, scene.voxel_size, num_threads=1
        ).transformations
    )


def _pointclm(
    model: str | None, refine: bool, config: dict | None = None, backend: str = "rust"
) -> Callable[[Any], np.ndarray]:
    from pointclm import Config
    from pointclm.embedding import resolve
    from pointclm.evaluation import register_scaled, scene_cues

    base = None if config is None else Config(**config)

    # The network loaded once, on the backend asked for (--backend).
    net = None if model is None else resolve(model, backend)

    def run(scene: Any) -> np.ndarray:
        # The pipeline's own defaults for raw or refined poses (or the model's recommended
        # thresholds), scaled to the voxel, exactly as `register_point_clouds` picks them.
        r = register_scaled(
            scene.correspondences, scene.voxel_size, base, 0, 1, net, refine, scene_cues(scene)
        )
        poses = _poses(r.transformations)
        return _refine(scene, poses) if refine else poses

    return run


def oracle(refine: bool) -> Callable[[Any], np.ndarray]:
    """The poses of the oracle embedding (the true labels), refined on the clouds if `refine`:
    an upper bound, not a method."""
    import pointclm
    from pointclm.point_clouds import scaled_config
    from realistic import ORACLE_CONFIG, oracle_features

    def run(scene: Any) -> np.ndarray:
        cfg = scaled_config(scene.voxel_size, pointclm.Config(**ORACLE_CONFIG))
        feats = oracle_features(scene.labels, scene.seed % 2**32)
        poses = _poses(
            pointclm.register(scene.correspondences, feats, cfg, 0, num_threads=1).transformations
        )
        return _refine(scene, poses) if refine else poses

    return run


def _peer(name: str) -> Callable[[Any], np.ndarray]:
    import peers
    from pointclm.point_clouds import scaled_config

    def run(scene: Any) -> np.ndarray:
        # In units of the model's diagonal: KISS-Matcher clamps its noise bounds at 1.0 (made
        # for metres in large maps), which would loosen them on a model measured in
        # millimetres. Rigid registration is otherwise unit-free; poses are scaled back.
        unit = scene.diameter
        radius = 2.0 * scene.voxel_size / unit  # the scenes' inlier definition
        least = scaled_config(scene.voxel_size).min_cluster_size
        solve = peers.sequential_kiss if name == "kiss" else peers.sequential_ransac
        poses = _poses(solve(scene.correspondences / unit, radius, least))
        poses[:, :3, 3] *= unit
        return poses

    return run


#: Where the report goes unless --out says otherwise: not over the committed results
#: (out/ is not committed).
DEFAULT_OUT = "out/realistic_models.md"


def peers_to_run(kiss: bool, ransac: bool, skip_missing: bool) -> tuple[bool, bool]:
    """Whether to run the KISS-Matcher and the RANSAC peers, of those asked for. A peer asked
    for but not installed stops the run here, before any scene is built, naming the package,
    unless `skip_missing`: then it is left out, and said so."""
    import peers

    wanted = {"sequential KISS-Matcher": "kiss_matcher"} if kiss else {}
    wanted |= {"sequential RANSAC (Open3D)": "open3d"} if ransac else {}
    if not skip_missing:
        peers.require_peers(wanted, "--skip-missing-peers (or --no-kiss / --no-ransac)")
        return kiss, ransac
    missing = peers.missing_peers(wanted)
    for method, module in missing.items():
        print(f"leaving out {method}: the module {module!r} is not installed", flush=True)
    return kiss and "kiss_matcher" not in missing.values(), ransac and (
        "open3d" not in missing.values()
    )


def _available(module: str) -> str | None:
    """The module's version if it imports, else None."""
    try:
        mod = __import__(module)
    except ImportError:
        return None
    return str(getattr(mod, "__version__", "?"))


def make_methods(
    models: Sequence[str],
    ransac: bool,
    kiss: bool = True,
    backend: str = "rust",
    configs: Sequence[tuple[str, dict, bool]] = (),
) -> list[Method]:
    """The rows: training-free (and one per `configs` entry: key, thresholds, refine), each
    network of `models` (run on `backend`), the oracle and the peers."""
    out = [
        Method(
            "pointclm", "pointclm, training-free, correspondences alone", _pointclm(None, False)
        ),
        Method(
            "pointclm+refine",
            "pointclm, training-free + refinement on the clouds",
            _pointclm(None, True),
        ),
    ]
    for key, cfg, refine in configs:
        what = "refinement on the clouds" if refine else "correspondences alone"
        label = f"pointclm, training-free, thresholds {json.dumps(cfg)}, {what}"
        out.append(Method(key, label, _pointclm(None, refine, cfg)))
    for m in models:
        out.append(
            Method(
                f"{m}", f"pointclm, learned embedding ({m!r})", _pointclm(m, False, None, backend)
            )
        )
        out.append(
            Method(
                f"{m}+refine",
                f"pointclm, learned embedding ({m!r}) + refinement on the clouds",
                _pointclm(m, True, None, backend),
            )
        )
    out.append(
        Method("oracle", "upper bound: oracle embedding from the true labels", oracle(False))
    )
    out.append(
        Method(
            "oracle+refine",
            "upper bound: oracle embedding + refinement on the clouds",
            oracle(True),
        )
    )
    kiss_version = _available("kiss_matcher") if kiss else None
    if kiss_version:
        out.append(Method("kiss", f"sequential KISS-Matcher ({kiss_version})", _peer("kiss")))
    o3d_version = _available("open3d") if ransac else None
    if o3d_version:
        out.append(Method("ransac", f"sequential RANSAC (Open3D {o3d_version})", _peer("ransac")))
    return out


# --- running and scoring ------------------------------------------------------------------


def run_methods(scenes: Sequence[Any], methods: Sequence[Method]) -> list[dict[str, Any]]:
    """One record per (scene, method): the scene's identity, the score and the wall time."""
    from pointclm.metrics import score_scene

    rows = []
    t_all = time.perf_counter()
    for i, sc in enumerate(scenes):
        for m in methods:
            # Each method runs twice back to back and keeps its faster time: the first run
            # shares the cores with the previous method's worker threads, which spin for a
            # while after it returns (pointclm right after KISS-Matcher: 2.9 ms, after a pause
            # 2.0), and a pool woken from sleep pays for it (KISS-Matcher after a 0.2 s pause:
            # 13 ms against 2). The second run sees the method's own steady state, as a loop
            # over many scans would. The poses are the same (every method is seeded).
            secs = float("inf")
            for _ in range(TIMED_RUNS):
                t = time.perf_counter()
                poses = m.run(sc)
                secs = min(secs, time.perf_counter() - t)
            s = score_scene(poses, sc.poses, 15.0, sc.max_translation)
            rows.append(
                {
                    "model": sc.model,
                    "seed": sc.seed,
                    "method": m.key,
                    "seconds": secs,
                    **dataclasses.asdict(s),
                }
            )
        if (i + 1) % 10 == 0 or i + 1 == len(scenes):
            print(
                f"  {i + 1}/{len(scenes)} scenes scored, {time.perf_counter() - t_all:.0f} s",
                flush=True,
            )
    return rows


def summary(rows: Sequence[dict[str, Any]]) -> dict[str, float]:
    """MR, MP, MF (paper), strict F1, predictions / GT (totals over the scenes), median and
    p90 ms of one method's records."""
    from pointclm.metrics import SceneScore, summarize

    fields = {f.name for f in dataclasses.fields(SceneScore)}
    s = summarize([SceneScore(**{k: v for k, v in r.items() if k in fields}) for r in rows])
    secs = np.array([r["seconds"] for r in rows])
    return {
        "MR": 100 * s.mean_recall,
        "MP": 100 * s.mean_precision,
        "MF": 100 * s.mean_f1,
        "strict F1": 100 * s.strict_f1,
        "pred/GT": sum(r["n_pred"] for r in rows) / max(sum(r["n_gt"] for r in rows), 1),
        "median ms": 1e3 * float(np.median(secs)),
        "p90 ms": 1e3 * float(np.percentile(secs, 90)),
        "scenes": len(rows),
    }


def _table(rows: Sequence[dict[str, Any]], methods: Sequence[Method]) -> list[str]:
    out = [
        "| method | MR | MP | MF (paper) | strict F1 | pred / GT | median ms | p90 ms |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for m in methods:
        mine = [r for r in rows if r["method"] == m.key]
        if not mine:
            continue
        s = summary(mine)
        out.append(
            f"| {m.label} | {s['MR']:.2f} | {s['MP']:.2f} | {s['MF']:.2f} | "
            f"{s['strict F1']:.2f} | {s['pred/GT']:.2f} | {s['median ms']:.1f} | "
            f"{s['p90 ms']:.1f} |"
        )
    return out


def _per_model(
    rows: Sequence[dict[str, Any]], methods: Sequence[Method], models: Sequence[str], stat: str
) -> list[str]:
    fmt = "{:.2f}" if stat == "pred/GT" else "{:.1f}"
    out = [
        "| model | " + " | ".join(m.key for m in methods) + " |",
        "|---|" + "---|" * len(methods),
    ]
    for model in models:
        cells = []
        for m in methods:
            mine = [r for r in rows if r["method"] == m.key and r["model"] == model]
            cells.append(fmt.format(summary(mine)[stat]) if mine else "-")
        out.append(f"| {model} | " + " | ".join(cells) + " |")
    return out


def scene_stats(scenes: Sequence[Any], models: Sequence[str]) -> list[str]:
    """Per model: correspondences, instances, inliers per instance, scene points, build time."""
    out = [
        "| model | split | scenes | median corr. | instances / scene | median inliers per "
        "instance | instances with < 3 inliers | median scene points | median build s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    from pointclm.datasets.scenes import HELDOUT_MODELS

    for model in models:
        mine = [s for s in scenes if s.model == model]
        if not mine:
            continue
        inl = np.concatenate(
            [np.bincount(s.labels[s.labels >= 0], minlength=s.n_instances) for s in mine]
        )
        out.append(
            f"| {model} | {'held-out' if model in HELDOUT_MODELS else 'validation'} | "
            f"{len(mine)} | {int(np.median([len(s.correspondences) for s in mine]))} | "
            f"{np.mean([s.n_instances for s in mine]):.1f} | {np.median(inl):.0f} | "
            f"{100 * np.mean(inl < 3):.0f} % | "
            f"{int(np.median([len(s.target_points) for s in mine]))} | "
            f"{np.median([s.timings.get('total', np.nan) for s in mine]):.2f} |"
        )
    return out


# --- N = 50,000 in a child process ----------------------------------------------------------


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def scale_child(path: str, threads: int, model: str | None = None) -> None:
    """Child mode: load one cached scene, register it once (training-free, or with the
    learned embedding `model` and its thresholds for raw poses), print one JSON line."""
    import pointclm
    from pointclm.metrics import score_scene
    from pointclm.point_clouds import cloud_config, scaled_config

    scene = load_scene(Path(path))
    cfg = cloud_config(scene.voxel_size, model, False) if model else scaled_config(scene.voxel_size)
    baseline = _peak_mb()
    t = time.perf_counter()
    r = pointclm.register(scene.correspondences, None, cfg, 0, num_threads=threads, model=model)
    seconds = time.perf_counter() - t
    peak = _peak_mb()
    s = score_scene(_poses(r.transformations), scene.poses, 15.0, scene.max_translation)
    print(
        json.dumps(
            {
                "model": scene.model,
                "method": model or "training-free",
                "n": len(scene.correspondences),
                "inliers": int((scene.labels >= 0).sum()),
                "threads": threads,
                "seconds": seconds,
                "timings": dict(r.timings),
                "baseline_mb": baseline,
                "peak_mb": peak,
                "found": s.n_pred,
                "gt": s.n_gt,
                "matched": s.n_matched,
                "strict_f1": s.strict_f1,
            }
        )
    )


def run_scale(
    n: int,
    cache: Path,
    data_dir: str | None,
    workers: int,
    timeout: float = 600,
    models: Sequence[str] = (),
) -> list[str]:
    jobs = [(m, benchmark_seeds(m, 1)[0], scale_params(m, n, data_dir)) for m in SCALE_MODELS]
    load_scenes(jobs, cache, workers)  # builds what the cache lacks; the children read it
    # Through sh, which forks python rather than exec'ing it: the child's ru_maxrss then starts
    # from sh's small RSS, not this process's. The address-space cap keeps a runaway
    # allocation from taking the shared machine down.
    sh = 'ulimit -v 8000000; "$@"; exit $?'
    results, failures = [], []
    runs = [
        (model, seed, params, method, threads)
        for model, seed, params in jobs
        for method in (None, *models)
        for threads in sorted({1, os.cpu_count() or 1})
    ]
    for model, seed, params, method, threads in runs:
        path = cache_path(cache, model, seed, params)
        label = method or "training-free"
        cmd = ["/bin/sh", "-c", sh, "sh", sys.executable, __file__]
        cmd += ["--scale-child", str(path), "--threads", str(threads)]
        cmd += ["--scale-model", method] if method else []
        t = time.perf_counter()
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            failures.append(f"{model} {label}, {threads} thread(s): over {timeout:.0f} s, stopped")
            continue
        if proc.returncode != 0:
            tail = proc.stderr.strip().splitlines()[-1:] or ["?"]
            failures.append(
                f"{model} {label}, {threads} thread(s): exit {proc.returncode} after "
                f"{time.perf_counter() - t:.0f} s ({tail[0]})"
            )
            continue
        results.append(json.loads(proc.stdout.strip().splitlines()[-1]))
        print(
            f"  scale {model} {label} {threads} thread(s): {results[-1]['seconds']:.2f} s",
            flush=True,
        )
    out = [
        f"### N = {n:,} realistic correspondences: time and peak memory",
        "",
        "Scenes: each model's first benchmark seed, 8 copies and 3 clutter objects, "
        f"voxel = diagonal / 80, FPFH matches without the mutual filter, the top {n:,} kept. One "
        "`pointclm.register` (training-free: the default config scaled to the voxel; learned: "
        "the network's thresholds for raw poses, `cloud_config(voxel, model, False)`; "
        "correspondences alone) per fresh child process; peak RSS = `ru_maxrss`, baseline = "
        "after loading the scene. The learned wall time includes the network's forward pass.",
        "",
        "| model | method | N | true matches | threads | wall s | pruning s | clustering s "
        "| poses s | baseline MB | peak MB | found / GT | correct |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        t = r["timings"]
        out.append(
            f"| {r['model']} | {r.get('method', 'training-free')} | {r['n']} | {r['inliers']} "
            f"| {r['threads']} | {r['seconds']:.2f} | "
            f"{t.get('pruning', float('nan')):.2f} | {t.get('clustering', float('nan')):.2f} | "
            f"{t.get('poses', float('nan')):.3f} | {r['baseline_mb']:.0f} | "
            f"{r['peak_mb']:.0f} | {r['found']} / {r['gt']} | {r['matched']} |"
        )
    out += [f"- failed: {f}" for f in failures]
    return out


# --- main -----------------------------------------------------------------------------------


def _resolve_models(spec: str) -> list[str]:
    from pointclm.datasets.scenes import HELDOUT_MODELS, VALIDATION_MODELS

    groups = {
        "all": [*HELDOUT_MODELS, *VALIDATION_MODELS],
        "heldout": list(HELDOUT_MODELS),
        "validation": list(VALIDATION_MODELS),
    }
    out: list[str] = []
    for part in (p.strip() for p in spec.split(",") if p.strip()):
        for m in groups.get(part, [part]):
            if m not in HELDOUT_MODELS and m not in VALIDATION_MODELS:
                raise SystemExit(
                    f"unknown model {m!r}: use all, heldout, validation or names from "
                    f"{', '.join(groups['all'])}"
                )
            if m not in out:
                out.append(m)
    return out


def _git_commit() -> str:
    proc = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=HERE
    )
    dirty = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=no"],
        capture_output=True,
        text=True,
        cwd=HERE,
    ).stdout.strip()
    return proc.stdout.strip() + (" + uncommitted changes" if dirty else "")


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--models", default="all", help="all, heldout, validation, or names")
    ap.add_argument("--scenes-per-model", type=int, default=8)
    ap.add_argument("--n", type=int, default=1000, help="correspondences per scene (1000, 5000)")
    ap.add_argument("--model", action="append", default=[], help="learned embedding(s)")
    ap.add_argument("--backend", default="rust", choices=["rust", "torch"], help="of --model")
    ap.add_argument("--config", help="JSON thresholds: one more training-free row, raw poses")
    ap.add_argument("--refined-config", help="JSON thresholds: one more refined row")
    ap.add_argument("--scale", type=int, default=50_000, help="N of the timed run (0: skip)")
    ap.add_argument("--no-ransac", action="store_true", help="leave the slow RANSAC peer out")
    ap.add_argument("--no-kiss", action="store_true", help="leave the KISS-Matcher peer out")
    ap.add_argument(
        "--skip-missing-peers",
        action="store_true",
        help="leave out the peers that are not installed (default: stop, naming them)",
    )
    ap.add_argument("--quick", action="store_true", help="CI-sized: 2 scenes of 4 models")
    ap.add_argument("--cache", default="out/realistic_scenes")
    ap.add_argument("--data-dir", default=None, help="default: $POINTCLM_DATA_DIR or ../shared")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument(
        "--out",
        default=DEFAULT_OUT,
        help=f"the report (default {DEFAULT_OUT}; benchmarks/results/ holds the committed ones)",
    )
    ap.add_argument(
        "--seeds",
        choices=("benchmark", "threshold"),
        default="benchmark",
        help="benchmark_seeds (the reported scenes) or threshold_seeds (the scenes defaults "
        "are chosen on; with --models validation, the validation set of BENCHMARKS.md)",
    )
    ap.add_argument("--scale-child", help=argparse.SUPPRESS)
    ap.add_argument("--scale-model", help=argparse.SUPPRESS)
    ap.add_argument("--threads", type=int, default=1, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.scale_child:
        scale_child(args.scale_child, args.threads, args.scale_model)
        return

    from pointclm.datasets.scenes import HELDOUT_MODELS, VALIDATION_MODELS, default_data_dir

    if args.quick:
        args.models = ",".join(QUICK_MODELS) if args.models == "all" else args.models
        args.scenes_per_model = min(args.scenes_per_model, 2)
        args.scale, args.no_ransac = 0, True
    models = _resolve_models(args.models)
    kiss, ransac = peers_to_run(not args.no_kiss, not args.no_ransac, args.skip_missing_peers)
    data_dir = args.data_dir or (str(default_data_dir()) if default_data_dir() else None)
    if data_dir is None and any("/" in m for m in models):
        raise SystemExit("the data folder is missing: pass --data-dir or set POINTCLM_DATA_DIR")
    cache = Path(args.cache)
    load0 = os.getloadavg()[0]
    t_start = time.perf_counter()

    pick = threshold_seeds if args.seeds == "threshold" else benchmark_seeds
    seeds = {m: pick(m, args.scenes_per_model) for m in models}
    jobs = [(m, s, scene_params(m, args.n, data_dir)) for m in models for s in seeds[m]]
    scenes = load_scenes(jobs, cache, args.workers)
    configs = [
        (key, json.loads(text), refine)
        for key, text, refine in (
            ("pointclm-config", args.config, False),
            ("pointclm-config+refine", args.refined_config, True),
        )
        if text
    ]
    methods = make_methods(args.model, ransac, kiss, args.backend, configs)
    print(f"{len(scenes)} scenes, methods: {', '.join(m.key for m in methods)}", flush=True)
    rows = run_methods(scenes, methods)
    scale_lines = (
        run_scale(args.scale, cache, data_dir, args.workers, models=args.model)
        if args.scale
        else []
    )

    import pointclm

    held = [m for m in models if m in HELDOUT_MODELS]
    val = [m for m in models if m in VALIDATION_MODELS]
    cmd = " ".join(["python", "benchmarks/realistic_models.py", *(argv or sys.argv[1:])])
    minutes = (time.perf_counter() - t_start) / 60
    lines = [
        f"# Realistic benchmark over the models, N = {args.n}",
        "",
        f"- Date: {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC. Command: `{cmd}`.",
        f"- Hardware: {platform.processor() or platform.machine()}, {os.cpu_count()} cores "
        f"(load average {load0:.1f} at the start: times are wall clock on a shared machine). "
        "pointclm on 1 thread; KISS-Matcher and Open3D with their default threads.",
        f"- Code: pointclm {pointclm.__version__}, git {_git_commit()}.",
        f"- Scenes: {args.scenes_per_model} per model, model i (in the order below) seeds "
        f"{BENCHMARK_SEED_BASE} + 1000 i + 0..{args.scenes_per_model - 1} "
        "(disjoint from threshold and training scenes); "
        + (
            f"FPFH, mutual nearest neighbours, top 10,000, at most {args.n} drawn"
            if args.n <= 1000
            else f"FPFH, no mutual filter, the top {args.n} matches"
        )
        + ". An instance is registered when RE < 15 deg and TE < 10 % of the model's diagonal. "
        "pred / GT: predicted instances over true instances, totals over the scenes.",
        f"- The whole run took {minutes:.1f} min (scenes from the cache where present).",
        "",
    ]
    if held:
        lines += [
            f"## Headline: pooled over the held-out models ({', '.join(held)})",
            "",
            "No threshold or default was chosen on these models.",
            "",
            *_table([r for r in rows if r["model"] in held], methods),
            "",
        ]
    if val:
        lines += [
            f"## Validation models, pooled ({', '.join(val)})",
            "",
            "In-sample: thresholds and defaults are picked on these models "
            "(`realistic_thresholds.py`, on other seeds), so these are not results.",
            "",
            *_table([r for r in rows if r["model"] in val], methods),
            "",
        ]
    order = held + val
    lines += [
        "## Per model",
        "",
        "Columns: " + "; ".join(f"`{m.key}` = {m.label}" for m in methods) + ".",
        "",
        "MF (paper):",
        "",
        *_per_model(rows, methods, order, "MF"),
        "",
        "Predictions / ground truth:",
        "",
        *_per_model(rows, methods, order, "pred/GT"),
        "",
        "Median ms per scene:",
        "",
        *_per_model(rows, methods, order, "median ms"),
        "",
        "Scenes:",
        "",
        *scene_stats(scenes, order),
        "",
    ]
    lines += scale_lines
    text = "\n".join(lines).rstrip() + "\n"
    print(text)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    meta = {"command": cmd, "methods": {m.key: m.label for m in methods}, "rows": rows}
    out.with_suffix(".json").write_text(json.dumps(meta, indent=0) + "\n")
    print(f"report written to {out} (and {out.with_suffix('.json').name} beside it)")


if __name__ == "__main__":
    main()

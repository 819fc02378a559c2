"""Each stage's time against the arithmetic it needs.

    python -m benchmarks.correspondences.stage_limits [--synthetic 100] [--realistic-cache DIR]
        [--clouds-cache DIR] [--bins-cache DIR] [--out FILE]

For every stage of the training-free correspondence pipeline (`register`, one thread) this
prints the measured median time, a count of the floating-point operations the stage cannot do
without (a lower bound of its arithmetic, below), the time that arithmetic takes at this
machine's measured peak, and the ratio between the two. The peak is measured in the same run
(numpy's single-threaded matrix product, f32 and f64), so the ratio stays meaningful on a
shared, noisy machine.

The arithmetic models (operations per unit, counted on the formulas the code evaluates):

- pruning: every unordered pair {i, j} of the N correspondences (the test is symmetric, so each
  pair is tested once and counted for both rows): two squared lengths (10), two square roots
  (2), a difference, a square and two comparisons (4): 16 f32 operations.
- clustering: the affinity of the k kept rows (k^2 pairs at about 16 f64 operations), plus the
  tridiagonal reduction a dense symmetric eigensolver needs (4/3 k^3); a partial solver may
  need less, so the bound is loose from `clustering::PARTIAL_ROWS` (64) rows.
- poses: every candidate pose (one per cluster) applied to all N correspondences with its
  residual (about 20 operations per correspondence), twice (inliers and the a-contrario
  test's own count), plus the test's radius count (about 10 per visited point, at least one
  per correspondence); RANSAC's hypotheses are not counted (their number is data-dependent).

Point clouds in (`register_point_clouds`, one thread; ``--clouds-cache`` for the realistic
held-out scenes, ``--bins-cache`` for the held-out bins), per stage on the downsampled clouds
(scan and model both), neighbours counted with scipy outside the timed call:

- normals: per neighbour (at most 30 within 2 voxels) its share of the mean and the 3 x 3
  covariance (21), per point a 3 x 3 symmetric eigenproblem (about 150): f64.
- fpfh: per neighbour pair (at most 100 within 5 voxels, the point itself excluded) the Darboux
  frame and its three angles (about 70, plus about 15 for the arctangent), and its share of
  the weighted sum (33 divisions and 66 additions): about 185, f64.
- matching: each scan descriptor's nearest model descriptor by brute force, 2 x 33 operations
  per (scan, model) pair, f32 (the screen's matrix products; the mutual check and the later
  passes reuse these nearest rows).
- refinement and peeling (ICP, verification by visibility, later passes): not modelled; the
  ICP iterations and the number of candidates depend on the data, so only the time is given.

A ratio of 10 means the stage runs ten times longer than its arithmetic at peak: the distance
left to the limit. Memory traffic is not the limit for any stage at these sizes (N = 1000
rows of 6 doubles is 48 KB; everything stays in cache).
"""

from __future__ import annotations

import os

# The reference (numpy's BLAS) and pointclm both on one thread; before numpy is imported.
for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.common import report  # noqa: E402

PAIR_FLOPS = 16
AFFINITY_FLOPS = 16
POSE_FLOPS = 20
RADIUS_FLOPS = 10
REPEATS = 3
NORMAL_NEIGHBOUR_FLOPS = 21
NORMAL_POINT_FLOPS = 150
FPFH_PAIR_FLOPS = 185
DESCRIPTOR_DIM = 33


def peak_gflops(dtype: type, n: int = 1024, repeats: int = 5) -> float:
    """Single-threaded matrix-product speed in GFLOP/s: the machine's attainable peak."""
    rng = np.random.default_rng(0)
    a = rng.standard_normal((n, n)).astype(dtype)
    b = rng.standard_normal((n, n)).astype(dtype)
    a @ b
    best = min(_timed(lambda: a @ b) for _ in range(repeats))
    return 2 * n**3 / best / 1e9


def _timed(fn: Callable[[], Any]) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def stage_flops(n: int, kept: int, clusters: int) -> dict[str, tuple[float, str]]:
    """The lower-bound operation counts of each stage and the precision they run in."""
    return {
        "pruning": (PAIR_FLOPS * n * (n + 1) // 2, "f32"),
        "clustering": (AFFINITY_FLOPS * kept**2 + 4 / 3 * kept**3, "f64"),
        "poses": (clusters * n * (2 * POSE_FLOPS + RADIUS_FLOPS), "f64"),
    }


def fastest(call: Callable[..., Any], *args: Any, **kwargs: Any) -> tuple[float, Any]:
    """The shortest wall time of `REPEATS` calls ``call(*args, **kwargs)``, and that call's
    result."""
    best: tuple[float, Any] | None = None
    for _ in range(REPEATS):
        t = time.perf_counter()
        result = call(*args, **kwargs)
        wall = time.perf_counter() - t
        if best is None or wall < best[0]:
            best = (wall, result)
    assert best is not None
    return best


def measure(scenes: Sequence[Any], config_for: Callable[[Any], Any]) -> list[dict[str, Any]]:
    """Per scene: the fastest of `REPEATS` runs' stage times, and the sizes the models need."""
    import pointclm

    rows = []
    for sc in scenes:
        cfg = config_for(sc)
        wall, r = fastest(pointclm.register, sc.correspondences, None, cfg, 0, num_threads=1)
        rows.append(
            {
                "wall": wall,
                "timings": dict(r.timings),
                "n": len(sc.correspondences),
                "kept": len(r.kept),
                "clusters": r.n_clusters,
            }
        )
    return rows


def limit_row(
    stage: str,
    rows: Sequence[dict[str, Any]],
    flops: Sequence[tuple[float, str]],
    peak: dict[str, float],
    digits: tuple[int, int, int],
) -> str:
    """One stage's markdown row: median time, median arithmetic (`flops`: count and precision
    per scene), its time at peak, and the median ratio; `digits` for the first three."""
    ms = [1e3 * r["timings"][stage] for r in rows]
    limit = [1e3 * f / (peak[p] * 1e9) for f, p in flops]
    ratio = [m / max(lim, 1e-9) for m, lim in zip(ms, limit, strict=True)]
    d_ms, d_flops, d_limit = digits
    return (
        f"| {stage} | {np.median(ms):.{d_ms}f} | "
        f"{np.median([f for f, _ in flops]) / 1e6:.{d_flops}f} "
        f"| {np.median(limit):.{d_limit}f} | {np.median(ratio):.1f} |"
    )


def table(name: str, rows: Sequence[dict[str, Any]], peak: dict[str, float]) -> list[str]:
    """Markdown rows: per stage, median time, median lower-bound arithmetic and the ratio."""
    out = [
        f"### {name}: {len(rows)} scenes, median N = {np.median([r['n'] for r in rows]):.0f}, "
        f"median kept rows = {np.median([r['kept'] for r in rows]):.0f}",
        "",
        "| stage | median ms | arithmetic (MFLOP) | at peak (ms) | time / limit |",
        "|---|---|---|---|---|",
    ]
    for stage in ("pruning", "clustering", "poses"):
        flops = [stage_flops(r["n"], r["kept"], r["clusters"])[stage] for r in rows]
        out.append(limit_row(stage, rows, flops, peak, (3, 2, 4)))
    wall = [1e3 * r["wall"] for r in rows]
    out.append(f"| whole call | {np.median(wall):.3f} | | | |")
    return out + [""]


def neighbour_counts(points: np.ndarray, radius: float, max_nn: int) -> int:
    """Neighbours within `radius` of every point (itself excluded), each capped at `max_nn - 1`."""
    from scipy.spatial import cKDTree

    n = cKDTree(points).query_ball_point(points, radius, return_length=True)
    return int(np.minimum(n, max_nn).sum() - len(points))


def cloud_flops(reg: Any) -> dict[str, tuple[float, str]]:
    """The point-cloud stages' lower-bound operation counts (module docstring)."""
    voxel = reg.voxel_size
    clouds = (reg.source_points, reg.target_points)
    normals = sum(
        NORMAL_NEIGHBOUR_FLOPS * neighbour_counts(c, 2 * voxel, 30) + NORMAL_POINT_FLOPS * len(c)
        for c in clouds
    )
    fpfh = sum(FPFH_PAIR_FLOPS * neighbour_counts(c, 5 * voxel, 100) for c in clouds)
    matching = 2 * DESCRIPTOR_DIM * len(reg.source_points) * len(reg.target_points)
    return {"normals": (normals, "f64"), "fpfh": (fpfh, "f64"), "matching": (matching, "f32")}


def measure_clouds(scenes: Sequence[tuple[Any, ...]]) -> list[dict[str, Any]]:
    """Per scene `(model, scan, voxel, viewpoint)`: the fastest of `REPEATS`
    `register_point_clouds` calls on one thread, and its stages' operation counts."""
    import pointclm

    rows = []
    for model, scan, voxel, view in scenes:
        wall, reg = fastest(
            pointclm.register_point_clouds, model, scan, voxel, viewpoint=view, num_threads=1
        )
        rows.append(
            {
                "wall": wall,
                "timings": dict(reg.timings),
                "flops": cloud_flops(reg),
                "points": (len(reg.source_points), len(reg.target_points)),
            }
        )
    return rows


def cloud_table(name: str, rows: Sequence[dict[str, Any]], peak: dict[str, float]) -> list[str]:
    """Markdown rows of the point-cloud stages (see :func:`table`)."""
    model, scan = (np.median([r["points"][k] for r in rows]) for k in (0, 1))
    out = [
        f"### {name}: {len(rows)} scenes, median {scan:.0f} scan and {model:.0f} model points "
        "after downsampling",
        "",
        "| stage | median ms | arithmetic (MFLOP) | at peak (ms) | time / limit |",
        "|---|---|---|---|---|",
    ]
    for stage in ("normals", "fpfh", "matching"):
        flops = [r["flops"][stage] for r in rows]
        out.append(limit_row(stage, rows, flops, peak, (1, 1, 2)))
    for stage in ("registration", "refinement", "peeling"):
        ms = [1e3 * r["timings"][stage] for r in rows]
        out.append(f"| {stage} | {np.median(ms):.1f} | not modelled | | |")
    wall = [1e3 * r["wall"] for r in rows]
    out.append(f"| whole call | {np.median(wall):.1f} | | | |")
    return out + [""]


def cloud_scenes(cache: Path, per_model: int) -> list[tuple[Any, ...]]:
    """The realistic held-out scenes with their clouds (``clouds/realistic_models.py``'s cache)."""
    from pointclm.datasets.scenes import HELDOUT_MODELS, default_data_dir

    from benchmarks.clouds.scenes import benchmark_seeds, load_scenes, scene_params

    dd = str(default_data_dir())
    jobs = [
        (m, s, scene_params(m, 1000, dd))
        for m in HELDOUT_MODELS
        for s in benchmark_seeds(m, per_model)
    ]
    return [
        (sc.source_points, sc.target_points, sc.voxel_size, sc.viewpoint)
        for sc in load_scenes(jobs, cache, 2, progress=False)
    ]


def bin_scenes(cache: Path, per_model: int) -> list[tuple[Any, ...]]:
    """The held-out bins (``bins/run.py``'s scenes and cache)."""
    from pointclm.datasets.bins import BIN_MODELS_HELD_OUT, BinParams, bin_scene_cached

    scenes = []
    for model in BIN_MODELS_HELD_OUT:
        for seed in range(per_model):
            sc = bin_scene_cached(cache, seed, BinParams(model=model, copies=(20, 80)))
            scenes.append((sc.model_points, sc.scan, sc.voxel_size, sc.sensor))
    return scenes


def synthetic(count: int) -> tuple[list[Any], Callable[[Any], Any]]:
    import pointclm
    from pointclm.datasets.synthetic import make_scenes

    return list(make_scenes(count, seed=0)), lambda _: pointclm.Config()


def realistic(cache: Path, per_model: int) -> tuple[list[Any], Callable[[Any], Any]]:
    from pointclm.datasets.scenes import HELDOUT_MODELS, default_data_dir
    from pointclm.point_clouds import cloud_config

    from benchmarks.clouds.scenes import benchmark_seeds, load_scenes, scene_params

    dd = str(default_data_dir())
    jobs = [
        (m, s, scene_params(m, 1000, dd))
        for m in HELDOUT_MODELS
        for s in benchmark_seeds(m, per_model)
    ]
    scenes = load_scenes(jobs, cache, 2, progress=False)
    return scenes, lambda sc: cloud_config(sc.voxel_size, None, False)


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--synthetic", type=int, default=100, help="synthetic scenes (0: none)")
    ap.add_argument(
        "--realistic-cache",
        type=Path,
        help="clouds/realistic_models.py's scene cache (held-out models, N = 1000); omitted: none",
    )
    ap.add_argument("--realistic-per-model", type=int, default=4)
    ap.add_argument(
        "--clouds-cache",
        type=Path,
        help="clouds/realistic_models.py's scene cache, for register_point_clouds; omitted: none",
    )
    ap.add_argument("--clouds-per-model", type=int, default=2)
    ap.add_argument("--bins-cache", type=Path, help="bins/run.py's scene cache; omitted: none")
    ap.add_argument("--bins-per-model", type=int, default=1)
    ap.add_argument("--out", type=Path, help="also write the report here (markdown)")
    args = ap.parse_args(argv)
    import pointclm

    peak = {"f32": peak_gflops(np.float32), "f64": peak_gflops(np.float64)}
    lines = [
        "# Stage times against their arithmetic (one thread)",
        "",
        f"- Date: {report.utc_now()}; pointclm {pointclm.__version__} "
        f"(git {report.git_commit()}); {report.hardware()}.",
        f"- Command: `{report.command(__spec__.name, argv)}`",
        f"- Peak (numpy matrix product, one thread, same run): f32 {peak['f32']:.1f} GFLOP/s, "
        f"f64 {peak['f64']:.1f} GFLOP/s.",
        f"- Each scene: the fastest of {REPEATS} calls; the arithmetic models are in the "
        "script's docstring.",
        "",
    ]
    if args.synthetic:
        scenes, cfg = synthetic(args.synthetic)
        lines += table("synthetic (paper protocol)", measure(scenes, cfg), peak)
    if args.realistic_cache:
        scenes, cfg = realistic(args.realistic_cache, args.realistic_per_model)
        lines += table("realistic, held-out models, N = 1000", measure(scenes, cfg), peak)
    if args.clouds_cache:
        rows = measure_clouds(cloud_scenes(args.clouds_cache, args.clouds_per_model))
        lines += cloud_table("point clouds in, realistic held-out scenes", rows, peak)
    if args.bins_cache:
        rows = measure_clouds(bin_scenes(args.bins_cache, args.bins_per_model))
        lines += cloud_table("point clouds in, held-out bins", rows, peak)
    print("\n".join(lines))
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()

"""The N = 50,000 run of the realistic benchmark: realistic correspondences registered in a
fresh child process that reports the time and the peak memory.

    python -m benchmarks.clouds.scale SCENE.npz [--threads 1] [--model NAME]

runs one child (a cached scene, see `benchmarks.clouds.scenes`) and prints one JSON line;
`benchmarks.clouds.realistic_models` (``--scale``) runs them all and writes the table.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from benchmarks.clouds.scenes import (
    benchmark_seeds,
    cache_path,
    load_scene,
    load_scenes,
    scale_params,
)
from benchmarks.common.report import ROOT, module_command

#: The N = 50,000 scenes: one held-out model with real scans, one mesh.
SCALE_MODELS = ("stanford/bunny", "common3d/teapot")


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
    poses = np.asarray(r.transformations, dtype=np.float64).reshape(-1, 4, 4)
    s = score_scene(poses, scene.poses, 15.0, scene.max_translation)
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
        cmd = ["/bin/sh", "-c", sh, "sh", *module_command(__spec__.name)]
        cmd += [str(path), "--threads", str(threads)]
        cmd += ["--model", method] if method else []
        t = time.perf_counter()
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT)
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


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", help="a cached scene (.npz)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--model", help="a learned embedding (default: training-free)")
    args = ap.parse_args(argv)
    scale_child(args.scene, args.threads, args.model)


if __name__ == "__main__":
    main()

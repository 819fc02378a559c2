"""Figures of the training-free pipeline (issue 2): accuracy, speed against the numpy/scipy/
scikit-learn reference in the same run, batch scaling, and scale/memory at N = 10k and 50k.

    python benchmarks/run_benchmarks.py [--quick] [--scenes 500] [--reference-scenes 100]
                                        [--out BENCHMARKS.md]

The reference is made single-threaded (BLAS threads = 1, set before numpy loads) so that the
one-thread comparison is fair. Writes markdown to --out (between the markers of its section,
keeping the rest of the file) and prints it.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import datetime  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pointclm  # noqa: E402
import scipy  # noqa: E402
import sklearn  # noqa: E402
from pointclm.datasets import make_planted_scene, make_scenes  # noqa: E402
from pointclm.metrics import score_scene, summarize  # noqa: E402
from tqdm import tqdm  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from reference_numpy import register_reference  # noqa: E402

BEGIN, END = "<!-- training-free:begin -->", "<!-- training-free:end -->"

# Runs in a fresh process that only loads the scene, so its peak RSS is register's (plus the
# interpreter, numpy and the extension), not the scene generator's.
SCALE_CHILD = """
import json, sys, time
import numpy as np

def vm(key):  # /proc/self/status, in MB; VmHWM is this process's own peak (ru_maxrss is not:
    # Linux carries it over exec from the parent)
    for line in open("/proc/self/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024

import pointclm
from pointclm.metrics import score_scene
corr, poses = np.load(sys.argv[1]), np.load(sys.argv[2])
before = vm("VmHWM")
t = time.perf_counter()
r = pointclm.register(corr)
dt = time.perf_counter() - t
sc = score_scene(r.transformations, poses)
print(json.dumps({"n": len(corr), "seconds": dt, "timings": r.timings,
                  "kept": len(r.kept), "found": len(r), "gt": len(poses),
                  "strict_f1": sc.strict_f1,
                  "rss_before_mb": before, "peak_mb": vm("VmHWM")}))
"""


def verdict(ok: bool) -> str:
    return "met" if ok else "**NOT met**"


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def timed_register(scenes, **kw):
    seconds, results = [], []
    for s in scenes:
        t = time.perf_counter()
        results.append(pointclm.register(s.correspondences, **kw))
        seconds.append(time.perf_counter() - t)
    return results, np.asarray(seconds)


def table(rows: list[tuple]) -> str:
    head = "| method | scenes | MR | MP | MF | strict F1 | median ms | p90 ms |"
    lines = [head, "|---|---|---|---|---|---|---|---|"]
    for name, summ, sec in rows:
        v = (summ.mean_recall, summ.mean_precision, summ.mean_f1, summ.strict_f1)
        cells = " | ".join(f"{100 * x:.2f}" for x in v)
        p90 = f"{1e3 * np.percentile(sec, 90):.1f}"
        med = f"{1e3 * np.median(sec):.2f}"
        lines.append(f"| {name} | {summ.n_scenes} | {cells} | {med} | {p90} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes, for a smoke test")
    ap.add_argument("--scenes", type=int, default=500)
    ap.add_argument("--reference-scenes", type=int, default=100)
    ap.add_argument("--batch-scenes", type=int, default=200)
    ap.add_argument("--out", default="BENCHMARKS.md")
    args = ap.parse_args()
    if args.quick:
        args.scenes, args.reference_scenes, args.batch_scenes = 20, 4, 20
    command = "python benchmarks/run_benchmarks.py " + " ".join(sys.argv[1:])
    out: list[str] = [BEGIN, "## Training-free pipeline (issue 2)", ""]
    out.append(
        f"Measured {datetime.date.today()} on {cpu_model()} ({os.cpu_count()} cores), "
        f"Python {platform.python_version()}, pointclm {pointclm.__version__}, "
        f"numpy {np.__version__}, scipy {scipy.__version__}, scikit-learn "
        f"{sklearn.__version__}. Command: `{command}`. The reference runs with BLAS "
        "threads = 1."
    )

    scenes = list(make_scenes(args.scenes, seed=0))
    pointclm.register(scenes[0].correspondences, num_threads=1)  # warm-up
    results, sec1 = timed_register(tqdm(scenes, desc="pointclm"), num_threads=1)
    ours = summarize(
        score_scene(r.transformations, s.poses) for r, s in zip(results, scenes, strict=True)
    )
    ref_scenes = scenes[: args.reference_scenes]
    register_reference(ref_scenes[0].correspondences)  # warm-up (imports, caches)
    ref_sec, ref_scores = [], []
    for s in tqdm(ref_scenes, desc="reference"):
        t = time.perf_counter()
        poses = register_reference(s.correspondences)
        ref_sec.append(time.perf_counter() - t)
        ref_scores.append(score_scene(np.asarray(poses).reshape(-1, 4, 4), s.poses))
    ref_sec = np.asarray(ref_sec)
    ours_same = sec1[: len(ref_scenes)]
    ratio = float(np.median(ref_sec) / np.median(ours_same))

    out += ["", f"### Accuracy: synthetic protocol, bunny, {args.scenes} seeded scenes", ""]
    out.append(
        table(
            [
                ("pointclm, training-free, 1 thread", ours, sec1),
                (
                    f"numpy/scipy/sklearn reference (first {len(ref_scenes)})",
                    summarize(ref_scores),
                    ref_sec,
                ),
            ]
        )
    )
    out.append(
        "| paper Table 1, PointCLM (GTX 1080Ti, trained) | - | 92.60 | 99.69 | 96.01 | - | 60 | - |"
    )
    out += [
        "",
        f"- MF >= 97: {verdict(ours.mean_f1 >= 0.97)} ({100 * ours.mean_f1:.2f}); "
        f"strict F1 >= 96: {verdict(ours.strict_f1 >= 0.96)} ({100 * ours.strict_f1:.2f}).",
    ]

    out += ["", "### Speed, N = 1000, one thread", ""]
    out.append(
        f"- pointclm median {1e3 * np.median(sec1):.2f} ms, p90 "
        f"{1e3 * np.percentile(sec1, 90):.2f} ms over {len(sec1)} scenes; target <= 5 ms: "
        f"{verdict(np.median(sec1) <= 0.005)}."
    )
    out.append(
        f"- Same {len(ref_scenes)} scenes: reference median "
        f"{1e3 * np.median(ref_sec):.1f} ms vs pointclm {1e3 * np.median(ours_same):.2f} "
        f"ms: **{ratio:.0f}x**; target >= 40x: {verdict(ratio >= 40)}."
    )
    stages = {k: np.median([r.timings[k] for r in results]) for k in results[0].timings}
    out.append(
        "- Median per stage: "
        + ", ".join(f"{k} {1e3 * v:.2f} ms" for k, v in stages.items())
        + f"; median kept after pruning: {int(np.median([len(r.kept) for r in results]))}."
    )

    batch = [s.correspondences for s in scenes[: args.batch_scenes]]
    rates = {}
    for threads in (1, 2):
        best = min(_timed_batch(batch, threads) for _ in range(3))
        rates[threads] = len(batch) / best
    speedup = rates[2] / rates[1]
    out += ["", f"### Batch throughput, {len(batch)} scenes (best of 3)", ""]
    out.append(
        f"- 1 thread {rates[1]:.0f} scenes/s, 2 threads {rates[2]:.0f} scenes/s: "
        f"**{speedup:.2f}x**; target >= 1.7x: {verdict(speedup >= 1.7)}."
    )

    sizes = [10_000] if args.quick else [10_000, 50_000]
    out += [
        "",
        "### Scale: random-plus-planted scenes (5 bunnies, 2% inliers each)",
        "",
        "| N | seconds | pruning s | clustering s | poses s | kept | found/GT | strict F1 "
        "| peak RSS before register MB | peak RSS MB |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    tmp = Path(tempfile.mkdtemp(prefix="pointclm-bench-"))
    for n in sizes:
        scene = make_planted_scene(n, seed=0)
        np.save(tmp / "corr.npy", scene.correspondences)
        np.save(tmp / "poses.npy", scene.poses)
        proc = subprocess.run(
            [sys.executable, "-c", SCALE_CHILD, str(tmp / "corr.npy"), str(tmp / "poses.npy")],
            capture_output=True,
            text=True,
            check=True,
        )
        r = json.loads(proc.stdout.strip().splitlines()[-1])
        t = r["timings"]
        out.append(
            f"| {n} | {r['seconds']:.2f} | {t['pruning']:.2f} | {t['clustering']:.2f} "
            f"| {t['poses']:.3f} | {r['kept']} | {r['found']}/{r['gt']} "
            f"| {100 * r['strict_f1']:.1f} | {r['rss_before_mb']:.0f} "
            f"| {r['peak_mb']:.0f} |"
        )
        if n == 50_000:
            peak = r["peak_mb"]
            out += ["", f"- Peak under 2 GB at 50,000: {verdict(peak < 2048)} ({peak:.0f} MB)."]
    out.append(END)
    text = "\n".join(out) + "\n"
    print(text)
    _write_section(Path(args.out), text)


def _timed_batch(batch, threads: int) -> float:
    t = time.perf_counter()
    pointclm.register_batch(batch, num_threads=threads)
    return time.perf_counter() - t


def _write_section(path: Path, text: str) -> None:
    old = path.read_text() if path.exists() else "# Benchmarks\n\n"
    if BEGIN in old and END in old:
        new = old[: old.index(BEGIN)] + text.rstrip("\n") + old[old.index(END) + len(END) :]
    else:
        new = old.rstrip("\n") + "\n\n" + text
    path.write_text(new)


if __name__ == "__main__":
    main()

"""`register_point_clouds` in the Rust core (its default) against its Python stages on the same
choices: the same copies, passes and voxel, poses to rounding, and the time of each.

    python benchmarks/scene_core.py [--seeds 3] [--threads 2] [--rounds 2] [--no-flips]
                                    [--model NAME] [--options NAME ...] [--out FILE]

Scenes: bins of the validation models' parts (procedural boxes, fandisk, dragon; 20-30 copies,
the bin's sensor as viewpoint), each with the default heap rule (ranked matching from the tenth
copy on) and said to be a heap (``heap=True``: point pair voting too), and realistic scenes of
the held-out models with their sensor given and without it (estimated from the scan). Both
paths try turned alternatives (``flips=True``, the default; ``--no-flips`` turns them off in
both); ``--model default`` adds the shipped network's embedding to both. ``--options`` runs
every scene with each named set of options too (``OPTIONS``: ``refine=False``, ``k=2``, a
fixed ``mutual_window`` and ``"auto"``; the mutual windows on the bins only, where heaps
need them). Each round runs
every scene with each path in turn (alternating which goes first); the
table takes each scene's fastest call.
"""

from __future__ import annotations

import argparse
import datetime
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


Job = tuple[str, np.ndarray, np.ndarray, tuple[float, float, float] | None, bool | None]

#: The options compared beside the defaults (``--options``), by name.
OPTIONS: dict[str, dict[str, object]] = {
    "default": {},
    "refine=False": {"refine": False},
    "k=2": {"k": 2},
    "mutual_window=0.5": {"mutual_window": 0.5},
    "mutual_window=auto": {"mutual_window": "auto"},
}


def scenes(seeds: int) -> list[Job]:
    """(name, model points, scan points, viewpoint, heap) of every run compared."""
    from pointclm.datasets.bins import BinParams, make_bin_scene
    from pointclm.datasets.scenes import HELDOUT_MODELS, SceneParams, make_realistic_scene

    out = []
    for model in ("box", "common3d/fandisk", "stanford/dragon"):
        for seed in range(seeds):
            sc = make_bin_scene(seed, BinParams(model=model, copies=(20, 30)))
            for heap in (None, True):
                name = f"bin {model} {seed}" + (" heap=True" if heap else "")
                out.append((name, sc.model_points, sc.scan, _view(sc.sensor), heap))
    for model in HELDOUT_MODELS:
        for seed in range(seeds):
            sc = make_realistic_scene(seed, SceneParams(model=model))
            if sc.viewpoint is not None:
                view = _view(sc.viewpoint)
                name = f"realistic {model} {seed}"
                out.append((name, sc.source_points, sc.target_points, view, None))
                name = f"realistic {model} {seed} no viewpoint"
                out.append((name, sc.source_points, sc.target_points, None, None))
    return out


def _view(v: np.ndarray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def main() -> None:
    import pointclm
    from pointclm.clouds import core_path

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--no-flips", action="store_true", help="no turned alternatives")
    ap.add_argument("--model", help="a learned model for both paths (e.g. default)")
    ap.add_argument("--options", nargs="+", default=["default"], choices=list(OPTIONS))
    ap.add_argument("--out", help="write the report here (default: print it)")
    args = ap.parse_args()
    rows = []
    jobs = [
        (f"{name} {option}" if option != "default" else name, model, scan, view, heap, option)
        for name, model, scan, view, heap in scenes(args.seeds)
        for option in args.options
        if name.startswith("bin") or not option.startswith("mutual_window")
    ]
    for name, model, scan, view, heap, option in jobs:
        best = {"python": np.inf, "rust": np.inf}
        py = rs = None
        for r in range(args.rounds):
            for path in ("python", "rust") if r % 2 == 0 else ("rust", "python"):
                core_path.ENABLED = path == "rust"  # False: the Python stages
                t0 = time.perf_counter()
                reg = pointclm.register_point_clouds(
                    model, scan, viewpoint=view, heap=heap, flips=not args.no_flips,
                    num_threads=args.threads, model=args.model, **OPTIONS[option],
                )  # fmt: skip
                best[path] = min(best[path], time.perf_counter() - t0)
                py, rs = (reg, rs) if path == "python" else (py, reg)
        core_path.ENABLED = True
        poses = rs.transformations
        same_count = len(poses) == len(py.instances) and len(rs.passes) == len(py.passes)
        diff = float(np.abs(poses - py.transformations).max()) if same_count and len(poses) else 0
        if same_count:  # and the passes' correspondences, confidences to rounding
            conf = [i.confidence for i in py.instances], [i.confidence for i in rs.instances]
            same_count = np.allclose(conf[0], conf[1], rtol=1e-9, atol=0) and all(
                np.array_equal(a.correspondences, b.correspondences)
                for a, b in zip(py.passes, rs.passes, strict=True)
            )
        rows.append((name, len(py.instances), len(poses), same_count, diff, best))
    lines = [
        f"# Rust scene pipeline against Python ({datetime.date.today()}, {platform.machine()}, "
        f"{args.threads} threads, flips={not args.no_flips}, model={args.model}, options "
        f"{' '.join(args.options)})",
        "",
        "| scene | copies (Python) | copies (Rust) | same copies and passes | max pose diff "
        "| Python s | Rust s | Rust / Python |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, n_py, n_rs, same, diff, best in rows:
        ratio = best["rust"] / best["python"]
        lines.append(
            f"| {name} | {n_py} | {n_rs} | {same} | {diff:.1e} | {best['python']:.3f} "
            f"| {best['rust']:.3f} | {ratio:.2f} |"
        )
    ratios = [b["rust"] / b["python"] for *_, b in rows]
    lines += [
        "",
        f"{sum(r[3] for r in rows)} of {len(rows)} scenes with the same copies and passes; "
        f"largest pose difference {max(r[4] for r in rows):.1e}; time Rust / Python median "
        f"{np.median(ratios):.2f}.",
    ]
    text = "\n".join(lines) + "\n"
    if args.out:
        Path(args.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()

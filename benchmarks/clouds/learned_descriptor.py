"""The learned descriptor against FPFH: true matches per copy, and the time to describe a scan.

    python -m benchmarks.clouds.learned_descriptor [--scenes 3] [--descriptor learned]
        [--out benchmarks/results/clouds/learned_descriptor.md]

Both descriptors run in the Rust core over the same downsampled points and oriented normals
(model normals outwards, scan normals towards the sensor), at the default voxel (the model's
diagonal / 40), and are matched as ``register_point_clouds`` matches (mutual nearest
neighbours, the 10,000 closest, 1,000 drawn with seed 0). A match is true when the scan point
lies on a copy and the copy's true pose puts the model point within 2 voxels of it. Per copy
(visible: at least 30 downsampled scan points for realistic scenes, 30 % visible for sensed
ones) the number of true matches among the 1,000; reported per model and pooled:

- the share of copies with at least 3 true matches (what a pose needs);
- the median true matches per copy and the share of true matches among all.

Two families, both on models the descriptor never trained on: the realistic scenes of the
HELD-OUT models (``pointclm.datasets.scenes``: real bunny scans among rendered copies,
clutter, Gaussian noise), and sensed bins (``pointclm.datasets.sensed``: a pile seen by an
RGB-D camera with structured light or time of flight) of the matrix's held-out parts (bunny,
fandisk, rocker arm, a box, the bracket). Time: describing each scan (normals given), FPFH's
seconds and the learned one's, on the same thread pool; the ratio per scan, median.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from benchmarks.common.report import command, hardware, utc_now, write_report

SENSED_PARTS = ("bunny", "fandisk", "rocker_arm", "box_120x52x50", "bracket")
SENSORS = ("structured_light", "tof")


def _owners(scan: np.ndarray, owner: np.ndarray, described: np.ndarray) -> np.ndarray:
    from scipy.spatial import cKDTree

    return owner[cKDTree(scan).query(described)[1]]


def true_matches(case: dict[str, Any], descriptor: str) -> dict[str, Any]:
    """Per visible copy, true matches of FPFH and of `descriptor`; both descriptors' times."""
    from pointclm import preprocessing as pp
    from pointclm.descriptors import learned_descriptors
    from pointclm.matcher import match_features

    v = case["voxel"]
    src = pp.describe(case["model"], v, away_from=case["model"].mean(0))
    tgt = pp.describe(case["scan"], v, towards=case["eye"])
    owner = _owners(case["scan"], case["owner"], tgt.points)
    t0 = time.perf_counter()
    pp.compute_fpfh(tgt.points, tgt.normals, 5 * v)
    t_fpfh = time.perf_counter() - t0
    t0 = time.perf_counter()
    learned_t = learned_descriptors(tgt.points, tgt.normals, v, descriptor)
    t_learned = time.perf_counter() - t0
    learned_s = learned_descriptors(src.points, src.normals, v, descriptor)
    out: dict[str, Any] = {"t_fpfh": t_fpfh, "t_learned": t_learned, "points": len(tgt.points)}
    pairs = {"fpfh": (src.descriptors, tgt.descriptors), "learned": (learned_s, learned_t)}
    for name, (ds, dt) in pairs.items():
        m = match_features(ds, dt, top_k=10_000, mutual=True, n_samples=1000, seed=0)
        on = owner[m.target]
        per_copy = []
        for k in case["visible"]:
            pose, sel = case["poses"][k], on == k
            moved = src.points[m.source[sel]] @ pose[:3, :3].T + pose[:3, 3]
            per_copy.append(int((np.linalg.norm(moved - tgt.points[m.target[sel]], axis=1)
                                 < 2 * v).sum()))  # fmt: skip
        out[name] = per_copy
        out[f"{name}_matches"] = len(m)
    return out


def realistic_cases(scenes: int) -> Iterator[tuple[str, dict[str, Any]]]:
    from pointclm.datasets.scenes import HELDOUT_MODELS, SceneParams, make_realistic_scene

    from benchmarks.clouds.scenes import benchmark_seeds

    for model in HELDOUT_MODELS:
        for seed in benchmark_seeds(model, scenes):
            s = make_realistic_scene(seed, SceneParams(model=model, n_correspondences=10))
            visible = [k for k in range(s.n_instances) if (s.target_ids == k).sum() >= 30]
            yield model, {"model": s.source_points, "scan": s.target_points,
                          "owner": s.target_ids, "poses": s.poses, "visible": visible,
                          "voxel": s.voxel_size, "eye": s.viewpoint}  # fmt: skip


def sensed_cases(scenes: int) -> Iterator[tuple[str, dict[str, Any]]]:
    from pointclm.datasets.sensed import SensedSceneParams, make_sensed_scene

    for part in SENSED_PARTS:
        for sensor in SENSORS:
            for seed in range(scenes):
                s = make_sensed_scene(seed, SensedSceneParams(parts=(part,), sensor=sensor))
                model = s.models[0]
                v = float(np.linalg.norm(model.max(0) - model.min(0))) / 40
                yield f"{part} / {sensor}", {"model": model, "scan": s.scan,
                                             "owner": s.scan_ids, "poses": s.poses,
                                             "visible": list(s.copies_of(0, 0.3)), "voxel": v,
                                             "eye": np.zeros(3)}  # fmt: skip


def _row(name: str, rows: list[dict[str, Any]]) -> str:
    f = np.array([c for r in rows for c in r["fpfh"]])
    g = np.array([c for r in rows for c in r["learned"]])
    true_f = f.sum() / max(sum(r["fpfh_matches"] for r in rows), 1)
    true_g = g.sum() / max(sum(r["learned_matches"] for r in rows), 1)
    ratio = np.median([r["t_learned"] / r["t_fpfh"] for r in rows])
    share_f, share_g = np.mean(f >= 3) if len(f) else np.nan, np.mean(g >= 3) if len(g) else np.nan
    return (
        f"| {name} | {len(f)} | {share_f:.2f} | {share_g:.2f} | {share_g / share_f:.2f} | "
        f"{np.median(f):.0f} / {np.median(g):.0f} | {100 * true_f:.1f} / {100 * true_g:.1f} | "
        f"{np.median([r['t_fpfh'] for r in rows]):.3f} / "
        f"{np.median([r['t_learned'] for r in rows]):.3f} ({ratio:.1f}x) |"
    )


def report(results: dict[str, dict[str, list[dict[str, Any]]]], argv: list[str] | None) -> str:
    lines = [
        "## Learned descriptor against FPFH (held-out models)",
        "",
        f"- Date: {utc_now()}. Command: `{command('benchmarks.clouds.learned_descriptor', argv)}`.",
        f"- Hardware: {hardware()}.",
    ]
    for family, per_model in results.items():
        lines += [
            "",
            f"### {family}",
            "",
            "| model | copies | >= 3 true, FPFH | >= 3 true, learned | ratio | median true "
            "(FPFH / learned) | true share % | describe s (FPFH / learned) |",
            "|---|---|---|---|---|---|---|---|",
        ]
        lines += [_row(m, rows) for m, rows in per_model.items()]
        lines.append(_row("**pooled**", [r for rows in per_model.values() for r in rows]))
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=int, default=3, help="scenes per model (and sensor)")
    ap.add_argument("--descriptor", default="learned", help="learned, or a descriptor file")
    ap.add_argument("--families", default="realistic,sensed")
    ap.add_argument("--out", default="out/learned_descriptor.md")
    args = ap.parse_args(argv)
    sources = {"realistic": realistic_cases, "sensed": sensed_cases}
    results: dict[str, dict[str, list[dict[str, Any]]]] = {}
    for family in [f.strip() for f in args.families.split(",") if f.strip()]:
        per_model: dict[str, list[dict[str, Any]]] = {}
        for name, case in sources[family](args.scenes):
            row = true_matches(case, args.descriptor)
            per_model.setdefault(name, []).append(row)
            print(name, {k: row[k] for k in ("fpfh", "learned", "t_fpfh", "t_learned")},
                  flush=True)  # fmt: skip
        results[family] = per_model
    write_report(args.out, report(results, argv))


if __name__ == "__main__":
    main()

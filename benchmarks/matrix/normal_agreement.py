"""The poses `register_point_clouds` returns on matrix cells, right and wrong, and how well each
one's surface is turned like the scan's (the `min_normal_agreement` rule's measure).

    python -m benchmarks.matrix.normal_agreement run --cells "base,sensor=tof" --out A.json
    python -m benchmarks.matrix.normal_agreement compare BEFORE.json AFTER.json

``run``: per cell, seed and product, `register_point_clouds` with defaults and (piles and
packed layouts) ``heap=True``, scan handed over as its (N, 3) returns without a viewpoint; each
returned pose right or wrong as the matrix scores it, and the exact poses of the copies at least
30 % visible; for each pose, the share of the model points within 1.5 voxels of a scan point
whose normals (fitted within 2 voxels, either sign) lie within 30 and 45 degrees of that scan
point's. ``compare``: right and wrong poses per cell and row between two runs (two builds on the
same cells and seeds), and the agreement of each kind of pose in the first.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from pathlib import Path

import numpy as np

from benchmarks.matrix.run import HEAPED, MAX_ROTATION_DEG, MAX_TRANSLATION_DIAGONALS, all_cells


def _agreement(src, ns, tree, tgt_normals, voxel: float, pose: np.ndarray) -> list[float]:  # type: ignore[no-untyped-def]
    """Shares of the explained model points agreeing within 30 and 45 degrees, and their count."""
    rot, t = pose[:3, :3], pose[:3, 3]
    dist, near = tree.query(src @ rot.T + t, distance_upper_bound=1.5 * voxel)
    hit = np.isfinite(dist)
    if not hit.any():
        return [0.0, 0.0, 0]
    cos = np.abs(np.sum((ns[hit] @ rot.T) * tgt_normals[near[hit]], axis=1))
    return [float((cos > np.cos(np.radians(a))).mean()) for a in (30, 45)] + [int(hit.sum())]


def run(cells: list[str], seeds: list[int]) -> list[dict]:
    import pointclm
    import pointclm.preprocessing as pp
    from pointclm.datasets.sensed import make_sensed_scene
    from pointclm.metrics import pose_match_matrix
    from scipy.spatial import cKDTree

    by_name = {c.name: c for c in all_cells()}
    out: list[dict] = []
    for name in cells:
        cell = by_name[name]
        params = cell.params()
        for seed in seeds:
            scene = make_sensed_scene(seed, params)
            for prod, model in enumerate(scene.models):
                mine = scene.product == prod
                truth, visible = scene.poses[mine], scene.visible_fraction[mine]
                tol = MAX_TRANSLATION_DIAGONALS * scene.diameters[prod]
                for row in ["default"] + (["heap"] if cell.layout in HEAPED else []):
                    t0 = time.perf_counter()
                    heap = True if row == "heap" else None
                    reg = pointclm.register_point_clouds(model, scene.scan, heap=heap)
                    v = reg.voxel_size
                    src = pp.voxel_downsample(model, v)
                    tgt = pp.voxel_downsample(scene.scan, v)
                    ns, nt = pp.estimate_normals(src, 2 * v), pp.estimate_normals(tgt, 2 * v)
                    tree = cKDTree(tgt)
                    poses = np.asarray(reg.transformations).reshape(-1, 4, 4)
                    right = pose_match_matrix(
                        poses, truth, MAX_ROTATION_DEG, tol, symmetries=scene.symmetries[prod]
                    ).any(axis=1)
                    for pose, ok in zip(poses, right, strict=True):
                        a = _agreement(src, ns, tree, nt, v, pose)
                        kind = "right" if ok else "wrong"
                        out.append({"cell": name, "seed": seed, "row": row, "kind": kind, "a": a})
                    if row == "default":
                        for k in np.flatnonzero(visible >= 0.3):
                            a = _agreement(src, ns, tree, nt, v, truth[k])
                            out.append(
                                {
                                    "cell": name,
                                    "seed": seed,
                                    "row": "exact",
                                    "kind": "exact",
                                    "a": a,
                                }
                            )
                    secs = time.perf_counter() - t0
                    print(f"{name} seed {seed} product {prod} {row}: {len(poses)} ({secs:.1f} s)")
    return out


def compare(before: list[dict], after: list[dict]) -> str:
    def counts(rows: list[dict]) -> Counter:
        return Counter((r["cell"], r["row"], r["kind"]) for r in rows if r["row"] != "exact")

    b, a = counts(before), counts(after)
    lines = [
        "| cell | row | right before -> after | wrong before -> after |",
        "|---|---|---|---|",
    ]
    total: Counter = Counter()
    for cell, row in sorted({(c, r) for c, r, _ in b | a}):
        rb, ra = b[(cell, row, "right")], a[(cell, row, "right")]
        wb, wa = b[(cell, row, "wrong")], a[(cell, row, "wrong")]
        total.update({(row, "rb"): rb, (row, "ra"): ra, (row, "wb"): wb, (row, "wa"): wa})
        lines.append(f"| {cell} | {row} | {rb} -> {ra} | {wb} -> {wa} |")
    for row in ("default", "heap"):
        lines.append(
            f"| **all** | {row} | {total[(row, 'rb')]} -> {total[(row, 'ra')]} | "
            f"{total[(row, 'wb')]} -> {total[(row, 'wa')]} |"
        )
    lines += [
        "",
        "Share of the explained model points agreeing within 30 degrees, in the first run:",
        "",
        "| kind | seed | poses | lowest | 10th percentile | median |",
        "|---|---|---|---|---|---|",
    ]
    for kind in ("exact", "right", "wrong"):
        for seed in sorted({r["seed"] for r in before}):
            v = np.sort([r["a"][0] for r in before if r["kind"] == kind and r["seed"] == seed])
            if len(v):
                lines.append(
                    f"| {kind} | {seed} | {len(v)} | {v[0]:.2f} | {v[len(v) // 10]:.2f} | "
                    f"{np.median(v):.2f} |"
                )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="what", required=True)
    r = sub.add_parser("run")
    r.add_argument("--cells", required=True, help="cell names, comma-separated")
    r.add_argument("--seeds", default="0,1")
    r.add_argument("--out", required=True)
    c = sub.add_parser("compare")
    c.add_argument("before")
    c.add_argument("after")
    args = ap.parse_args(argv)
    if args.what == "run":
        seeds = [int(s) for s in args.seeds.split(",")]
        rows = run([x.strip() for x in args.cells.split(",") if x.strip()], seeds)
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(rows))
    else:
        before = json.loads(Path(args.before).read_text())
        after = json.loads(Path(args.after).read_text())
        print(compare(before, after))


if __name__ == "__main__":
    main()

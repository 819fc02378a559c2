"""Time of `register_point_clouds` on whole depth frames: an RGB-D camera's 640 x 480 frame
(about 280k-300k points with the bin's walls and floor) and one model, on 2 threads.

    python -m benchmarks.clouds.frame_speed [--seeds 2] [--threads 2] [--out FILE]

Frames: ``pointclm.datasets.sensed`` scenes under the ``rgbd_0.6m`` camera with structured-light
noise: packed grids, rows and piles of touching boxes (``make_packed_boxes``, two products,
each product's model registered in turn) and a pile of bunnies (``make_sensed_scene``). Each
frame is registered with default arguments (no voxel, no viewpoint: the scan in the camera's
frame) and with ``heap=True``, after one warm-up call.

The reference, timed on the same frame in the same run: what any descriptor pipeline does
before matching, with Open3D (voxel downsampling at pointclm's voxel, normals, FPFH at
pointclm's radii), so the ratio stays meaningful on a loaded machine. Without Open3D the
reference column is left empty.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from benchmarks.common import report

LAYOUTS = ("grid", "row", "pile")


def frames(seeds: int) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, scan, model) for every frame and model timed."""
    from pointclm.datasets.sensed import SensedSceneParams, make_packed_boxes, make_sensed_scene

    out = []
    for seed in range(seeds):
        for layout in LAYOUTS:
            scene = make_packed_boxes(seed=seed, layout=layout)
            for part, model in zip(scene.params.parts, scene.models, strict=True):
                out.append((f"boxes {layout} / {part}", scene.scan, np.asarray(model)))
        scene = make_sensed_scene(seed, SensedSceneParams(parts=("bunny",), layout="pile"))
        out.append(("bunny pile", scene.scan, np.asarray(scene.models[0])))
    return out


def reference_seconds(scan: np.ndarray, voxel: float) -> float | None:
    """Open3D's downsampling, normals and FPFH of `scan` at `voxel` (pointclm's radii)."""
    try:
        import open3d as o3d
    except ImportError:
        return None
    t0 = time.perf_counter()
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scan))
    down = cloud.voxel_down_sample(voxel)
    down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    o3d.pipelines.registration.compute_fpfh_feature(
        down, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)
    )
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=2, help="scenes per layout")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default="out/frame_speed.md")
    ap.add_argument("--descriptor", default="auto", help="auto, fpfh, fpfh+learned, ...")
    args = ap.parse_args()

    import pointclm

    rows = []
    timed = frames(args.seeds)
    warm = timed[0]
    pointclm.register_point_clouds(warm[2], warm[1], num_threads=args.threads, seed=0)
    for name, scan, model in timed:
        row = {"frame": name, "points": len(scan)}
        for setting, heap in (("default", None), ("heap", True)):
            t0 = time.perf_counter()
            result = pointclm.register_point_clouds(
                model,
                scan,
                heap=heap,
                num_threads=args.threads,
                seed=0,
                descriptor=args.descriptor,
            )
            row[setting] = time.perf_counter() - t0
            row[f"{setting} copies"] = len(result.instances)
            row[f"{setting} peeling"] = result.timings.get("peeling", 0.0)
        row["reference"] = reference_seconds(scan, result.voxel_size)
        rows.append(row)
        print(name, {k: round(v, 3) if isinstance(v, float) else v for k, v in row.items()})
    write_report(rows, args)


def _s(v: float | None) -> str:
    return "" if v is None else f"{v:.2f}"


def write_report(rows: list[dict], args: argparse.Namespace) -> None:
    import pointclm

    lines = [
        "## Whole depth frames: time per frame",
        "",
        f"- Date: {report.utc_now()}. Command: `{report.command(__spec__.name)}`.",
        f"- Hardware: {report.hardware()}, {args.threads} threads on a shared machine; "
        f"pointclm {pointclm.__version__} (git {report.git_commit()}), "
        f"descriptor={args.descriptor!r}.",
        "",
        "| frame | points | default s | heap s | heap peeling s | copies default / heap "
        "| reference s | default / reference | heap / reference |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ref = r["reference"]
        ratios = [f"{r[k] / ref:.1f}" if ref else "" for k in ("default", "heap")]
        lines.append(
            f"| {r['frame']} | {r['points']} | {_s(r['default'])} | {_s(r['heap'])} | "
            f"{_s(r['heap peeling'])} | {r['default copies']} / {r['heap copies']} | "
            f"{_s(ref)} | {ratios[0]} | {ratios[1]} |"
        )
    for setting in ("default", "heap"):
        times = [r[setting] for r in rows]
        lines.append(
            f"\n{setting}: median {statistics.median(times):.2f} s, max {max(times):.2f} s "
            f"over {len(times)} frame-model pairs."
        )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    print(f"report written to {out}")


if __name__ == "__main__":
    main()

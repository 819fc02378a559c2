"""How far each scan's depth steps make flat terraces at the normals' radius
(`pointclm.preprocessing.terraced_share`, the measure by which pointclm fits a scan's normals
within 4 voxels instead of 2), on the validation matrix's cells and on the real scans of
``../shared/data``.

    python -m benchmarks.matrix.depth_steps [--cells NAME,...] [--seeds 0,2] [--out FILE]

Per matrix cell and seed: the share of the scan downsampled at the default voxel (the first
product's), seen from the sensor (the origin: the scan is in the camera's frame). Per real
scan: the share at the voxels of a part a tenth and a fortieth of the scan's extent, and at
the voxels pointclm picks for the bundled models (3-9 mm), seen from the origin (PCL's
Kinect frame is in its sensor's frame; the Stanford scans and 3DMatch fragments are not).
"""

from __future__ import annotations

import argparse
import datetime
import platform
import time
import warnings
from pathlib import Path

import numpy as np

from benchmarks.matrix.run import all_cells


def cell_rows(names: list[str] | None, seeds: list[int]) -> list[tuple[str, int, float, float]]:
    import pointclm.preprocessing as pp
    from pointclm.clouds.sensor import default_voxel_size
    from pointclm.datasets.sensed import make_sensed_scene

    rows = []
    for cell in all_cells():
        if cell.family != "clouds" or (names and cell.name not in names):
            continue
        for seed in seeds:
            scene = make_sensed_scene(seed, cell.params())
            voxel = default_voxel_size(scene.models[0], scene.scan)
            scan = pp.voxel_downsample(scene.scan, voxel)
            share = pp.terraced_share(scan, 2 * voxel)
            rows.append((cell.name, seed, voxel, share))
            print(f"{cell.name} seed {seed}: voxel {voxel * 1000:.1f} mm, share {share:.3f}")
    return rows


def real_rows(data: Path) -> list[tuple[str, float, float]]:
    import pointclm.preprocessing as pp
    from pointclm.io import load_points

    files = [data / "pcl" / "milk_cartoon_all_small_clorox.pcd"]
    files += sorted((data / "stanford" / "bunny" / "data").glob("bun*.ply"))
    files += sorted((data / "3dmatch" / "open3d_feature").glob("*.pcd"))
    rows = []
    for f in files:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pts = np.asarray(load_points(f), dtype=np.float64)
        extent = float(np.linalg.norm(pts.max(0) - pts.min(0)))
        for voxel in sorted({extent / 400, extent / 100, 0.003, 0.005, 0.009}):
            scan = pp.voxel_downsample(pts, voxel)
            if len(scan) < 100 or len(scan) > 400_000:
                continue
            share = pp.terraced_share(scan, 2 * voxel)
            rows.append((f.name, voxel, share))
            print(f"{f.name}: voxel {voxel * 1000:.1f} mm, share {share:.3f}")
    return rows


def main(argv: list[str] | None = None) -> None:
    import pointclm.preprocessing as pp

    from benchmarks.clouds.scenes import data_folder

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cells", default=None, help="cell names, comma-separated (default: all)")
    ap.add_argument("--seeds", default="0,2")
    ap.add_argument("--data-dir", default=None, help="default: $POINTCLM_DATA_DIR or ../shared")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    names = [c.strip() for c in args.cells.split(",")] if args.cells else None
    cells = cell_rows(names, [int(s) for s in args.seeds.split(",")])
    real = real_rows(Path(data_folder(args.data_dir)))
    limit = pp.MAX_TERRACED_SHARE
    lines = [
        "# Depth steps: the terraced share of each scan",
        "",
        f"- Date: {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC. Command: "
        f"`python -m benchmarks.matrix.depth_steps --seeds {args.seeds}`"
        + (f" `--cells {args.cells}`" if args.cells else "")
        + f"; {platform.machine()}; {time.perf_counter() - t0:.0f} s.",
        f"- Above {limit} the scan's normals are fitted within 4 voxels instead of 2.",
        "",
        "| matrix cell | seed | voxel (mm) | terraced share | normals over |",
        "|---|---|---|---|---|",
    ]
    for name, seed, voxel, share in cells:
        over = "4 voxels" if share > limit else "2 voxels"
        lines.append(f"| {name} | {seed} | {voxel * 1000:.1f} | {share:.3f} | {over} |")
    lines += ["", "| real scan | voxel (mm) | terraced share | normals over |", "|---|---|---|---|"]
    for name, voxel, share in real:
        over = "4 voxels" if share > limit else "2 voxels"
        lines.append(f"| {name} | {voxel * 1000:.1f} | {share:.3f} | {over} |")
    text = "\n".join(lines) + "\n"
    if args.out:
        Path(args.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()

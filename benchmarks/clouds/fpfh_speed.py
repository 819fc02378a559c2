"""FPFH + correspondence search: pointclm vs Open3D, same clouds, same threads, same run.

    pip install open3d-cpu   # only for this benchmark
    python -m benchmarks.clouds.fpfh_speed [--repeats 5] [--threads 2]

Clouds: a realistic scene (``pointclm.datasets.scenes``, the Stanford bunny among clutter)
cropped or subsampled to 20,000 scene points, and the bunny model sampled to 5,000 points; both
with normals estimated by pointclm (the same normals go to both libraries, so only FPFH and
matching are timed). Open3D: ``compute_fpfh_feature`` on both clouds then
``correspondences_from_features`` (nearest neighbour of each source descriptor, exact k-d tree).
pointclm: ``compute_fpfh`` on both then ``match_features`` (nearest source descriptor of each
target descriptor, exact, all kept). Same radius (5 voxels) and max_nn (100). Writes a
markdown table to stdout and, with --out, to a file.
"""

from __future__ import annotations

import argparse
import os
import time

from benchmarks.common import report


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out")
    args = ap.parse_args()
    os.environ["OMP_NUM_THREADS"] = str(args.threads)

    import numpy as np
    import open3d as o3d
    import pointclm
    import pointclm.preprocessing as pp
    from pointclm.datasets.scenes import (
        SceneParams,
        default_data_dir,
        dense_model,
        make_realistic_scene,
    )

    data = default_data_dir()
    rng = np.random.default_rng(0)
    params = SceneParams(instances=(8, 8), clutter=(3, 3), voxel_fraction=1 / 60)
    scene = make_realistic_scene(0, params)
    target = scene.target_points
    if len(target) >= 20_000:
        target = target[np.sort(rng.choice(len(target), 20_000, replace=False))]
    model, _ = dense_model("stanford/bunny", str(data) if data else None)
    source = model[np.sort(rng.choice(len(model), 5_000, replace=False))]
    voxel = scene.voxel_size
    rad, nn = 5 * voxel, 100
    s_n = pp.estimate_normals(source, 2 * voxel, 30, away_from=source.mean(0))
    t_n = pp.estimate_normals(target, 2 * voxel, 30, towards=target.mean(0) + [0, 0, 1.0])

    def o3d_cloud(p: np.ndarray, n: np.ndarray) -> o3d.geometry.PointCloud:
        c = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
        c.normals = o3d.utility.Vector3dVector(n)
        return c

    src_o3d, tgt_o3d = o3d_cloud(source, s_n), o3d_cloud(target, t_n)
    param = o3d.geometry.KDTreeSearchParamHybrid(radius=rad, max_nn=nn)
    reg = o3d.pipelines.registration

    def run_o3d() -> tuple[float, float, int]:
        t0 = time.perf_counter()
        fs = reg.compute_fpfh_feature(src_o3d, param)
        ft = reg.compute_fpfh_feature(tgt_o3d, param)
        t1 = time.perf_counter()
        corr = reg.correspondences_from_features(fs, ft, mutual_filter=False)
        t2 = time.perf_counter()
        return t1 - t0, t2 - t1, len(np.asarray(corr))

    def run_ours() -> tuple[float, float, int]:
        t0 = time.perf_counter()
        fs = pp.compute_fpfh(source, s_n, rad, nn, num_threads=args.threads)
        ft = pp.compute_fpfh(target, t_n, rad, nn, num_threads=args.threads)
        t1 = time.perf_counter()
        m = pp.match_features(fs, ft, top_k=10**9, n_samples=None, num_threads=args.threads)
        t2 = time.perf_counter()
        return t1 - t0, t2 - t1, len(m)

    # Same descriptors? (a parity check inside the timing run)
    fs_o3d = np.asarray(reg.compute_fpfh_feature(src_o3d, param).data).T
    fs_ours = pp.compute_fpfh(source, s_n, rad, nn)
    max_diff = float(np.abs(fs_o3d - fs_ours).max())

    rows: dict[str, list[tuple[float, float, int]]] = {"open3d": [], "pointclm": []}
    run_o3d(), run_ours()  # warm-up
    for _ in range(args.repeats):  # alternate, so both see the same machine load
        rows["open3d"].append(run_o3d())
        rows["pointclm"].append(run_ours())

    def med(name: str, k: int) -> float:
        return float(np.median([r[k] for r in rows[name]]))

    total = {n: med(n, 0) + med(n, 1) for n in rows}
    lines = [
        f"- Date: {report.utc_now()}. Command: `{report.command(__spec__.name)}`.",
        f"- Hardware: {report.hardware()}; "
        f"{args.threads} threads for both (OMP_NUM_THREADS for Open3D, a pool for pointclm).",
        f"- Versions: pointclm {pointclm.__version__} (git {report.git_commit()}), "
        f"open3d {o3d.__version__}.",
        f"- Clouds: scene {len(target)} points, model {len(source)} points; radius "
        f"{rad:.4g} (5 voxels), max_nn {nn}. Max |FPFH difference| on the model: {max_diff:.2e}.",
        "",
        "| | FPFH (both clouds) ms | matching ms | total ms | matches |",
        "|---|---|---|---|---|",
    ]
    for n in rows:
        lines.append(
            f"| {n} | {1e3 * med(n, 0):.1f} | {1e3 * med(n, 1):.1f} | {1e3 * total[n]:.1f} "
            f"| {rows[n][0][2]} |"
        )
    lines.append("")
    lines.append(
        f"- pointclm / Open3D speed (total, medians of {args.repeats}): "
        f"**{total['open3d'] / total['pointclm']:.2f}x**"
    )
    text = "\n".join(lines)
    print(text)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text + "\n")


if __name__ == "__main__":
    main()

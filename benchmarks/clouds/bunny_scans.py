"""`register_point_clouds` on the Stanford bunny's real range scans, each in its own scanner
frame, with default arguments (no voxel, no viewpoint), the model given as the fine
reconstruction (``res2``) or one of the two coarser meshes of the same shape (``res3``,
``res4``), matched by each descriptor.

The true pose of each scan comes from ``bun.conf`` (``p_model = R(q)^T p_scan + t``). A pose is
right within 15 degrees and 10 % of the model's diagonal; each scan holds one copy, so the
first pose returned is scored, and every pose returned that is not right is wrong.

    python -m benchmarks.clouds.bunny_scans [--descriptors auto,fpfh,learned,fpfh+learned]
        [--data-dir ../shared/data] [--out FILE]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pointclm
from pointclm.datasets import bunny_scan_pose
from pointclm.io import read_point_cloud
from pointclm.metrics import score_scene

from benchmarks.clouds.scenes import data_folder
from benchmarks.common import report

SCANS = ("bun000.ply", "bun045.ply", "bun090.ply", "bun315.ply")
MODELS = ("res2", "res3", "res4")


def run(data: Path, descriptor: str, res: str) -> tuple[list[str], int, int, float]:
    """Per scan "right" / "wrong" / "none", the counts of right and wrong poses, and the
    median seconds a call, for one descriptor and one model file."""
    path = data / f"stanford/bunny/reconstruction/bun_zipper_{res}.ply"
    model = read_point_cloud(path).points
    diagonal = float(np.linalg.norm(model.max(0) - model.min(0)))
    folder = data / "stanford/bunny/data"
    verdicts, right, wrong, times = [], 0, 0, []
    for name in SCANS:
        t = time.perf_counter()
        r = pointclm.register_point_clouds(path, folder / name, descriptor=descriptor)
        times.append(time.perf_counter() - t)
        truth = bunny_scan_pose(folder, name)[None]
        hit = score_scene(r.transformations[:1], truth, 15.0, 0.1 * diagonal).n_matched
        right += hit
        wrong += len(r.instances) - hit
        verdicts.append("right" if hit else ("wrong" if len(r.instances) else "none"))
    return verdicts, right, wrong, float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--descriptors", default="auto,fpfh,learned,fpfh+learned")
    ap.add_argument("--data-dir", default=None, help="default: $POINTCLM_DATA_DIR or ../shared")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    data = Path(data_folder(args.data_dir))
    lines = [
        "# Stanford bunny range scans, default arguments",
        "",
        f"- Date: {report.utc_now()}. Command: `{report.command(__spec__.name)}`.",
        f"- Hardware: {report.hardware()}; pointclm {pointclm.__version__} "
        f"(git {report.git_commit()}).",
        "",
        "| descriptor | model | " + " | ".join(SCANS) + " | right | wrong | median s |",
        "|---|---|" + "---|" * (len(SCANS) + 3),
    ]
    totals = {}
    for descriptor in args.descriptors.split(","):
        for res in MODELS:
            verdicts, right, wrong, median = run(data, descriptor, res)
            total = totals.setdefault(descriptor, [0, 0])
            total[0], total[1] = total[0] + right, total[1] + wrong
            lines.append(
                f"| {descriptor} | {res} | " + " | ".join(verdicts)
                + f" | {right} / {len(SCANS)} | {wrong} | {median:.2f} |"
            )  # fmt: skip
            print(lines[-1], flush=True)
    lines += ["", "| descriptor | right of 12 | wrong |", "|---|---|---|"]
    lines += [f"| {d} | {r} | {w} |" for d, (r, w) in totals.items()]
    text = "\n".join(lines) + "\n"
    report.write_report(args.out, text)


if __name__ == "__main__":
    main()

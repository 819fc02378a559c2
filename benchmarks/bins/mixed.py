"""Mixed bins: two box products in one scan, each registered alone (one
`register_point_clouds` call per product) against both judged together
(`pointclm.register_models`), on the same scans in the same run.

    python -m benchmarks.bins.mixed [--seeds 4] [--layouts grid,row,pile] [--heap] [--out FILE]

Scenes: ``pointclm.datasets.sensed.make_packed_boxes`` (two products, 5-10 copies each, an
RGB-D camera 0.6 m above, structured-light noise, the bin's walls and floor in the scan), as
the validation matrix's ``boxes2`` cells build them; the scan is handed over as its (N, 3)
returns without a viewpoint; ``--heap`` passes ``heap=True`` to every call.

Scoring as the matrix scores (``benchmarks.matrix.run.score_poses``): right within 15
degrees and 10 % of the product's diagonal, symmetry-aware, one prediction per copy; recall
over the copies at least 30 % visible, precision over every copy returned. A copy returned
for the wrong product counts against that product's precision; "on the other product" counts
the returned poses near no copy of their product whose centre lies inside a box of the other
product (its model's bounding box at that copy's true pose).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks.common.report import command, hardware, utc_now, write_report
from benchmarks.matrix.run import (
    MAX_ROTATION_DEG,
    MAX_TRANSLATION_DIAGONALS,
    Tally,
    score_poses,
)


def on_other_product(poses: np.ndarray, scene, prod: int) -> int:  # type: ignore[no-untyped-def]
    """How many of `poses` (returned for product `prod`) are near no copy of `prod` and have
    their centre inside a box of another product."""
    from pointclm.metrics import pose_match_matrix

    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    mine = scene.product == prod
    near_own = pose_match_matrix(
        poses,
        scene.poses[mine],
        MAX_ROTATION_DEG,
        MAX_TRANSLATION_DIAGONALS * scene.diameters[prod],
        symmetries=scene.symmetries[prod],
    ).any(axis=1)
    centre = scene.models[prod].mean(axis=0)
    count = 0
    for pose in poses[~near_own]:
        c = pose[:3, :3] @ centre + pose[:3, 3]
        for other in np.flatnonzero(~mine):
            model, truth = scene.models[scene.product[other]], scene.poses[other]
            local = truth[:3, :3].T @ (c - truth[:3, 3])
            if np.all(local >= model.min(axis=0)) and np.all(local <= model.max(axis=0)):
                count += 1
                break
    return count


def run(seeds: int, layouts: list[str], heap: bool = False) -> dict[str, dict[str, Tally]]:
    """Per layout, per method ("alone", "together"): the pooled tallies and seconds."""
    import pointclm
    from pointclm.datasets.sensed import make_packed_boxes

    out: dict[str, dict[str, Tally]] = {}
    for layout in layouts:
        tallies = {"alone": Tally(), "together": Tally()}
        for seed in range(seeds):
            scene = make_packed_boxes(seed=seed, layout=layout)
            t0 = time.perf_counter()
            opts = {"heap": True} if heap else {}
            alone = [pointclm.register_point_clouds(m, scene.scan, **opts) for m in scene.models]
            t_alone = time.perf_counter() - t0
            t0 = time.perf_counter()
            together = pointclm.register_models(list(scene.models), scene.scan, **opts)
            t_together = time.perf_counter() - t0
            for name, results, seconds in (
                ("alone", alone, t_alone),
                ("together", together, t_together),
            ):
                for prod, res in enumerate(results):
                    mine = scene.product == prod
                    tally = score_poses(
                        res.transformations,
                        scene.poses[mine],
                        scene.visible_fraction[mine],
                        scene.diameters[prod],
                        scene.symmetries[prod],
                    )
                    tally.extra["on other product"] += on_other_product(
                        res.transformations, scene, prod
                    )
                    tallies[name].add(tally)
                    tallies.setdefault(f"{name}: {scene.parts[prod]}", Tally()).add(tally)
                tallies[name].seconds += seconds
                tallies[name].calls += 1
            print(f"{layout} seed {seed}: alone {t_alone:.1f} s, together {t_together:.1f} s")
        out[layout] = tallies
    return out


def report(results: dict[str, dict[str, Tally]], argv: list[str] | None) -> str:
    lines = [
        "## Mixed bins: each product alone against both together",
        "",
        f"- Date: {utc_now()}. Command: `{command('benchmarks.bins.mixed', argv)}`.",
        f"- Hardware: {hardware()}.",
        "",
        "| layout | method | R>=30 % | precision | F1 | copies returned | on the other product "
        "| s a scan |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for layout, tallies in results.items():
        for name, tally in tallies.items():
            s = tally.summary()
            secs = f"{tally.seconds / tally.calls:.1f}" if tally.calls else "-"
            lines.append(
                f"| {layout} | {name} | {s['recall30']:.2f} | {s['precision']:.2f} | "
                f"{s['f1']:.2f} | {s['predictions']} | {tally.extra['on other product']} | "
                f"{secs} |"
            )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=4, help="scenes per layout")
    ap.add_argument("--layouts", default="grid,row,pile")
    ap.add_argument("--heap", action="store_true", help="heap=True in every call")
    ap.add_argument("--out", default="out/bins_mixed.md")
    args = ap.parse_args(argv)
    layouts = [x.strip() for x in args.layouts.split(",") if x.strip()]
    results = run(args.seeds, layouts, args.heap)
    write_report(args.out, report(results, argv))


if __name__ == "__main__":
    main()

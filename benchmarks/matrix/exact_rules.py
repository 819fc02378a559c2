"""What each acceptance rule of `refine_poses` measures on the exact poses of the validation
matrix's copies: the evidence behind (or against) each threshold, per cell.

    python -m benchmarks.matrix.exact_rules [--cells NAME,...] [--seeds 0,1,2,3] [--out FILE]

Per cloud cell, seed and product, the copies at least 30 % visible, verified as the matrix's
exact-pose test verifies them (``RefinementContext`` on the scan downsampled at the default
voxel, the sensor at the origin, ICP first): each rule's value read with that rule alone on,
at a threshold every pose fails (so ``RefinementContext.rejections`` reports the value), the
others off. Per cell: the worst value over its exact poses and how many the default threshold
rejects. A rule rejecting exact poses rejects the truth; how far its worst exact value lies
from the threshold is the margin the threshold leaves on that cell.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from benchmarks.common import report
from benchmarks.matrix.run import MIN_VISIBLE, all_cells, exact_context

#: Each rule, the threshold that makes every pose report its value, and whether its default
#: is a floor (the value must reach it) or a ceiling.
RULES: dict[str, tuple[float, bool]] = {
    "min_seen": (1.0, True),
    "min_visible_fitness": (1.0, True),
    "max_contradiction": (0.0, False),
    "min_normal_agreement": (1.0, True),
    "max_slid_fitness": (0.0, False),
}

#: Every rule switched off, as ``RefinementContext`` takes them.
OFF = {
    "min_seen": 0.0,
    "min_visible_fitness": 0.0,
    "max_contradiction": 1.0,
    "min_normal_agreement": 0.0,
    "max_slid_fitness": 1.0,
    "max_shared": 1.0,
}


def measure(cells: list[str] | None, seeds: list[int]) -> dict[str, dict[str, list[float]]]:
    """Per cell and rule, the value each exact pose shows (a pose a rule does not name passes
    its extreme threshold: 1 for a floor, 0 for a ceiling)."""
    from pointclm.datasets.sensed import make_sensed_scene

    out: dict[str, dict[str, list[float]]] = {}
    for cell in all_cells():
        if cell.family != "clouds" or (cells and cell.name not in cells):
            continue
        values = out.setdefault(cell.name, {rule: [] for rule in RULES})
        t = time.perf_counter()
        for seed in seeds:
            scene = make_sensed_scene(seed, cell.params())
            for product in range(len(scene.models)):
                if len(scene.copies_of(product, MIN_VISIBLE)) == 0:
                    continue
                idx, ctx = exact_context(scene, product)
                for rule, (extreme, floor) in RULES.items():
                    got = np.full(len(idx), 1.0 if floor else 0.0)
                    for r in ctx.rejections(scene.poses[idx], **{**OFF, rule: extreme}):
                        if r.rule == rule:
                            got[r.origin] = r.value
                    values[rule].extend(got.tolist())
        secs = time.perf_counter() - t
        print(f"{cell.name}: {len(values['min_seen'])} exact poses ({secs:.0f} s)")
    return out


def table(values: dict[str, dict[str, list[float]]]) -> str:
    """Per cell and rule: the worst exact value and how many the default rejects."""
    import pointclm.refinement as rf

    defaults = {rule: getattr(rf, rule.upper()) for rule in RULES}
    head = " | ".join(f"{r} ({defaults[r]:g})" for r in RULES)
    lines = [
        f"| cell | exact poses | {head} |",
        "|---|---|" + "---|" * len(RULES),
    ]
    pooled: dict[str, list[float]] = {rule: [] for rule in RULES}
    for name, per in [*values.items(), ("**all cells**", pooled)]:
        cols = []
        for rule, (_, floor) in RULES.items():
            v = np.asarray(per[rule])
            if per is not pooled:
                pooled[rule].extend(per[rule])
            limit = defaults[rule]
            worst = v.min() if floor else v.max()
            lost = int(np.sum(v < limit if floor else v > limit))
            cols.append(f"{worst:.3f}, {lost} rejected" if lost else f"{worst:.3f}")
        lines.append(f"| {name} | {len(per['min_seen'])} | " + " | ".join(cols) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cells", default=None, help="cell names, comma-separated (default: all)")
    ap.add_argument("--seeds", default="0,1,2,3")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    names = [c.strip() for c in args.cells.split(",")] if args.cells else None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        values = measure(names, [int(s) for s in args.seeds.split(",")])
    text = "\n".join(
        [
            "# The acceptance rules on the exact poses of the validation matrix",
            "",
            f"- Date: {report.utc_now()}. Command: `{report.command(__spec__.name)}`.",
            f"- Hardware: {report.hardware()}; git {report.git_commit()}; "
            f"{time.perf_counter() - t0:.0f} s.",
            "- Each column: the worst value over the cell's exact poses (after ICP), and how "
            "many the default threshold (in the header) rejects. A sliding pose is returned "
            "apart, not lost (`max_slid_fitness`).",
            "",
            table(values),
        ]
    )
    report.write_report(args.out, text)


if __name__ == "__main__":
    main()

"""The validation matrix: registration and exact-pose verification on sensed scenes varying
camera, sensor, layout, part and model form.

    python -m benchmarks.matrix.run [--quick] [--cells SUBSTR,...] [--scenes 4] [--out FILE]
                                    [--scene RULE=VALUE ...] [--descriptor D] [--table FILE]

Every axis takes at least three values (``pointclm.datasets.cameras.CAMERAS``,
``sensor_effects.SENSORS``, ``layouts.LAYOUTS``, ``parts.PARTS``, ``parts.MODEL_FORMS``). The
full cross product is far too large, so the cells are: a base cell (a pile of bunnies in a
bin, an RGB-D camera 0.6 m above, structured light, the fine mesh as the model), each axis
varied alone from it, a seeded random sample of combinations, mixed bins of two or three
box products (rows, grids, piles of touching boxes), and a family where correspondences alone
(FPFH matches of the scan against the model, 2-6 partial copies among clutter) go to
``pointclm.register``.

Each cell holds ``--scenes`` scenes; the first half of the seeds is the validation half (rules
may be chosen on it), the second the test half (reported, never chosen on). Per scene and
product:

- ``register_point_clouds(model, scan)`` with default arguments (no voxel, no viewpoint: the
  scan is in the camera's frame, as a sensor delivers it), and for piles and packed bins a
  second row with ``heap=True``. A prediction is right when it is within 15 degrees and 10 %
  of the part's diagonal of a copy of its product, symmetry-aware (a box's half turns are the
  same pose), one prediction per copy. Recall counts the copies at least 30 % (and 50 %)
  visible; precision counts every prediction (a right pose of a barely visible copy is right).
- The exact-pose test: ``RefinementContext.refine`` (what ``refine_poses`` runs) started
  from the true poses of the copies at least 30 % visible, the sensor (the origin) as
  viewpoint, at the default voxel; the share kept within the same tolerance of their truth,
  and the rule that rejected each one lost.

Results go to ``--out`` (JSON, per cell and pooled, validation and test halves apart);
``--table`` writes the markdown table. ``--scene RULE=VALUE`` changes one of
:class:`pointclm.SceneRules` for every call: runs with several values of a rule are compared
cell by cell by ``python -m benchmarks.matrix.choose``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

BASE = {
    "camera": "rgbd_0.6m",
    "sensor": "structured_light",
    "layout": "pile",
    "part": "bunny",
    "form": "fine_mesh",
}
AXES = {
    "camera": ("rgbd_0.6m", "wide_0.35m", "narrow_far", "offcentre_1m", "far_2m"),
    "sensor": ("structured_light", "gauss_0.5mm", "tof", "quantised_1mm", "flying_unorganised"),
    "layout": ("pile", "room", "grid", "row", "lean"),
    "part": (
        "bunny",
        "dragon",
        "fandisk",
        "rocker_arm",
        "box_95x36x68",
        "box_120x52x50",
        "bracket",
    ),
    "form": ("fine_mesh", "coarse_mesh", "points", "scan"),
}
#: Layouts where copies touch in heaps or packs: a second row with ``heap=True``.
HEAPED = ("pile", "grid", "row")
MIN_VISIBLE, HALF_VISIBLE = 0.3, 0.5
#: Options every ``register_point_clouds`` call of the run adds (``--descriptor``).
REGISTER_OPTIONS: dict[str, object] = {}
MAX_ROTATION_DEG, MAX_TRANSLATION_DIAGONALS = 15.0, 0.1


@dataclass(frozen=True)
class Cell:
    name: str
    parts: tuple[str, ...]
    layout: str
    camera: str
    sensor: str
    form: str
    family: str = "clouds"  # or "correspondences"
    copies: tuple[int, int] = (5, 10)

    def params(self, data_dir: str | None = None):  # type: ignore[no-untyped-def]
        """The sensed-scene parameters of this cell's scenes."""
        from pointclm.datasets.sensed import SensedSceneParams

        return SensedSceneParams(
            parts=self.parts,
            layout=self.layout,
            copies=self.copies,
            camera=self.camera,
            sensor=self.sensor,
            form=self.form,
            data_dir=data_dir,
        )

    def axes(self) -> dict[str, str]:
        return {
            "camera": self.camera,
            "sensor": self.sensor,
            "layout": self.layout,
            "part": "+".join(self.parts),
            "form": self.form,
        }


def _cell(name: str, axes: dict[str, str], **kw: object) -> Cell:
    parts = tuple(axes["part"].split("+"))
    copies = (2, 6) if axes["layout"] == "room" else (5, 10)
    return Cell(
        name,
        parts,
        axes["layout"],
        axes["camera"],
        axes["sensor"],
        axes["form"],
        copies=copies,
        **kw,  # type: ignore[arg-type]
    )


def all_cells(n_random: int = 8) -> list[Cell]:
    """The base cell, each axis varied alone, `n_random` seeded combinations, the mixed box
    bins and the correspondence family."""
    cells = [_cell("base", BASE)]
    for axis, values in AXES.items():
        for v in values[1:]:
            cells.append(_cell(f"{axis}={v}", {**BASE, axis: v}))
    rng = np.random.default_rng(20261128)
    seen = {tuple(sorted(c.axes().items())) for c in cells}
    while len(cells) < 1 + sum(len(v) - 1 for v in AXES.values()) + n_random:
        axes = {a: str(rng.choice(v)) for a, v in AXES.items()}
        key = tuple(sorted(axes.items()))
        if key not in seen:
            seen.add(key)
            k = len(cells) - sum(len(v) - 1 for v in AXES.values())
            cells.append(_cell(f"combo{k}", axes))
    two = "box_95x36x68+box_232x44x52"
    three = two + "+box_120x52x50"
    for layout in ("grid", "row", "pile"):
        cells.append(_cell(f"boxes2 {layout}", {**BASE, "part": two, "layout": layout}))
    cells.append(
        _cell("boxes3 grid tof", {**BASE, "part": three, "layout": "grid", "sensor": "tof"})
    )
    cells.append(
        _cell(
            "boxes2 row narrow_far", {**BASE, "part": two, "layout": "row", "camera": "narrow_far"}
        )
    )
    for part, sensor in (
        ("bunny", "structured_light"),
        ("fandisk", "gauss_0.5mm"),
        ("dragon", "tof"),
    ):
        axes = {**BASE, "part": part, "layout": "room", "sensor": sensor}
        cells.append(_cell(f"corr {part} {sensor}", axes, family="correspondences"))
    # The families the open questions are about first, so that a run stopped early has them.
    first = [c for c in cells if c.name == "base" or " " in c.name]
    return first + [c for c in cells if c not in first]


QUICK = ("base", "layout=grid", "part=box_95x36x68", "boxes2 grid", "corr bunny structured_light")


# --- scoring --------------------------------------------------------------------------------


@dataclass
class Tally:
    """Counts over scenes: copies at least 30 % / 50 % visible and how many were found,
    predictions and how many were right, seconds."""

    n30: int = 0
    found30: int = 0
    n50: int = 0
    found50: int = 0
    n_pred: int = 0
    right: int = 0
    seconds: float = 0.0
    calls: int = 0
    extra: Counter = field(default_factory=Counter)

    def add(self, other: Tally) -> None:
        for k in ("n30", "found30", "n50", "found50", "n_pred", "right", "seconds", "calls"):
            setattr(self, k, getattr(self, k) + getattr(other, k))
        self.extra.update(other.extra)

    def summary(self) -> dict[str, float | int | dict[str, int]]:
        r30 = self.found30 / self.n30 if self.n30 else float("nan")
        r50 = self.found50 / self.n50 if self.n50 else float("nan")
        nan = float("nan")
        # No prediction: precision 0 where there was something to find, undefined otherwise.
        p = self.right / self.n_pred if self.n_pred else (nan if self.n30 == 0 else 0.0)
        f1 = nan if not self.n30 else (2 * p * r30 / (p + r30) if p + r30 > 0 else 0.0)
        return {
            "recall30": r30,
            "recall50": r50,
            "precision": p,
            "f1": f1,
            "copies30": self.n30,
            "copies50": self.n50,
            "predictions": self.n_pred,
            "predictions_per_copy": self.n_pred / self.n30 if self.n30 else nan,
            "right": self.right,
            "seconds_per_call": self.seconds / max(self.calls, 1),
            **({"counts": dict(self.extra)} if self.extra else {}),
        }


def score_poses(
    pred: np.ndarray,
    truth: np.ndarray,
    visible: np.ndarray,
    diameter: float,
    symmetries: np.ndarray | None,
) -> Tally:
    """One product of one scene: each copy claimed by at most one prediction (maximum
    matching), symmetry-aware errors under 15 degrees and 10 % of the diagonal."""
    from pointclm.metrics import max_bipartite_matching, pose_match_matrix

    pred = np.asarray(pred, dtype=np.float64).reshape(-1, 4, 4)
    ok = pose_match_matrix(
        pred,
        truth,
        MAX_ROTATION_DEG,
        MAX_TRANSLATION_DIAGONALS * diameter,
        symmetries=symmetries,
    )
    match = max_bipartite_matching(ok) if len(pred) and len(truth) else np.full(len(pred), -1)
    claimed = np.zeros(len(truth), dtype=bool)
    claimed[match[match >= 0]] = True
    v30, v50 = visible >= MIN_VISIBLE, visible >= HALF_VISIBLE
    return Tally(
        n30=int(v30.sum()),
        found30=int((claimed & v30).sum()),
        n50=int(v50.sum()),
        found50=int((claimed & v50).sum()),
        n_pred=len(pred),
        right=int((match >= 0).sum()),
    )


def exact_context(scene, product: int):  # type: ignore[no-untyped-def]
    """The copies of `product` at least `MIN_VISIBLE` visible (indices) and the refinement
    context the exact-pose test verifies them in: the model and scan downsampled at the
    default voxel, the sensor at the origin (the scan is in the camera's frame)."""
    import pointclm.preprocessing as pp
    from pointclm import RefinementContext
    from pointclm.clouds.sensor import default_voxel_size

    model = scene.models[product]
    voxel = default_voxel_size(model, scene.scan)
    src = pp.voxel_downsample(model, voxel)
    tgt = pp.voxel_downsample(scene.scan, voxel)
    ctx = RefinementContext(src, tgt, voxel, viewpoint=np.zeros(3))
    return scene.copies_of(product, MIN_VISIBLE), ctx


def exact_pose_test(scene, product: int) -> tuple[Tally, Tally]:  # type: ignore[no-untyped-def]
    """Verification started from the truth (module documentation): the copies kept, and
    those kept or returned apart as sliding along a face."""
    from pointclm.metrics import pose_match_matrix

    out, ambiguous = Tally(), Tally()
    if len(scene.copies_of(product, MIN_VISIBLE)) == 0:
        return out, ambiguous
    idx, ctx = exact_context(scene, product)
    truth = scene.poses[idx]
    t = time.perf_counter()
    kept = ctx.refine(truth)

    def within_tolerance(poses) -> int:  # type: ignore[no-untyped-def]
        """How many of `poses` lie within tolerance of the truth they started from."""
        ok = pose_match_matrix(
            poses.transformations,
            truth,
            MAX_ROTATION_DEG,
            MAX_TRANSLATION_DIAGONALS * scene.diameters[product],
            symmetries=scene.symmetries[product],
        )
        return int(sum(ok[i, o] for i, o in enumerate(poses.origin)))

    in_tol = within_tolerance(kept)
    out.n30, out.found30 = len(idx), in_tol
    out.seconds, out.calls = time.perf_counter() - t, 1
    out.extra.update(r.rule for r in ctx.rejections(truth))
    out.extra["drifted"] += len(kept.origin) - in_tol
    out.extra["judged_by_view"] += int(kept.by_visibility)
    # Returned apart as sliding along a face: not rejected, but not kept either.
    slid_in_tol = within_tolerance(kept.sliding)
    ambiguous.n30, ambiguous.found30 = len(idx), in_tol + slid_in_tol
    ambiguous.calls = 1
    return out, ambiguous


def _register_clouds(
    scene, product: int, heap: bool, organised: bool = False
) -> tuple[np.ndarray, np.ndarray, float, bool]:  # type: ignore[no-untyped-def]
    """The copies found, and those with the ambiguous (sliding) poses too. `organised`: the
    scan handed over as the organised frame where the sensor delivers one."""
    import pointclm
    from pointclm.datasets.sensor_effects import SENSORS

    sensor = scene.params.sensor
    delivers_frame = (SENSORS[sensor] if isinstance(sensor, str) else sensor).organised
    scan = scene.frame if organised and delivers_frame else scene.scan
    t = time.perf_counter()
    res = pointclm.register_point_clouds(
        scene.models[product], scan, heap=True if heap else None, **REGISTER_OPTIONS
    )
    seconds = time.perf_counter() - t
    both = [c.transformation for c in [*res.instances, *res.ambiguous]]
    every = np.stack(both) if both else np.zeros((0, 4, 4))
    return res.transformations, every, seconds, res.viewpoint is not None


def _register_correspondences(scene, product: int, seed: int) -> tuple[np.ndarray, float]:  # type: ignore[no-untyped-def]
    """FPFH matches of the scan against the model at 1/40 of its diagonal (mutual, top
    10,000, 1000 drawn), then the correspondence pipeline alone at that voxel."""
    import pointclm
    import pointclm.preprocessing as pp

    voxel = scene.diameters[product] / 40
    model = scene.models[product]
    src = pp.describe(model, voxel, away_from=model.mean(0))
    tgt = pp.describe(scene.scan, voxel, towards=np.zeros(3))
    matches = pp.match_features(
        src.descriptors, tgt.descriptors, top_k=10_000, mutual=True, n_samples=1000, seed=seed
    )
    corr = matches.correspondences(src.points, tgt.points)
    t = time.perf_counter()
    res = pointclm.register(corr, config=pointclm.Config.for_voxel(voxel), seed=seed)
    return np.asarray(res.transformations).reshape(-1, 4, 4), time.perf_counter() - t


def run_cell(
    cell: Cell, seeds: list[int], data_dir: str | None, organised: bool = False
) -> tuple[dict, dict]:
    """Every scene of `cell`: per row (default, heap) and the exact-pose test, per half;
    `organised`: organised frames handed over as such (:func:`_register_clouds`)."""
    from pointclm.datasets.sensed import make_sensed_scene

    params = cell.params(data_dir)
    half = len(seeds) // 2 or 1
    rows = ["correspondences"] if cell.family == "correspondences" else ["default"]
    if cell.family == "clouds" and cell.layout in HEAPED:
        rows.append("heap")
    if cell.family == "clouds":
        rows += [f"{r}+ambiguous" for r in rows]
    extra = ["exact", "exact+ambiguous"]
    tallies = {r: {"validation": Tally(), "test": Tally()} for r in [*rows, *extra]}
    per_product: dict[str, Tally] = {}
    t_scene = 0.0
    for i, seed in enumerate(seeds):
        split = "validation" if i < half else "test"
        t = time.perf_counter()
        scene = make_sensed_scene(seed, params)
        t_scene += time.perf_counter() - t
        for prod in range(len(cell.parts)):
            mine = scene.product == prod
            args = (scene.poses[mine], scene.visible_fraction[mine], scene.diameters[prod])
            for row in rows:
                if row.endswith("+ambiguous"):
                    continue
                both = np.zeros((0, 4, 4))
                if row == "correspondences":
                    poses, secs = _register_correspondences(scene, prod, seed)
                    used_view = False
                else:
                    poses, both, secs, used_view = _register_clouds(
                        scene, prod, row == "heap", organised
                    )
                for name, pred in ((row, poses), (f"{row}+ambiguous", both)):
                    if name not in tallies:
                        continue
                    tally = score_poses(pred, *args, scene.symmetries[prod])
                    tally.seconds, tally.calls = secs, 1
                    tally.extra["viewpoint_used"] += int(used_view)
                    tallies[name][split].add(tally)
                    per_product.setdefault(f"{name} {cell.parts[prod]}", Tally()).add(tally)
            if cell.family == "clouds":
                kept, ambiguous = exact_pose_test(scene, prod)
                tallies["exact"][split].add(kept)
                tallies["exact+ambiguous"][split].add(ambiguous)
    out: dict = {"axes": cell.axes(), "family": cell.family, "seeds": seeds, "rows": {}}
    for row, halves in tallies.items():
        if row.startswith("exact") and cell.family != "clouds":
            continue
        both = Tally()
        for h in halves.values():
            both.add(h)
        out["rows"][row] = {k: v.summary() for k, v in {**halves, "all": both}.items()}
    if len(cell.parts) > 1:
        out["per_product"] = {k: v.summary() for k, v in per_product.items()}
    out["scene_seconds"] = t_scene / max(len(seeds), 1)
    return out, tallies


def _fmt(x: float | None) -> str:
    return "-" if x is None or x != x else f"{x:.2f}"


def _clean(x: object) -> object:
    """NaN (nothing to measure) as JSON null."""
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_clean(v) for v in x]
    if isinstance(x, float | np.floating):
        return None if x != x else float(x)
    if isinstance(x, np.integer):
        return int(x)
    return x


def _exact(rows: dict) -> str:
    """The exact-pose keep rate, validation / test, and with the ambiguous poses."""
    pair = [
        f"{_fmt(h['validation']['recall30'])} / {_fmt(h['test']['recall30'])}" if h else "-"
        for h in (rows.get("exact"), rows.get("exact+ambiguous"))
    ]
    return "-" if pair[0] == "-" else f"{pair[0]} ({pair[1]})"


def table(results: dict) -> str:
    lines = [
        "| cell | varies | row | R>=30% val / test | R>=50% | P val / test | F1 val / test "
        "| exact keep val / test (with ambiguous) | s/call |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, cell in results["cells"].items():
        varies = ", ".join(f"{k}={v}" for k, v in cell["axes"].items() if BASE.get(k) != v) or "-"
        ex = _exact(cell["rows"])
        for row, s in cell["rows"].items():
            if row.startswith("exact"):
                continue
            v, t, a = s["validation"], s["test"], s["all"]
            lines.append(
                f"| {name} | {varies} | {row} | {_fmt(v['recall30'])} / {_fmt(t['recall30'])} | "
                f"{_fmt(a['recall50'])} | {_fmt(v['precision'])} / {_fmt(t['precision'])} | "
                f"{_fmt(v['f1'])} / {_fmt(t['f1'])} | {ex} | {a['seconds_per_call']:.1f} |"
            )
    for row, s in results["pooled"].items():
        v, t, a = s["validation"], s["test"], s["all"]
        if row == "exact":
            keep = _exact(results["pooled"])
            lines.append(f"| **pooled** | | exact poses | - | - | - | - | {keep} | - |")
            continue
        if row.startswith("exact"):
            continue
        lines.append(
            f"| **pooled** | | {row} | {_fmt(v['recall30'])} / {_fmt(t['recall30'])} | "
            f"{_fmt(a['recall50'])} | {_fmt(v['precision'])} / {_fmt(t['precision'])} | "
            f"{_fmt(v['f1'])} / {_fmt(t['f1'])} | - | {a['seconds_per_call']:.1f} |"
        )
    return "\n".join(lines) + "\n"


def _write(results: dict, pooled: dict, args, argv, seeds: list[int], t0: float) -> None:  # type: ignore[no-untyped-def]
    """Pool the cells run so far and write the JSON (after every cell: a long run that is
    stopped keeps what it measured)."""
    for row, halves in pooled.items():
        both = Tally()
        for tally in halves.values():
            both.add(tally)
        results["pooled"][row] = {k: v.summary() for k, v in {**halves, "all": both}.items()}
    cut = len(seeds) // 2 or 1
    results["meta"] = {
        "date": f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC",
        "command": "python -m benchmarks.matrix.run "
        + " ".join(argv if argv is not None else sys.argv[1:]),
        "hardware": f"{platform.machine()}, {os.cpu_count()} cores",
        "seconds": time.perf_counter() - t0,
        "seeds": {"validation": seeds[:cut], "test": seeds[cut:]},
    }
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(_clean(results), indent=1) + "\n")


def _scene_rules(pairs: list[str]) -> dict[str, object]:
    """``["heap_min_copies=3"]`` -> ``{"heap_min_copies": 3}`` (literals), checked by
    :class:`pointclm.SceneRules` before any scene is built."""
    import ast

    from pointclm import SceneRules

    rules: dict[str, object] = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        if not sep:
            raise SystemExit(f"--scene takes RULE=VALUE, got {pair!r}")
        rules[name.strip()] = ast.literal_eval(value.strip())
    SceneRules(**rules)  # type: ignore[arg-type]
    return rules


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="a few cells, one scene each (CI)")
    ap.add_argument("--cells", help="comma-separated substrings of the cell names to run")
    ap.add_argument("--scenes", type=int, default=4, help="scenes per cell (half validation)")
    ap.add_argument("--random", type=int, default=8, help="random combinations of the axes")
    ap.add_argument("--out", default="benchmarks/results/matrix/matrix.json")
    ap.add_argument("--table", help="also write the markdown table here")
    ap.add_argument("--data-dir", default=None)
    ap.add_argument(
        "--descriptor", default="auto", help="auto, fpfh, learned, fpfh+learned or a file"
    )
    ap.add_argument(
        "--scene",
        action="append",
        default=[],
        metavar="RULE=VALUE",
        help="a scene-wide rule changed for every call (pointclm.SceneRules), e.g. "
        "heap_min_copies=3; repeatable (benchmarks.matrix.choose compares such runs)",
    )
    ap.add_argument(
        "--organised",
        action="store_true",
        help="hand the scan over as the organised (H, W, 3) frame where the sensor gives one "
        "(judged from its sensor, the origin); default: the frame's returns as (N, 3)",
    )
    args = ap.parse_args(argv)
    REGISTER_OPTIONS["descriptor"] = args.descriptor
    if args.scene:
        REGISTER_OPTIONS["scene"] = _scene_rules(args.scene)
    cells = all_cells(args.random)
    if args.quick:
        cells = [c for c in cells if c.name in QUICK]
    if args.cells:
        keys = [k.strip() for k in args.cells.split(",") if k.strip()]
        cells = [c for c in cells if any(k in c.name for k in keys)]
    n = 1 if args.quick else args.scenes
    seeds = list(range(n))
    data_dir = args.data_dir or os.environ.get("POINTCLM_DATA_DIR")
    if data_dir is None:
        from pointclm.datasets.scenes import default_data_dir

        dd = default_data_dir()
        data_dir = str(dd) if dd else None
    t0 = time.perf_counter()
    results: dict = {"cells": {}, "pooled": {}}
    pooled: dict[str, dict[str, Tally]] = {}
    for cell in cells:
        t = time.perf_counter()
        try:
            res, tallies = run_cell(cell, seeds, data_dir, args.organised)
        except ValueError as err:  # a part that needs the data folder
            print(f"{cell.name}: skipped ({err})", flush=True)
            continue
        results["cells"][cell.name] = res
        for row, halves in tallies.items():
            for h, tally in halves.items():
                pooled.setdefault(row, {}).setdefault(h, Tally()).add(tally)
        brief = {
            r: round(s["all"]["f1"], 2) for r, s in res["rows"].items() if not r.startswith("exact")
        }
        ex = res["rows"].get("exact", {}).get("all", {}).get("recall30")
        print(f"{cell.name}: F1 {brief} exact {ex} ({time.perf_counter() - t:.0f} s)", flush=True)
        _write(results, pooled, args, argv, seeds, t0)
    _write(results, pooled, args, argv, seeds, t0)
    text = table(json.loads(json.dumps(_clean(results))))
    if args.table:
        Path(args.table).write_text(text)
    print(text)
    print(f"total {time.perf_counter() - t0:.0f} s")
    return results


if __name__ == "__main__":
    main()

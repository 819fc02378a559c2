"""The bin-picking benchmark: dozens of copies of one part per scan.

    pip install ".[bench]"      # the peers: KISS-Matcher and Open3D (benchmarks/common/peers.py)
    python -m benchmarks.bins.run [--scenes 2] [--validation-scenes 1] [--cache DIR]
                              [--models held-out|validation|all|m1,m2] [--out FILE]
                              [--skip-missing-peers]

The report goes to ``out/bins.md`` (not committed); ``--out benchmarks/results/bins/bins.md``
replaces the committed one. A peer that is not installed stops the run before any scene is
built, naming the package; ``--skip-missing-peers`` runs the other methods instead.

The default (the 7 held-out models, 2 scenes each, all three methods) took 16 minutes on 2
shared cores; ``--models validation`` reports the validation models (1 scene each by default).

Scenes: :func:`pointclm.datasets.bins.make_bin_scene` (20-80 copies of one part heaped in a
0.4 x 0.3 m bin, part diagonal 0.1 m, one structured-light depth sensor 0.8 m above; scan
cropped to the bin's interior, about 200k raw points, about 33k after downsampling at
pointclm's default voxel, 1/40 of the part's diagonal). Seeds 0..n-1 per model (each model
has its own random stream, so the scenes are fixed per model). ``--cache DIR`` keeps the
built scenes as .npz files and reads them back on the next run.

Methods, all given the same model points (dense samples of the scaled part), the same raw scan,
the same voxel and the sensor position, in the same run:

- **pointclm**: ``register_point_clouds(model, scan, voxel_size, viewpoint=sensor)`` with its
  defaults (training-free thresholds for refined poses, ICP refinement and verification,
  peeling rounds over the scan points no accepted copy explains, the scene-wide mutual check,
  relaxed by rank once ``HEAP_MIN_COPIES`` copies are accepted: ``heap_rank``).
- **pointclm (scene-wide mutual)**: the same with ``heap_rank=None``: the mutual nearest check
  in every round (the default before the ranked check).
- **pointclm (heap)**: the same with ``heap=True`` (what a picking cell knows of its scans): the
  ranked check from the round after the first accepted copy.
- **pointclm (heap switch)**: the same with ``mutual_window="auto"`` (:data:`HEAP_SWITCH`): the
  windowed mutual check in the rounds after ``HEAP_MIN_COPIES`` copies are accepted.
- **pointclm (FPFH)**, **pointclm (heap + FPFH)**: the defaults and ``heap=True`` matched by
  FPFH alone (``descriptor="fpfh"``; the default ``"auto"`` adds the learned descriptor for
  curved parts);
- **pointclm (learned descriptor)**, **pointclm (heap + learned descriptor)**: the defaults and
  ``heap=True`` with ``descriptor="learned"`` (matches by the shipped learned descriptor);
  **pointclm (FPFH and learned)**, **pointclm (heap + FPFH and learned)**: the same with
  ``descriptor="fpfh+learned"`` (both side by side).
- **pointclm (one pass)**: the same with ``peel=False`` (one correspondence stage, the paper's).
- **pointclm (all matches)**: the same with ``mutual=False, n_samples=None`` (:data:`ALL_MATCHES`):
  every scan point's best model match among the top 10,000, the setting for heaps.
- **pointclm (windowed mutual)**: the same with ``mutual_window=2, n_samples=None``
  (:data:`WINDOWED_MATCHES`): the mutual check within overlapping cubes two part diagonals
  wide, so each copy keeps its own mutual matches, all of them kept.
- **pointclm (no viewpoint)**: the scan where the scene puts it and no viewpoint given, as a
  scan exported to a world frame comes: the sensor's position is estimated from the scan
  (``pointclm._core.estimate_sensor``) and used once pass 0 confirms it.
- **pointclm (no flips)**: the same with ``flips=False``: the accepted poses are not compared
  with their half-turned alternatives.
- **sequential KISS-Matcher** (``benchmarks/common/peers.py``) on the correspondences of pointclm's
  first pass (``PointCloudRegistration.correspondences``): noise bound 2 voxels, a pose kept
  while it explains at least 6 correspondences (twice the minimal sample), at most 80 poses;
  the correspondences are rescaled for it (:func:`kiss_in_its_units`). Its time is pointclm's
  correspondence building (downsampling, normals, FPFH, matching) plus the loop.
- **sequential RANSAC (Open3D)**, the loop a user writes with Open3D alone: downsample both
  clouds at the voxel, normals (radius 2 voxels; the scan's towards the sensor, the model's
  away from its centroid), FPFH (radius 5 voxels, as pointclm), then repeat:
  ``registration_ransac_based_on_feature_matching`` (mutual filter, 1.5-voxel inlier
  distance, 3-point samples, edge-length 0.9 and distance checkers, 100,000 iterations,
  confidence 0.999) on the scan points left, point-to-point ICP (1.5 voxels) on them, stop
  when the pose explains less than 20 % of the model's points within 1.5 voxels (a copy at
  least half visible shows about half of its upper side: 20-25 % of the model) or after
  ``--ransac-max-fits`` poses (default 40); otherwise keep the pose and remove the scan points
  within 1.5 voxels of the posed model.

Scoring per scene: a prediction is correct when RE < 15 deg and TE < 10 % of the part's
diagonal to some copy (hidden copies included), with one prediction per copy at most: a
maximum matching of predictions to copies (the Hungarian method, scipy's
``linear_sum_assignment``, on the match matrix). Reported: recall of the copies at least half
visible (visible fraction >= 0.5, see the generator), recall of the k most visible copies
(k = 5, 10), precision (correct predictions / predictions), the share of scenes whose first five
returned poses are all correct (a scene with fewer than five poses fails), predictions per
scene, seconds per scene and the ratio to pointclm's time in the same run. Recalls and
precision are pooled over a model's scenes (sums of copies and predictions), then over the
models of a group.

The last two columns score symmetric parts fairly: a prediction also counts when its ADD-S to a
copy is under 10 % of the diagonal (:func:`symmetric_match`), whatever its RE.

Model split (project rule): figures are reported on the held-out models (stanford/bunny and
the six common3d meshes); the validation models (stanford dragon/happy/armadillo, modelnet
bathtub/bed, the procedural shapes) are reported separately. Symmetry: RE is measured against
the one true rotation; a part with a rotational symmetry (near-symmetric: fandisk, rocker-arm,
procedural box/cylinder) can be posed right and scored wrong.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks.common import report
from benchmarks.common.peers import (
    missing_peers,
    require_peers,
    sequential_kiss,
    sequential_ransac_fpfh,
)

#: The matching a user sets for a heap: every scan point's best model match among the top
#: 10,000, not only mutual ones (a model point has one true match per visible copy, and the
#: mutual filter keeps at most one of them), all of them, not a sample of 1000.
ALL_MATCHES = {"mutual": False, "n_samples": None}
#: The mutual check made within cubes of two part diagonals (a grid of stride one diagonal),
#: so that each copy keeps its own mutual matches, and all of them kept.
WINDOWED_MATCHES = {"mutual_window": 2.0, "n_samples": None}
#: The windowed check once peeling has accepted `HEAP_MIN_COPIES` copies (the scan is a heap).
HEAP_SWITCH = {"mutual_window": "auto"}
#: Matching arguments per method (the others: `register_point_clouds`' defaults).
MATCHING = {
    "pointclm (all matches)": ALL_MATCHES,
    "pointclm (windowed mutual)": WINDOWED_MATCHES,
    "pointclm (heap switch)": HEAP_SWITCH,
    "pointclm (no flips)": {"flips": False},
    "pointclm (scene-wide mutual)": {"heap_rank": None},
    "pointclm (heap)": {"heap": True},
    "pointclm (FPFH)": {"descriptor": "fpfh"},
    "pointclm (heap + FPFH)": {"heap": True, "descriptor": "fpfh"},
    "pointclm (learned descriptor)": {"descriptor": "learned"},
    "pointclm (heap + learned descriptor)": {"heap": True, "descriptor": "learned"},
    "pointclm (FPFH and learned)": {"descriptor": "fpfh+learned"},
    "pointclm (heap + FPFH and learned)": {"heap": True, "descriptor": "fpfh+learned"},
}
#: Sequential RANSAC stops at a pose explaining less of the model than this (see above).
RANSAC_MIN_FITNESS = 0.2
#: Sequential KISS-Matcher keeps a pose while it explains this many correspondences.
KISS_MIN_INLIERS = 6
METHODS = (
    "pointclm",
    "pointclm (scene-wide mutual)",
    "pointclm (heap)",
    "pointclm (FPFH)",
    "pointclm (heap + FPFH)",
    "pointclm (learned descriptor)",
    "pointclm (heap + learned descriptor)",
    "pointclm (FPFH and learned)",
    "pointclm (heap + FPFH and learned)",
    "pointclm (one pass)",
    "pointclm (all matches)",
    "pointclm (windowed mutual)",
    "pointclm (heap switch)",
    "pointclm (no flips)",
    "pointclm (scan in its sensor's frame)",
    "pointclm (no viewpoint)",
    "sequential KISS-Matcher",
    "sequential RANSAC (Open3D)",
)
#: The methods that need a peer, and the module each imports (`peers.PEER_PACKAGES`).
PEER_MODULES = {"sequential KISS-Matcher": "kiss_matcher", "sequential RANSAC (Open3D)": "open3d"}
#: Where the report goes unless --out says otherwise: beside the committed results, not over
#: them (out/ is not committed).
DEFAULT_OUT = "out/bins.md"


def choose_methods(requested: str, skip_missing_peers: bool) -> list[str]:
    """The methods of `requested` (comma-separated names) in `METHODS`' order. A method whose
    peer is not installed stops the run here, before any scene is built, unless
    `skip_missing_peers`: then it is left out, and said so."""

    names = [m for m in requested.split(",") if m]
    unknown = [m for m in names if m not in METHODS]
    if unknown:
        raise SystemExit(f"unknown method(s): {', '.join(unknown)}; known: {', '.join(METHODS)}")
    methods = [m for m in METHODS if m in names]
    peers = {m: PEER_MODULES[m] for m in methods if m in PEER_MODULES}
    if not skip_missing_peers:
        require_peers(peers, "--skip-missing-peers")
        return methods
    missing = missing_peers(peers)
    for method, module in missing.items():
        print(f"leaving out {method}: the module {module!r} is not installed", flush=True)
    return [m for m in methods if m not in missing]


@dataclass
class SceneResult:
    """One method on one scene."""

    n_pred: int
    n_correct: int
    half_found: int
    half_total: int
    top_found: dict[int, int]
    top_total: dict[int, int]
    first_five_ok: bool
    seconds: float
    sym_correct: int = 0
    sym_half_found: int = 0


def symmetric_match(pred: np.ndarray, scene) -> np.ndarray:
    """(P, G) bool: the posed model under a prediction lies on the posed copy, whatever the
    rotation: ADD-S (mean distance from each posed model point to the nearest point of the
    copy) under 10 % of the part's diagonal, the usual bound of the BOP / LineMOD scores. It
    forgives a symmetric part's equivalent poses, which RE / TE count as wrong."""
    from scipy.spatial import cKDTree

    pts = scene.model_points[np.random.default_rng(0).choice(len(scene.model_points), 500)]
    centre = scene.model_points.mean(0)
    pc = pred[:, :3, :3] @ centre + pred[:, :3, 3]
    gc = scene.poses[:, :3, :3] @ centre + scene.poses[:, :3, 3]
    out = np.zeros((len(pred), scene.n_copies), dtype=bool)
    for j in range(scene.n_copies):
        near = np.flatnonzero(np.linalg.norm(pc - gc[j], axis=1) < 0.2 * scene.diameter)
        if len(near) == 0:
            continue
        tree = cKDTree(pts @ scene.poses[j, :3, :3].T + scene.poses[j, :3, 3])
        for i in near:
            d, _ = tree.query(pts @ pred[i, :3, :3].T + pred[i, :3, 3])
            out[i, j] = d.mean() < 0.1 * scene.diameter
    return out


def score(pred: np.ndarray, scene, seconds: float) -> SceneResult:
    """Score predictions against every copy of a scene (module documentation)."""
    from pointclm.metrics import pose_match_matrix
    from scipy.optimize import linear_sum_assignment

    pred = np.asarray(pred, dtype=np.float64).reshape(-1, 4, 4)
    adj = pose_match_matrix(pred, scene.poses, 15.0, scene.max_translation)
    found = np.zeros(scene.n_copies, dtype=bool)
    n_correct = 0
    if len(pred):
        rows, cols = linear_sum_assignment(-adj.astype(np.float64))
        ok = adj[rows, cols]
        found[cols[ok]] = True
        n_correct = int(ok.sum())
    first = adj[:5]
    first_ok = len(pred) >= 5
    if first_ok:
        r, c = linear_sum_assignment(-first.astype(np.float64))
        first_ok = bool(first[r, c].all())
    half = scene.visible_fraction >= 0.5
    tops = {k: scene.least_hidden(k) for k in (5, 10)}
    sym_found = np.zeros(scene.n_copies, dtype=bool)
    if len(pred):
        sym = symmetric_match(pred, scene) | adj
        rows, cols = linear_sum_assignment(-sym.astype(np.float64))
        sym_found[cols[sym[rows, cols]]] = True
    return SceneResult(
        n_pred=len(pred),
        n_correct=n_correct,
        half_found=int(found[half].sum()),
        half_total=int(half.sum()),
        top_found={k: int(found[i].sum()) for k, i in tops.items()},
        top_total={k: len(i) for k, i in tops.items()},
        first_five_ok=first_ok,
        seconds=seconds,
        sym_correct=int(sym_found.sum()),
        sym_half_found=int(sym_found[half].sum()),
    )


def kiss_in_its_units(corr: np.ndarray, noise_bound: float) -> list[np.ndarray]:
    """Sequential KISS-Matcher with the correspondences rescaled so that the noise bound is
    0.1: its settings are meant for metre-scale LiDAR maps (it refuses a voxel under 0.01 and
    clamps noise bounds over 1), and a rigid fit does not care about units. The translations
    are scaled back."""

    scale = 0.1 / noise_bound
    poses = sequential_kiss(corr * scale, 0.1, KISS_MIN_INLIERS, 80)
    for pose in poses:
        pose[:3, 3] /= scale
    return poses


@dataclass
class Table:
    """Scene results per (model, method)."""

    rows: dict[tuple[str, str], list[SceneResult]] = field(default_factory=dict)
    copies: dict[str, list[int]] = field(default_factory=dict)

    def add(self, model: str, method: str, r: SceneResult) -> None:
        self.rows.setdefault((model, method), []).append(r)


def _summary(results: list[SceneResult]) -> dict[str, float]:
    def ratio(a: float, b: float) -> float:
        return a / b if b else float("nan")

    return {
        "scenes": len(results),
        "half": ratio(sum(r.half_found for r in results), sum(r.half_total for r in results)),
        "r5": ratio(sum(r.top_found[5] for r in results), sum(r.top_total[5] for r in results)),
        "r10": ratio(sum(r.top_found[10] for r in results), sum(r.top_total[10] for r in results)),
        "precision": ratio(sum(r.n_correct for r in results), sum(r.n_pred for r in results)),
        "first5": float(np.mean([r.first_five_ok for r in results])),
        "sym_half": ratio(
            sum(r.sym_half_found for r in results), sum(r.half_total for r in results)
        ),
        "sym_precision": ratio(sum(r.sym_correct for r in results), sum(r.n_pred for r in results)),
        "preds": float(np.mean([r.n_pred for r in results])),
        "seconds": float(np.median([r.seconds for r in results])),
        "total_seconds": float(np.sum([r.seconds for r in results])),
    }


def _markdown(title: str, models: list[str], table: Table, methods: list[str]) -> list[str]:
    lines = [
        f"### {title}",
        "",
        "| model | method | scenes | copies / scene | half-visible / scene | recall half-visible"
        " | recall 5 most visible | recall 10 most visible | precision | first 5 all correct |"
        " poses / scene | median s / scene | time / pointclm's | recall half-visible, ADD-S |"
        " precision, ADD-S |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    groups = [(m, [m]) for m in models] + [("**pooled**", models)]
    for name, group in groups:
        base = None
        for method in methods:
            res = [r for m in group for r in table.rows.get((m, method), [])]
            if not res:
                continue
            s = _summary(res)
            if base is None:
                base = s["total_seconds"]
            copies = [c for m in group for c in table.copies.get(m, [])]
            half = np.mean([r.half_total for r in res])
            lines.append(
                f"| {name} | {method} | {s['scenes']} | {np.mean(copies):.1f} | {half:.1f} | "
                f"{s['half']:.3f} | {s['r5']:.3f} | {s['r10']:.3f} | {s['precision']:.3f} | "
                f"{s['first5']:.2f} | {s['preds']:.1f} | {s['seconds']:.1f} | "
                f"{s['total_seconds'] / base:.2f} | {s['sym_half']:.3f} | "
                f"{s['sym_precision']:.3f} |"
            )
    return lines + [""]


def main() -> None:
    from pointclm.datasets.bins import (
        BIN_MODELS_HELD_OUT,
        BIN_MODELS_VALIDATION,
        BinParams,
        bin_scene_cached,
    )

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", type=int, default=2, help="scenes per held-out model")
    ap.add_argument("--validation-scenes", type=int, default=1, help="per validation model")
    ap.add_argument("--models", default="held-out", help="held-out, validation, all, or m1,m2,...")
    ap.add_argument("--cache", default=None, help="folder for the built scenes (.npz)")
    ap.add_argument("--methods", default=",".join(METHODS), help="comma-separated subset")
    ap.add_argument("--ransac-max-fits", type=int, default=40)
    ap.add_argument("--copies", default="20,80", help="copies per scene: lo,hi")
    ap.add_argument(
        "--out",
        default=DEFAULT_OUT,
        help=f"the report (default {DEFAULT_OUT}; benchmarks/results/bins/bins.md is the "
        "committed one)",
    )
    ap.add_argument(
        "--skip-missing-peers",
        action="store_true",
        help="leave out the peers that are not installed (default: stop, naming them)",
    )
    args = ap.parse_args()
    methods = choose_methods(args.methods, args.skip_missing_peers)

    import pointclm

    if args.models == "all":
        models = list(BIN_MODELS_HELD_OUT) + list(BIN_MODELS_VALIDATION)
    elif args.models == "held-out":
        models = list(BIN_MODELS_HELD_OUT)
    elif args.models == "validation":
        models = list(BIN_MODELS_VALIDATION)
    else:
        models = [m for m in args.models.split(",") if m]
    lo, hi = (int(v) for v in args.copies.split(","))
    table = Table()
    t_start = time.perf_counter()
    n_raw, n_down = [], []
    for model in models:
        n = args.scenes if model in BIN_MODELS_HELD_OUT else args.validation_scenes
        for seed in range(n):
            t0 = time.perf_counter()
            sc = bin_scene_cached(args.cache, seed, BinParams(model=model, copies=(lo, hi)))
            t_build = time.perf_counter() - t0
            table.copies.setdefault(model, []).append(sc.n_copies)
            n_raw.append(len(sc.scan))
            reg = None
            for method in methods:
                t = time.perf_counter()
                if method.startswith("pointclm") or (
                    method.startswith("sequential KISS") and reg is None
                ):
                    own_frame = method == "pointclm (scan in its sensor's frame)"
                    blind = method == "pointclm (no viewpoint)"
                    reg = pointclm.register_point_clouds(
                        sc.model_points,
                        sc.scan - sc.sensor if own_frame else sc.scan,
                        voxel_size=sc.voxel_size,
                        viewpoint=None if own_frame or blind else sc.sensor,
                        peel=method != "pointclm (one pass)",
                        **MATCHING.get(method, {}),
                    )
                    n_down.append(len(reg.target_points))
                if method.startswith("pointclm"):
                    poses = np.array(reg.transformations).reshape(-1, 4, 4)
                    if own_frame:  # back from the sensor's frame to the scene's
                        poses[:, :3, 3] += sc.sensor
                elif method.startswith("sequential KISS"):
                    assert reg is not None
                    tk = time.perf_counter()
                    poses = kiss_in_its_units(reg.correspondences, 2.0 * sc.voxel_size)
                    built = sum(reg.timings[k] for k in ("downsample", "normals", "fpfh"))
                    t = tk - built - reg.timings["matching"]
                else:
                    poses = sequential_ransac_fpfh(
                        sc.model_points,
                        sc.scan,
                        sc.voxel_size,
                        sc.sensor,
                        args.ransac_max_fits,
                        RANSAC_MIN_FITNESS,
                    )
                r = score(np.asarray(poses), sc, time.perf_counter() - t)
                table.add(model, method, r)
                print(
                    f"{model} seed {seed}: {method}: {r.n_correct}/{r.n_pred} correct, "
                    f"half-visible {r.half_found}/{r.half_total}, top10 {r.top_found[10]}, "
                    f"{r.seconds:.1f} s",
                    flush=True,
                )
            print(f"{model} seed {seed}: built in {t_build:.1f} s, {sc.n_copies} copies")

    try:
        import open3d as o3d

        o3d_version = o3d.__version__
    except ImportError:
        o3d_version = "absent"
    lines = [
        "## Bin-picking benchmark",
        "",
        f"- Date: {report.utc_now()}. Command: `{report.command(__spec__.name)}`.",
        f"- Hardware: {report.hardware()} "
        "(shared with other jobs: times are indicative, ratios taken in the same run); every "
        f"method with its default threads. pointclm {pointclm.__version__} "
        f"(git {report.git_commit()}), "
        f"Open3D {o3d_version}.",
        f"- Scenes: {lo}-{hi} copies; median {int(np.median(n_raw))} raw scan points, "
        f"{int(np.median(n_down)) if n_down else 0} after downsampling. RE < 15 deg, TE < 10 % "
        "of the part's diagonal, one prediction per copy (Hungarian matching).",
        "",
    ]
    held = [m for m in models if m in BIN_MODELS_HELD_OUT]
    val = [m for m in models if m not in BIN_MODELS_HELD_OUT]
    if held:
        lines += _markdown("Held-out models (headline)", held, table, methods)
    if val:
        lines += _markdown("Validation models", val, table, methods)
    lines.append(f"The whole run took {(time.perf_counter() - t_start) / 60:.1f} min.")
    text = "\n".join(lines)
    print(text)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text + "\n")
    print(f"report written to {args.out}")


if __name__ == "__main__":
    main()

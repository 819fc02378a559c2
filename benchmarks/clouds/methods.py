"""The rows of the realistic benchmark: pointclm (training-free, learned, refined), the oracle
bound and the sequential peers, each a `Method` run on the same correspondences of a scene
(see `benchmarks.clouds.realistic_models`)."""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

#: Runs of each method per scene; the fastest is its time (see `run_methods`).
TIMED_RUNS = 2


@dataclasses.dataclass(frozen=True)
class Method:
    """A row: `run(scene)` returns the predicted poses."""

    key: str
    label: str
    run: Callable[[Any], np.ndarray]


def _poses(x: Any) -> np.ndarray:
    return np.asarray(x, dtype=np.float64).reshape(-1, 4, 4)


def _refine(scene: Any, poses: np.ndarray) -> np.ndarray:
    import pointclm

    return _poses(
        pointclm.refine_poses(
            scene.source_points, scene.target_points, poses, scene.voxel_size, num_threads=1
        ).transformations
    )


def _pointclm(
    model: str | None, refine: bool, config: dict | None = None, backend: str = "rust"
) -> Callable[[Any], np.ndarray]:
    from pointclm import Config
    from pointclm.embedding import resolve
    from pointclm.evaluation import register_scaled, scene_cues

    base = None if config is None else Config(**config)

    # The network loaded once, on the backend asked for (--backend).
    net = None if model is None else resolve(model, backend)

    def run(scene: Any) -> np.ndarray:
        # The pipeline's own defaults for raw or refined poses (or the model's recommended
        # thresholds), scaled to the voxel, exactly as `register_point_clouds` picks them.
        r = register_scaled(
            scene.correspondences, scene.voxel_size, base, 0, 1, net, refine, scene_cues(scene)
        )
        poses = _poses(r.transformations)
        return _refine(scene, poses) if refine else poses

    return run


def oracle(refine: bool) -> Callable[[Any], np.ndarray]:
    """The poses of the oracle embedding (the true labels), refined on the clouds if `refine`:
    an upper bound, not a method."""
    import pointclm
    from pointclm.point_clouds import scaled_config

    from benchmarks.clouds.realistic import ORACLE_CONFIG, oracle_features

    def run(scene: Any) -> np.ndarray:
        cfg = scaled_config(scene.voxel_size, pointclm.Config(**ORACLE_CONFIG))
        feats = oracle_features(scene.labels, scene.seed % 2**32)
        poses = _poses(
            pointclm.register(scene.correspondences, feats, cfg, 0, num_threads=1).transformations
        )
        return _refine(scene, poses) if refine else poses

    return run


def _peer(name: str) -> Callable[[Any], np.ndarray]:
    from pointclm.point_clouds import scaled_config

    from benchmarks.common import peers

    def run(scene: Any) -> np.ndarray:
        # In units of the model's diagonal: KISS-Matcher clamps its noise bounds at 1.0 (made
        # for metres in large maps), which would loosen them on a model measured in
        # millimetres. Rigid registration is otherwise unit-free; poses are scaled back.
        unit = scene.diameter
        radius = 2.0 * scene.voxel_size / unit  # the scenes' inlier definition
        least = scaled_config(scene.voxel_size).min_cluster_size
        solve = peers.sequential_kiss if name == "kiss" else peers.sequential_ransac
        poses = _poses(solve(scene.correspondences / unit, radius, least))
        poses[:, :3, 3] *= unit
        return poses

    return run


#: Where the report goes unless --out says otherwise: not over the committed results
#: (out/ is not committed).


def peers_to_run(kiss: bool, ransac: bool, skip_missing: bool) -> tuple[bool, bool]:
    """Whether to run the KISS-Matcher and the RANSAC peers, of those asked for. A peer asked
    for but not installed stops the run here, before any scene is built, naming the package,
    unless `skip_missing`: then it is left out, and said so."""
    from benchmarks.common import peers

    wanted = {"sequential KISS-Matcher": "kiss_matcher"} if kiss else {}
    wanted |= {"sequential RANSAC (Open3D)": "open3d"} if ransac else {}
    if not skip_missing:
        peers.require_peers(wanted, "--skip-missing-peers (or --no-kiss / --no-ransac)")
        return kiss, ransac
    missing = peers.missing_peers(wanted)
    for method, module in missing.items():
        print(f"leaving out {method}: the module {module!r} is not installed", flush=True)
    return kiss and "kiss_matcher" not in missing.values(), ransac and (
        "open3d" not in missing.values()
    )


def _available(module: str) -> str | None:
    """The module's version if it imports, else None."""
    try:
        mod = __import__(module)
    except ImportError:
        return None
    return str(getattr(mod, "__version__", "?"))


def make_methods(
    models: Sequence[str],
    ransac: bool,
    kiss: bool = True,
    backend: str = "rust",
    configs: Sequence[tuple[str, dict, bool]] = (),
) -> list[Method]:
    """The rows: training-free (and one per `configs` entry: key, thresholds, refine), each
    network of `models` (run on `backend`), the oracle and the peers."""
    out = [
        Method(
            "pointclm", "pointclm, training-free, correspondences alone", _pointclm(None, False)
        ),
        Method(
            "pointclm+refine",
            "pointclm, training-free + refinement on the clouds",
            _pointclm(None, True),
        ),
    ]
    for key, cfg, refine in configs:
        what = "refinement on the clouds" if refine else "correspondences alone"
        label = f"pointclm, training-free, thresholds {json.dumps(cfg)}, {what}"
        out.append(Method(key, label, _pointclm(None, refine, cfg)))
    for m in models:
        out.append(
            Method(
                f"{m}", f"pointclm, learned embedding ({m!r})", _pointclm(m, False, None, backend)
            )
        )
        out.append(
            Method(
                f"{m}+refine",
                f"pointclm, learned embedding ({m!r}) + refinement on the clouds",
                _pointclm(m, True, None, backend),
            )
        )
    out.append(
        Method("oracle", "upper bound: oracle embedding from the true labels", oracle(False))
    )
    out.append(
        Method(
            "oracle+refine",
            "upper bound: oracle embedding + refinement on the clouds",
            oracle(True),
        )
    )
    kiss_version = _available("kiss_matcher") if kiss else None
    if kiss_version:
        out.append(Method("kiss", f"sequential KISS-Matcher ({kiss_version})", _peer("kiss")))
    o3d_version = _available("open3d") if ransac else None
    if o3d_version:
        out.append(Method("ransac", f"sequential RANSAC (Open3D {o3d_version})", _peer("ransac")))
    return out


def run_methods(scenes: Sequence[Any], methods: Sequence[Method]) -> list[dict[str, Any]]:
    """One record per (scene, method): the scene's identity, the score and the wall time."""
    from pointclm.metrics import score_scene

    rows = []
    t_all = time.perf_counter()
    for i, sc in enumerate(scenes):
        for m in methods:
            # Each method runs twice back to back and keeps its faster time: the first run
            # shares the cores with the previous method's worker threads, which spin for a
            # while after it returns (pointclm right after KISS-Matcher: 2.9 ms, after a pause
            # 2.0), and a pool woken from sleep pays for it (KISS-Matcher after a 0.2 s pause:
            # 13 ms against 2). The second run sees the method's own steady state, as a loop
            # over many scans would. The poses are the same (every method is seeded).
            secs = float("inf")
            for _ in range(TIMED_RUNS):
                t = time.perf_counter()
                poses = m.run(sc)
                secs = min(secs, time.perf_counter() - t)
            s = score_scene(poses, sc.poses, 15.0, sc.max_translation)
            rows.append(
                {
                    "model": sc.model,
                    "seed": sc.seed,
                    "method": m.key,
                    "seconds": secs,
                    **dataclasses.asdict(s),
                }
            )
        if (i + 1) % 10 == 0 or i + 1 == len(scenes):
            print(
                f"  {i + 1}/{len(scenes)} scenes scored, {time.perf_counter() - t_all:.0f} s",
                flush=True,
            )
    return rows

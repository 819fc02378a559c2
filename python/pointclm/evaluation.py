"""Run the pipeline over a dataset and score it: what `pointclm eval` and the benchmarks share."""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .config import Config
from .embedding import resolve
from .metrics import SceneScore, Summary, score_scene, summarize
from .registration import register

__all__ = ["Evaluation", "evaluate"]


@dataclass(frozen=True)
class Evaluation:
    """Scores and per-scene wall times (seconds) of one run over a dataset."""

    summary: Summary
    scores: list[SceneScore]
    seconds: np.ndarray

    @property
    def median_ms(self) -> float:
        return float(np.median(self.seconds) * 1e3)

    @property
    def p90_ms(self) -> float:
        return float(np.percentile(self.seconds, 90) * 1e3)

    def as_dict(self) -> dict[str, Any]:
        return {
            **self.summary.as_dict(),
            "median_ms": self.median_ms,
            "p90_ms": self.p90_ms,
        }


def evaluate(
    scenes: Iterable[Any],
    config: Config | None = None,
    *,
    seed: int = 0,
    num_threads: int | None = None,
    max_translation: float = 0.1,
    max_rotation_deg: float = 15.0,
    progress: Any = None,
    model: Any = None,
    refine: bool = True,
) -> Evaluation:
    """Register each scene (objects with `correspondences` and `poses`) and score it.

    Scenes with a ``voxel_size`` (realistic ones) are in real units: a given `config`, in
    synthetic units, is scaled to each scene's voxel by :meth:`Config.for_voxel`; without one,
    `register_point_clouds`' default applies (:func:`pointclm.point_clouds.cloud_config`). A
    scene's own ``max_translation`` replaces the default TE threshold.

    `progress` wraps the scene iterable (e.g. `tqdm.tqdm`) when given; `model` is passed to
    `register` (the learned embedding; its time counts in the per-scene time). Scenes that
    carry their clouds (``source_points``, ``target_points``) get the poses refined and
    verified on them as `register_point_clouds` does, unless `refine` is False.
    """
    it = progress(scenes) if progress is not None else scenes
    scores, seconds = [], []
    for scene in it:
        t0 = time.perf_counter()
        poses = _found_poses(scene, config, seed, num_threads, model, refine)
        seconds.append(time.perf_counter() - t0)
        scores.append(
            score_scene(
                poses,
                scene.poses,
                max_rotation_deg=max_rotation_deg,
                max_translation=getattr(scene, "max_translation", max_translation),
            )
        )
    if not scores:
        raise ValueError("no scenes to evaluate")
    return Evaluation(summarize(scores), scores, np.asarray(seconds))


def _found_poses(
    scene: Any,
    config: Config | None,
    seed: int,
    num_threads: int | None,
    model: Any,
    refine: bool,
) -> np.ndarray:
    """The (M, 4, 4) poses registration finds in one scene: in synthetic units, or in the
    scene's real units and refined on its clouds when it carries them."""
    voxel = getattr(scene, "voxel_size", None)
    refined = refine and hasattr(scene, "target_points")
    if voxel is None:
        result = register(
            scene.correspondences, config=config, seed=seed, num_threads=num_threads, model=model
        )
    else:
        result = _register_scaled(
            scene.correspondences, voxel, config, seed, num_threads, model, refined
        )
    poses = np.asarray(result.transformations).reshape(-1, 4, 4)
    if voxel is not None and refined:
        from .refinement import refine_poses

        poses = refine_poses(
            scene.source_points, scene.target_points, poses, voxel, num_threads=num_threads
        ).transformations
    return poses


def _register_scaled(
    corr: np.ndarray,
    voxel: float,
    config: Config | None,
    seed: int,
    num_threads: int | None,
    model: Any,
    refine: bool,
) -> Any:
    """Register correspondences in real units as `register_point_clouds` does, with the
    default thresholds for refined poses if `refine` (the refinement itself is the caller's)."""
    from .point_clouds import cloud_config

    # A given config is in synthetic units (like the CLI's flags): scale it too.
    cfg = (
        Config.for_voxel(voxel, config)
        if config is not None
        else cloud_config(voxel, model, refine)
    )
    features = None
    if model is not None:
        features = resolve(model).embed(corr, cfg.sigma_d, num_threads=num_threads)
    return register(corr, features, cfg, seed, num_threads=num_threads)

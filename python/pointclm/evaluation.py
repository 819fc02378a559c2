"""Run the pipeline over a dataset and score it: what `pointclm eval` and the benchmarks share."""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from .config import Config
from .cues import similarity
from .embedding import resolve
from .errors import ConfigError
from .metrics import SceneScore, Summary, score_scene, summarize
from .registration import default_config, register

__all__ = ["Evaluation", "evaluate"]


@dataclass(frozen=True)
class Evaluation:
    """Scores and per-scene wall times (seconds) of one run over a dataset, and the config
    (synthetic units) its scenes were registered with (realistic ones after scaling it to their
    voxel; None when the scenes took different paths, and so different configs)."""

    summary: Summary
    scores: list[SceneScore]
    seconds: np.ndarray
    config: Config | None = None

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


#: How a scene is registered: from correspondences only (synthetic units), or in its real units
#: with its poses refined on its clouds or kept raw.
SceneKind = Literal["correspondences", "refined", "raw"]


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
    config_overrides: Mapping[str, Any] | None = None,
) -> Evaluation:
    """Register each scene (objects with `correspondences` and `poses`) and score it.

    `config` is in synthetic units; scenes with a ``voxel_size`` (realistic ones) are in real
    units, and the config is scaled to each scene's voxel by :meth:`Config.for_voxel`. Without
    one, each path's default applies: `register`'s on correspondences
    (:func:`pointclm.registration.default_config`: `Config()`, or the thresholds recommended
    with `model`), `register_point_clouds`' on realistic scenes
    (:func:`pointclm.point_clouds.cloud_config`, without peeling), with `config_overrides`
    (some fields, in synthetic units, as the CLI's method flags give them) in place of its
    own; give `config` or `config_overrides`, not both. A scene's own ``max_translation``
    replaces the default TE threshold.

    `progress` wraps the scene iterable (e.g. `tqdm.tqdm`) when given; `model` is passed to
    `register` (the learned embedding; its time counts in the per-scene time). Scenes that
    carry their clouds (``source_points``, ``target_points``) get the poses refined and
    verified on them as `register_point_clouds` does, unless `refine` is False.
    """
    if config is not None and config_overrides is not None:
        raise ConfigError(
            "evaluate takes config (a whole config) or config_overrides (some fields over "
            "each path's default), not both"
        )
    it = progress(scenes) if progress is not None else scenes
    configs: dict[SceneKind, Config] = {}
    scores, seconds = [], []
    for scene in it:
        kind = _kind(scene, refine)
        if kind not in configs:
            configs[kind] = _config_of(kind, config, config_overrides, model)
        t0 = time.perf_counter()
        poses = _found_poses(scene, configs[kind], seed, num_threads, model, kind)
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
    used = list(configs.values())
    same = all(c == used[0] for c in used)
    return Evaluation(summarize(scores), scores, np.asarray(seconds), used[0] if same else None)


def _kind(scene: Any, refine: bool) -> SceneKind:
    if getattr(scene, "voxel_size", None) is None:
        return "correspondences"
    return "refined" if refine and hasattr(scene, "target_points") else "raw"


def _config_of(
    kind: SceneKind, config: Config | None, overrides: Mapping[str, Any] | None, model: Any
) -> Config:
    """The config of one kind of scene in synthetic units: `config` as given, else the default
    of its path with `overrides` in place of its own fields."""
    if config is not None:
        return config
    if kind == "correspondences":
        return default_config(model, overrides)
    from .point_clouds import cloud_base_config

    return cloud_base_config(model, kind == "refined", overrides=overrides)


def _found_poses(
    scene: Any,
    config: Config,
    seed: int,
    num_threads: int | None,
    model: Any,
    kind: SceneKind,
) -> np.ndarray:
    """The (M, 4, 4) poses registration finds in one scene with `config` (synthetic units):
    in synthetic units, or in the scene's real units and refined on its clouds as its `kind`
    says."""
    if kind == "correspondences":
        result = register(
            scene.correspondences, config=config, seed=seed, num_threads=num_threads, model=model
        )
        return np.asarray(result.transformations).reshape(-1, 4, 4)
    voxel = scene.voxel_size
    result = register_scaled(
        scene.correspondences,
        voxel,
        config,
        seed,
        num_threads,
        model,
        kind == "refined",
        scene_cues(scene),
    )
    poses = np.asarray(result.transformations).reshape(-1, 4, 4)
    if kind == "refined":
        from .refinement import refine_poses

        poses = refine_poses(
            scene.source_points, scene.target_points, poses, voxel, num_threads=num_threads
        ).transformations
    return poses


def scene_cues(scene: Any) -> tuple[np.ndarray | None, np.ndarray | None]:
    """A realistic scene's pair normals and match similarities (None where it has none)."""
    normals = getattr(scene, "pair_normals", None)
    distance = getattr(scene, "match_distance", None)
    return normals, None if distance is None else similarity(distance)


def register_scaled(
    corr: np.ndarray,
    voxel: float,
    config: Config | None,
    seed: int,
    num_threads: int | None,
    model: Any,
    refine: bool,
    cues: tuple[Any, Any] = (None, None),
) -> Any:
    """Register correspondences in real units as `register_point_clouds` does: `config`
    (synthetic units) scaled to `voxel`, or without one the default thresholds for refined
    poses if `refine` (:func:`pointclm.point_clouds.cloud_config`; the refinement itself is the
    caller's). `cues` (normals, similarity) go to a network that takes them, and the normals
    to the pipeline too when it does, as `register_point_clouds` gives them. The benchmarks
    call it too."""
    from .point_clouds import cloud_base_config

    base = config if config is not None else cloud_base_config(model, refine)
    cfg = Config.for_voxel(voxel, base)
    features = None
    normals = None
    if model is not None:
        emb = resolve(model)
        features = emb.embed(
            corr, cfg.sigma_d, num_threads=num_threads, normals=cues[0], similarity=cues[1]
        )
        normals = emb.pipeline_normals(cues[0])
    return register(corr, features, cfg, seed, num_threads=num_threads, normals=normals)

"""Run the pipeline over a dataset and score it: what `pointclm eval` and the benchmarks share."""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .config import Config
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
) -> Evaluation:
    """Register each scene (objects with `correspondences` and `poses`) and score it.

    `progress` wraps the scene iterable (e.g. `tqdm.tqdm`) when given; `model` is passed to
    `register` (the learned embedding; its time counts in the per-scene time).
    """
    it = progress(scenes) if progress is not None else scenes
    scores, seconds = [], []
    for scene in it:
        t0 = time.perf_counter()
        result = register(
            scene.correspondences, config=config, seed=seed, num_threads=num_threads, model=model
        )
        seconds.append(time.perf_counter() - t0)
        scores.append(
            score_scene(
                result.transformations,
                scene.poses,
                max_rotation_deg=max_rotation_deg,
                max_translation=max_translation,
            )
        )
    if not scores:
        raise ValueError("no scenes to evaluate")
    return Evaluation(summarize(scores), scores, np.asarray(seconds))

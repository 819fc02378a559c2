"""What every pass of one `register_point_clouds` call shares, and matching a pass's scan
points against the model."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, NamedTuple

import numpy as np

from .. import _core
from .. import preprocessing as pp
from ..config import Config
from ..cues import similarity
from ..embedding import Embedding
from ..refinement import (
    RefinementContext,
)
from ..scene_rules import SCENE_DEFAULTS, SceneRules


@dataclass(frozen=True)
class _Run:
    """What every pass of one `register_point_clouds` call shares."""

    src_d: pp.DescribedCloud
    tgt_d: pp.DescribedCloud
    voxel: float
    #: The sensor position verification judges by; None: none known.
    viewpoint: tuple[float, float, float] | None
    matching: dict[str, Any]
    #: Matches scan points to the model; finds each scan point's nearest model descriptors
    #: once for every pass.
    matcher: pp.DescriptorMatcher
    normals: bool
    seed: int
    #: The learned embedding, resolved once for every pass; None: training-free.
    model: Embedding | None
    num_threads: int | None
    #: The matching of the passes once the accepted copies show a heap (``heap_rank`` or
    #: ``mutual_window="auto"``); None: every pass uses `matching`.
    heap_matching: dict[str, Any] | None = None
    #: The viewpoint is the origin of a scan in its sensor's frame, not given: the first
    #: pass confirms it (:func:`_confirm_viewpoint`).
    guessed_viewpoint: bool = False
    #: Whether the scan is a heap (``heap``): None once `SceneRules.heap_min_copies` copies
    #: are accepted, True in every pass.
    heap: bool | None = None
    #: The scene-wide rules.
    scene: SceneRules = SCENE_DEFAULTS
    #: A guessed viewpoint the first pass did not confirm: the scan's normals face it, but
    #: poses are judged without one.
    unconfirmed: tuple[float, float, float] | None = None

    @cached_property
    def refiner(self) -> RefinementContext:
        """Refinement against this scan, its cloud-only part built once for every pass."""
        return RefinementContext(
            self.src_d.points,
            self.tgt_d.points,
            self.voxel,
            viewpoint=self.viewpoint,
            target_normals=self.tgt_d.normals,
            num_threads=self.num_threads,
        )

    @cached_property
    def voter(self) -> _core.PpfModel:
        """The model's point pair features tabled for voting, built once for every pass; its
        diameter is the model's bounding-box diagonal."""
        pts = self.src_d.points
        diameter = _core.bounding_diagonal(pts)
        return _core.PpfModel(
            pts, self.src_d.normals, diameter, max_poses=self.scene.heap_voted_poses
        )

    def voted_poses(self, rows: np.ndarray, offset: int) -> np.ndarray:
        """Poses voted by point pairs among the scan points `rows`, most voted first (the
        references start at `offset`, so that each round votes from other points)."""
        poses, _ = self.voter.poses(
            self.tgt_d.points, self.tgt_d.normals, rows, offset, num_threads=self.num_threads
        )
        return poses

    def features(
        self,
        corr: np.ndarray,
        cfg: Config,
        normals: np.ndarray | None = None,
        sims: np.ndarray | None = None,
    ) -> np.ndarray | None:
        """The learned embedding of `corr` (in the units of `cfg`) with the cues its network
        takes, or None without one."""
        if self.model is None:
            return None
        return self.model.embed(
            corr, cfg.sigma_d, num_threads=self.num_threads, normals=normals, similarity=sims
        )


class PassMatches(NamedTuple):
    """A pass's correspondences, with what its network takes beside them."""

    #: (N, 6) rows: downsampled model point | downsampled scan point.
    correspondences: np.ndarray
    #: (N, 6) the unit normals at both ends, when the run uses normals or its network takes
    #: them; else None.
    normals: np.ndarray | None
    #: (N,) descriptor similarity, when the network takes it; else None.
    similarity: np.ndarray | None


def _match(
    run: _Run, rows: np.ndarray, seed: int, matching: dict[str, Any] | None = None
) -> PassMatches:
    """Correspondences between the model and the scan points `rows`, by the run's
    :class:`pointclm.preprocessing.DescriptorMatcher` with `matching` (the run's own when
    None); the normals at their ends when the run uses normals or its network takes them,
    and their descriptor similarity when the network takes it (else None)."""
    m = run.matcher.match(rows, seed=seed, **(run.matching if matching is None else matching))
    corr = m.correspondences(run.src_d.points, run.tgt_d.points)
    inputs = () if run.model is None else run.model.inputs
    normals = None
    if run.normals or "normals" in inputs:
        normals = m.normals(run.src_d.normals, run.tgt_d.normals)
    sims = similarity(m.distance) if "similarity" in inputs and len(corr) else None
    return PassMatches(corr, normals, sims)


def _matching(
    top_k: int, mutual: bool, n_samples: int | None, window: float | None, src: np.ndarray
) -> dict[str, Any]:
    """The matcher's arguments of every pass; a window (in model diagonals) in the clouds'
    units."""
    matching: dict[str, Any] = {"top_k": top_k, "mutual": mutual, "n_samples": n_samples}
    if window is not None:
        matching["window"] = window * float(np.linalg.norm(src.max(0) - src.min(0)))
    return matching


def _matchings(
    top_k: int,
    mutual: bool,
    n_samples: int | None,
    k: int,
    window: float | str | None,
    src: np.ndarray,
    rank: int | None = None,
    heap: bool | None = None,
    scene: SceneRules = SCENE_DEFAULTS,
) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """The matcher's arguments of the first passes, and those once a heap is recognised
    (None: no switch)."""
    fixed = None if isinstance(window, str) else window  # "auto" starts scene-wide
    matching = _matching(top_k, mutual, n_samples, fixed, src)
    if not mutual or k != 1 or heap is False:
        return matching, None  # only the mutual check can be relaxed
    if window == "auto":
        return matching, _matching(top_k, True, None, scene.heap_window, src)
    if window is None and rank is not None and rank > 1:
        return matching, dict(matching, mutual_rank=rank)
    return matching, None


def _matcher(
    src_d: pp.DescribedCloud, tgt_d: pp.DescribedCloud, k: int, num_threads: int | None
) -> pp.DescriptorMatcher:
    """The run's matcher: the scan's positions come along for a windowed mutual check."""
    return pp.DescriptorMatcher(
        src_d.descriptors,
        tgt_d.descriptors,
        k=k,
        num_threads=num_threads,
        target_points=tgt_d.points,
    )

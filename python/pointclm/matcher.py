"""Descriptor matching: a scan's points paired with the model's by FPFH, scene-wide or, in a
heap, by rank or within windows (:class:`DescriptorMatcher`), and the one-shot
:func:`match_features`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from . import _core
from .errors import InputError
from .preprocessing import as_count, as_flag, as_positive
from .registration import as_matrix, as_seed, as_threads

__all__ = ["WINDOW_CANDIDATES", "DescriptorMatcher", "Matches", "match_features"]


@dataclass(frozen=True)
class Matches:
    """Descriptor matches, most salient (smallest descriptor distance) first."""

    source: np.ndarray
    target: np.ndarray
    distance: np.ndarray

    def __len__(self) -> int:
        return len(self.source)

    def correspondences(self, source_points: ArrayLike, target_points: ArrayLike) -> np.ndarray:
        """(N, 6) rows (source xyz | target xyz) for these matches."""
        s = np.asarray(source_points, dtype=np.float64)
        t = np.asarray(target_points, dtype=np.float64)
        return np.ascontiguousarray(np.hstack([s[self.source], t[self.target]]))

    def normals(self, source_normals: ArrayLike, target_normals: ArrayLike) -> np.ndarray:
        """(N, 6) rows (source normal | target normal) for these matches: the ``normals=`` of
        :func:`pointclm.register`."""
        return self.correspondences(source_normals, target_normals)


def match_features(
    source: ArrayLike,
    target: ArrayLike,
    *,
    top_k: int = 10_000,
    mutual: bool = False,
    n_samples: int | None = 1000,
    seed: int = 0,
    num_threads: int | None = None,
    k: int = 1,
) -> Matches:
    """Each target descriptor's `k` nearest source descriptors (exact), the `top_k` closest
    matches kept (if `mutual`, only pairs where the target is also among the source's `k`
    nearest: mutual nearest neighbours for k = 1), then `n_samples` drawn at random with
    `seed` (None keeps all), as the paper's appendix builds its correspondences.

    k > 1 matters for several copies of a model in one scan: each scan point proposes its k
    best model points, so every copy gets matches, not only the one a model point likes best.
    """
    return DescriptorMatcher(source, target, k=k, num_threads=num_threads).match(
        top_k=top_k, mutual=mutual, n_samples=n_samples, seed=seed
    )


def _descriptor_pair(source: ArrayLike, target: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    s = as_matrix(source, "source descriptors", None)
    t = as_matrix(target, "target descriptors", None)
    if len(s) == 0 or len(t) == 0:
        raise InputError("need at least one source and one target descriptor")
    if s.shape[1] != t.shape[1]:
        raise InputError(f"descriptor lengths differ: source {s.shape[1]}, target {t.shape[1]}")
    return s, t


#: Nearest target rows per source row that a windowed mutual check (`DescriptorMatcher.match`'s
#: ``window``) looks at: a heap shows a few dozen copies, so a source point's true match on
#: each lies among its few dozen nearest; more cost time and found no more copies on the
#: validation bins (128: recall of half-visible copies 0.362 vs 0.356).
WINDOW_CANDIDATES = 64
#: The corner offsets (in cells) of the 8 cubes of `DescriptorMatcher`'s windows holding a cell.
_CUBE_CORNERS = np.array([(i, j, k) for i in (0, 1) for j in (0, 1) for k in (0, 1)])


class DescriptorMatcher:
    """:func:`match_features` for one model and one scan, matched whole or in parts.

    Each target row's `k` nearest source rows do not depend on the other target rows, so the
    matcher finds them once (on the first call that needs them) and every later
    :meth:`match` of a subset of the target rows reuses them; only the mutual check, which
    depends on which target rows take part, is redone. Peeling in
    :func:`pointclm.register_point_clouds` matches the scan points no accepted copy explains,
    pass after pass, this way. The results equal :func:`match_features` on the subset.
    """

    def __init__(
        self,
        source: ArrayLike,
        target: ArrayLike,
        *,
        k: int = 1,
        num_threads: int | None = None,
        target_points: ArrayLike | None = None,
    ) -> None:
        self.source, self.target = _descriptor_pair(source, target)
        self.k = as_count(k, "k", 1)
        self.num_threads = as_threads(num_threads)
        self.target_points = None
        if target_points is not None:
            self.target_points = as_matrix(target_points, "target_points", 3)
            if len(self.target_points) != len(self.target):
                raise InputError(
                    f"need one target point per target descriptor: {len(self.target)} "
                    f"descriptors, {len(self.target_points)} points"
                )
        self._nearest: tuple[np.ndarray, np.ndarray] | None = None
        self._nearest_targets: np.ndarray | None = None

    def match(
        self,
        rows: ArrayLike | None = None,
        *,
        top_k: int = 10_000,
        mutual: bool = False,
        n_samples: int | None = 1000,
        seed: int = 0,
        window: float | None = None,
        mutual_rank: int = 1,
    ) -> Matches:
        """Matches of the target rows `rows` (None: all; indices into the target); the
        returned target indices index the whole target.

        `window` (with `mutual`, ``k=1`` and the matcher's `target_points`) makes the mutual
        check local: the target points are covered by overlapping cubes of side `window` (a
        grid of stride `window` / 2), and a pair counts as mutual when the source point is
        the target point's nearest and the target point is the source point's nearest among
        the target rows of some cube (:data:`WINDOW_CANDIDATES` nearest looked at). Why: in a
        heap of identical parts a source point has one true match per visible copy, and the
        scene-wide mutual check keeps at most one of them; within a window about a part wide
        each copy keeps its own, while the check still drops most of the pairs a source point
        would not choose.

        `mutual_rank` (with `mutual` and ``k=1``, no `window`) relaxes the check by rank
        instead of place: a pair counts when the source point is the target point's nearest
        and the target point is among the source point's `mutual_rank` nearest target rows
        taking part (looked for among its :data:`WINDOW_CANDIDATES` nearest of the whole
        target, or `mutual_rank` if more). 1 is the mutual nearest neighbour check. Why: in a
        heap each copy holds one true match of a source point, and the copies compete for it;
        ranked, a source point keeps a match on as many copies as the rank allows, wherever
        they lie."""
        n = None if n_samples is None else as_count(n_samples, "n_samples", 1)
        rank = as_count(mutual_rank, "mutual_rank", 1)
        seed = as_seed(seed)
        kept, mutual_only = as_count(top_k, "top_k", 1), as_flag(mutual, "mutual")
        nearest = None
        if window is not None or rank > 1:
            picked = self._relaxed(rows, window, rank, mutual_only)
            if len(picked) == 0:
                empty = np.zeros(0, dtype=np.int64)
                return Matches(empty, empty.copy(), np.zeros(0))
            rows, mutual_only = picked, False  # the pairs left are the mutual ones
        elif rows is not None:
            picked = self._rows(rows)
        if rows is not None:
            near, d2 = self._nearest_sources()
            nearest = (near[picked], d2[picked])
        src, tgt, dist = _core.match_features(
            self.source,
            self.target if rows is None else self.target[picked],
            top_k=kept,
            mutual=mutual_only,
            n_samples=n,
            seed=seed,
            num_threads=self.num_threads,
            k=self.k,
            nearest=nearest,
        )
        return Matches(src, tgt if rows is None else picked[tgt], dist)

    def _rows(self, rows: ArrayLike) -> np.ndarray:
        picked = np.asarray(rows)
        if picked.dtype == bool:
            if picked.shape != (len(self.target),):
                raise InputError(
                    f"a boolean rows mask needs one entry per target row ({len(self.target)}), "
                    f"got shape {picked.shape}"
                )
            picked = np.flatnonzero(picked)
        if picked.ndim != 1 or not np.issubdtype(picked.dtype, np.integer):
            raise InputError("rows must be a 1-D array of target row indices or a boolean mask")
        if len(picked) == 0:
            raise InputError("rows is empty: need at least one target row to match")
        if picked.min() < 0 or picked.max() >= len(self.target):
            raise InputError(f"rows must index the {len(self.target)} target rows")
        return picked.astype(np.int64)

    def _window(self, window: float, mutual: bool) -> float:
        side = as_positive(window, "window")
        if not mutual or self.k != 1:
            raise InputError("window needs mutual=True and k=1: it makes the mutual check local")
        if self.target_points is None:
            raise InputError("window needs the matcher's target_points (the target's positions)")
        return side

    def _relaxed(
        self, rows: ArrayLike | None, window: float | None, rank: int, mutual: bool
    ) -> np.ndarray:
        """The target rows (of `rows`) in a pair the windowed or ranked mutual check keeps."""
        picked = np.arange(len(self.target)) if rows is None else self._rows(rows)
        if window is None:
            if not mutual or self.k != 1:
                raise InputError(
                    "mutual_rank needs mutual=True and k=1: it relaxes the mutual check"
                )
            return self._rank_mutual(picked, rank)
        if rank > 1:
            raise InputError("give window or mutual_rank, not both: each relaxes the check")
        return self._windowed_mutual(picked, self._window(window, mutual))

    def _nearest_targets_of_sources(self, k: int) -> np.ndarray:
        """Every source row's `k` (at least :data:`WINDOW_CANDIDATES`) nearest target rows of
        the whole target, nearest first; found once, again only for a larger `k`."""
        k = max(k, WINDOW_CANDIDATES)
        if self._nearest_targets is None or self._nearest_targets.shape[1] < min(
            k, len(self.target)
        ):
            self._nearest_targets, _ = _core.nearest_descriptors(
                self.target, self.source, k=k, num_threads=self.num_threads
            )
        return self._nearest_targets

    def _candidates(self, picked: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """`(source row, target row)` for each of the rows of `picked` among every source row's
        nearest target rows (:meth:`_nearest_targets_of_sources`, found once over the whole
        target; a call on fewer rows looks at those of the list among them), by source row,
        then nearest first."""
        nearest = self._nearest_targets_of_sources(k)
        taking_part = np.zeros(len(self.target), dtype=bool)
        taking_part[picked] = True
        src, col = np.nonzero(taking_part[nearest])
        return src, nearest[src, col]

    def _rank_mutual(self, picked: np.ndarray, rank: int) -> np.ndarray:
        """The rows of `picked` whose nearest source row counts them among its `rank`
        nearest rows of `picked` (:meth:`match`'s `mutual_rank`), in increasing order."""
        src, tgt = self._candidates(picked, rank)
        # The rank among the rows taking part: the position within the source row's run.
        place = np.arange(len(src)) - np.searchsorted(src, src)
        src, tgt = src[place < rank], tgt[place < rank]
        near, _ = self._nearest_sources()
        return np.unique(tgt[near[tgt, 0] == src])

    def _windowed_mutual(self, picked: np.ndarray, side: float) -> np.ndarray:
        """The rows of `picked` whose pair with their nearest source row is mutual within
        some cube of side `side` (:meth:`match`), in increasing order."""
        assert self.target_points is not None
        src, tgt = self._candidates(picked, WINDOW_CANDIDATES)
        # A point in cell c (of side / 2) lies in the cubes whose corner cells are c - {0, 1}^3.
        cells = np.floor((self.target_points - self.target_points.min(0)) / (side / 2))
        cells = cells.astype(np.int64) + 1
        shape = tuple(int(v) for v in cells.max(0) + 1)
        corners = cells[tgt][:, None, :] - _CUBE_CORNERS[None]
        cube = np.ravel_multi_index(tuple(np.moveaxis(corners, 2, 0)), shape)
        n_cubes = int(np.prod(shape))
        key = (np.repeat(src, 8) * n_cubes + cube.reshape(-1)).astype(np.int64)
        _, first = np.unique(key, return_index=True)  # each source row's best in each cube
        best_src, best_tgt = np.repeat(src, 8)[first], np.repeat(tgt, 8)[first]
        near, _ = self._nearest_sources()
        mutual = best_tgt[near[best_tgt, 0] == best_src]
        return np.unique(mutual)

    def _nearest_sources(self) -> tuple[np.ndarray, np.ndarray]:
        if self._nearest is None:
            self._nearest = _core.nearest_descriptors(
                self.source, self.target, k=self.k, num_threads=self.num_threads
            )
        return self._nearest

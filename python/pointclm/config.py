"""`Config`: every threshold of the method, mirroring the Rust `pointclm::Config`.

Lengths (`sigma_d`, `affinity_sigma`, `inlier_threshold`) are in the units of your points. The
defaults are the paper's synthetic settings (shapes in a unit sphere, noise about 0.01); use
`Config().scaled(f)` when your objects and noise are `f` times larger, and
`Config.for_voxel(voxel)` for clouds downsampled at `voxel`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any, Literal

import numpy as np

from . import _core
from .errors import ConfigError, InputError

__all__ = ["INLIER_VOXELS", "SIGMA_D_VOXELS", "Config"]

#: `Config.for_voxel`: sigma_d is this many voxels (see there why).
SIGMA_D_VOXELS = 3.0
#: `Config.for_voxel`: `Config()`'s inlier threshold becomes this many voxels (see there why).
INLIER_VOXELS = 2.0


@dataclass(frozen=True)
class Config:
    """Parameters of `pointclm.register`; checked by the Rust core when constructed.

    Units: three fields are lengths, `sigma_d`, `affinity_sigma` and `inlier_threshold`, in
    the units of the coordinates the config is used with; every other field is unitless (a
    consistency or similarity level in [0, 1], a count, an eigenvalue level, an expected
    number of false alarms). The defaults are in the synthetic protocol's units (shapes in a
    unit sphere). Where each entry point takes its config:

    - `pointclm.register` / `register_batch`: the correspondences' units. With a `model` the
      network still sees them in the units it was trained in (:mod:`pointclm.embedding`
      converts them by ``sigma_d``), so ``Config().scaled(f)`` is right for coordinates `f`
      times larger with or without a network.
    - `pointclm.register_point_clouds(config=...)`: the clouds' units, used as given. Build one
      from synthetic-unit settings with ``Config.for_voxel(voxel_size, base)``; without a
      config it uses that with the defaults for clouds.
    - `pointclm.evaluation.evaluate(config=...)` on scenes with a ``voxel_size`` (realistic
      scenes of different sizes): the synthetic units, scaled to each scene's voxel by
      `for_voxel`.

    Attributes
    ----------
    sigma_d : float
        Length tolerance of spatial consistency ``beta = [1 - d^2 / sigma_d^2]_+``.
    pruning : {"paper", "authors", "none"}
        "paper": binarise ``S`` at `tau_s`, keep rows whose sum exceeds `tau_n`.
        "authors": the authors' code, ``beta > beta_threshold`` (and feature similarity
        ``> feature_threshold``), keep rows whose count exceeds `min_count`.
        "none": no pruning (ablation).
    max_kept : int
        At most this many pruned correspondences go to the dense eigensolver (the densest).
    affinity_sigma : float
        Length scale of the clustering affinity.
    max_instances : int or None
        Optional cap on the number of clusters the eigengap may choose.
    cluster_level : float or None
        When set, the cluster count is the larger of the eigengap's and the number of
        normalised-Laplacian eigenvalues below this level (in (0, 2)): with dozens of similar
        copies the largest gap comes early. None: the eigengap alone (the paper's rule).
    max_rounds : int
        Clustering rounds: after each, the correspondences explained by validated instances
        leave the kept set and the rest is clustered again (finds copies the eigengap merged
        or missed). Needs `max_nfa`; 1 is the paper's single round.
    assignment : {"kmeans", "discretize"}
        k-means++ on the row-normalised embedding, or Yu-Shi discretisation.
    kmeans_restarts : int
        Restarts of the label assignment (best objective wins).
    min_cluster_size : int
        Clusters and final instances with fewer members are dropped.
    ransac_iterations : int
        At most this many 3-point hypotheses per cluster.
    ransac_confidence : float
        RANSAC stops once an all-inlier sample would have been drawn with this probability at
        the best inlier share so far (1.0 runs all `ransac_iterations`).
    max_nfa : float or None
        A-contrario validation: an instance is kept only if its expected number of false
        alarms (equally supported poses arising from unrelated matches, among all candidates)
        is at most this. None keeps every instance.
    inlier_threshold : float
        A correspondence is an inlier of a pose if ``||R x + t - y||`` is below this.
    refine : bool
        Least-squares refit of each pose on its inliers.
    merge_duplicates : bool
        Merge instances whose poses place the object at the same spot.
    """

    sigma_d: float = 0.05
    pruning: Literal["paper", "authors", "none"] = "paper"
    tau_s: float = 0.85
    tau_n: int = 10
    beta_threshold: float = 0.9
    feature_threshold: float = 0.8
    min_count: int = 9
    max_kept: int = 2000
    affinity_sigma: float = 0.1
    max_instances: int | None = None
    cluster_level: float | None = None
    max_rounds: int = 1
    assignment: Literal["kmeans", "discretize"] = "kmeans"
    kmeans_restarts: int = 10
    min_cluster_size: int = 10
    ransac_iterations: int = 1000
    ransac_confidence: float = 1.0
    max_nfa: float | None = 1e-3
    inlier_threshold: float = 0.1
    refine: bool = True
    merge_duplicates: bool = True

    def __post_init__(self) -> None:
        for name in (
            "sigma_d",
            "tau_s",
            "beta_threshold",
            "feature_threshold",
            "affinity_sigma",
            "inlier_threshold",
            "ransac_confidence",
        ):
            value = getattr(self, name)
            if isinstance(value, bool):
                raise ConfigError(f"config field {name}: expected a number, got {value!r}")
            if isinstance(value, int | float | np.integer | np.floating):
                try:
                    object.__setattr__(self, name, float(value))  # numpy floats -> float
                except OverflowError:
                    raise ConfigError(f"config field {name}: {value!r} is too large") from None
        for name in ("refine", "merge_duplicates"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"config field {name}: expected True or False")
        for name in (
            "tau_n",
            "min_count",
            "max_kept",
            "kmeans_restarts",
            "min_cluster_size",
            "ransac_iterations",
            "max_rounds",
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer):
                raise ConfigError(f"config field {name}: expected an int, got {value!r}")
            if value < 0:
                raise ConfigError(f"config field {name}: must be >= 0, got {value}")
            object.__setattr__(self, name, int(value))  # numpy ints -> int for the core
        level = self.cluster_level
        if level is not None:
            if isinstance(level, bool) or not isinstance(
                level, int | float | np.integer | np.floating
            ):
                raise ConfigError(
                    f"config field cluster_level: expected None or a number, got {level!r}"
                )
            object.__setattr__(self, "cluster_level", float(level))
        nfa = self.max_nfa
        if nfa is not None:
            if isinstance(nfa, bool) or not isinstance(nfa, int | float | np.integer | np.floating):
                raise ConfigError(f"config field max_nfa: expected None or a number, got {nfa!r}")
            object.__setattr__(self, "max_nfa", float(nfa))
        mi = self.max_instances
        if mi is not None:
            if isinstance(mi, bool) or not isinstance(mi, int | np.integer) or mi < 1:
                raise ConfigError(
                    f"config field max_instances: expected None or an int >= 1, got {mi!r}"
                )
            object.__setattr__(self, "max_instances", int(mi))
        # The Rust core is the single source of truth for valid ranges.
        _core.validate_config(self.to_dict())

    def to_dict(self) -> dict[str, Any]:
        """Fields as a plain dict (what the Rust core receives)."""
        return asdict(self)

    @classmethod
    def for_voxel(cls, voxel_size: float, base: Config | None = None) -> Config:
        """`base` (default `Config()`, in the synthetic protocol's units) with its lengths in
        the units of clouds downsampled at `voxel_size`: sigma_d = `SIGMA_D_VOXELS` (3)
        voxels, the clustering affinity in its ratio to sigma_d, and the inlier threshold at
        `INLIER_VOXELS` (2) voxels for `Config()`'s (other values of `base.inlier_threshold`
        in proportion). The unitless fields are kept. This is the config
        `pointclm.register_point_clouds` uses by default (with its thresholds for clouds as
        `base`) and `evaluate` applies to realistic scenes.

        Why 3: a correct descriptor match lands within about a voxel of the true point on each
        side, so the pairwise length differences that spatial consistency compares are off by
        up to about 2 voxels; at sigma_d = 3 voxels their consistency stays above 0.5. Why 2
        for inliers: the same voxel on each side bounds a correct pose's residual; the
        synthetic ratio (twice sigma_d, 6 voxels) lets a wrong pose collect as many chance
        inliers on a dense scan as a right one, and a least-squares refit on them drifts
        (chosen on the validation models: MF 17.6 -> 20.5 on dragon, happy and armadillo
        scenes).
        """
        base = base or cls()
        scaled = base.scaled(SIGMA_D_VOXELS * voxel_size / base.sigma_d)
        per_unit = INLIER_VOXELS * voxel_size / cls().inlier_threshold
        return replace(scaled, inlier_threshold=base.inlier_threshold * per_unit)

    def scaled(self, factor: float) -> Config:
        """The same settings with every length multiplied by `factor`."""
        real = not isinstance(factor, bool) and isinstance(
            factor, int | float | np.integer | np.floating
        )
        try:
            ok = real and factor > 0 and math.isfinite(factor)
        except OverflowError:  # an int beyond float range
            ok = False
        if not ok:
            raise InputError(f"scale factor must be a finite number > 0, got {factor!r}")
        return replace(
            self,
            sigma_d=self.sigma_d * factor,
            affinity_sigma=self.affinity_sigma * factor,
            inlier_threshold=self.inlier_threshold * factor,
        )

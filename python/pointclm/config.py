"""`Config`: every threshold of the method, the typed Python view of the Rust `pointclm::Config`.

The Rust struct is the one definition of the fields: their names, defaults, documentation,
kinds and which are lengths reach Python through `_core.config_schema()`. Here each field is a
typed line (for mypy and IDEs) whose default is read from that schema; the checks, `scaled` and
the "Attributes" section of `Config`'s docstring are derived from it, and a test fails if the
lines and the schema drift apart.

Lengths (`sigma_d`, `affinity_sigma`, `inlier_threshold`) are in the units of your points. The
defaults are the paper's synthetic settings (shapes in a unit sphere, noise about 0.01); use
`Config().scaled(f)` when your objects and noise are `f` times larger, and
`Config.for_voxel(voxel)` for clouds downsampled at `voxel`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np

from . import _core
from .errors import ConfigError, InputError

__all__ = ["INLIER_VOXELS", "SIGMA_D_VOXELS", "Config"]

#: `Config.for_voxel`: sigma_d is this many voxels (declared in the core,
#: ``pointclm::scene::SIGMA_D_VOXELS``; see `for_voxel` why).
SIGMA_D_VOXELS: float = _core.SIGMA_D_VOXELS
#: `Config.for_voxel`: `Config()`'s inlier threshold becomes this many voxels (declared in the
#: core, ``pointclm::scene::INLIER_VOXELS``).
INLIER_VOXELS: float = _core.INLIER_VOXELS

#: The Rust core's description of every field of `Config`, by name, in declaration order:
#: kind ("float", "count", "bool", "choice"), choices, optional, default, length, doc.
_SCHEMA: dict[str, dict[str, Any]] = {f["name"]: f for f in _core.config_schema()}
#: The fields that are lengths (multiplied by `Config.scaled`), from the schema.
_LENGTHS: tuple[str, ...] = tuple(name for name, f in _SCHEMA.items() if f["length"])

_REAL = (int, float, np.integer, np.floating)


def _default(name: str) -> Any:
    """The Rust default of field `name` (a KeyError at import for a name the core lacks)."""
    return _SCHEMA[name]["default"]


def _checked(
    name: str,
    value: Any,
    schema: Mapping[str, Mapping[str, Any]] = _SCHEMA,
    what: str = "config field",
) -> Any:
    """`value` of field `name` of `schema` (default `Config`'s) as the plain Python type the
    core and repr expect (numpy scalars and ints as float or int), or ConfigError (its message
    starting with `what` and the name) for a value of the wrong kind. Ranges and choices are
    the core's to check."""
    field = schema[name]
    kind, optional = field["kind"], field["optional"]
    if optional and value is None:
        return None
    if kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{what} {name}: expected True or False")
        return value
    if kind == "float":
        number = not isinstance(value, bool) and isinstance(value, _REAL)
        if optional and not number:
            raise ConfigError(f"{what} {name}: expected None or a number, got {value!r}")
        if isinstance(value, bool):
            raise ConfigError(f"{what} {name}: expected a number, got {value!r}")
        if not number:
            return value  # the core names the type it wanted
        try:
            return float(value)
        except OverflowError:
            raise ConfigError(f"{what} {name}: {value!r} is too large") from None
    if kind == "count":
        integer = not isinstance(value, bool) and isinstance(value, int | np.integer)
        if optional:
            if not integer or value < 1:
                raise ConfigError(f"{what} {name}: expected None or an int >= 1, got {value!r}")
        elif not integer:
            raise ConfigError(f"{what} {name}: expected an int, got {value!r}")
        elif value < 0:
            raise ConfigError(f"{what} {name}: must be >= 0, got {value}")
        return int(value)
    return value  # a choice: the core checks the name


def _unknown_keys(values: Mapping[str, Any], known: Any, what: str) -> None:
    """ConfigError naming the keys of `values` that are not among `known`, and the valid ones
    (`what`: the struct's name for its fields)."""
    unknown = [k for k in values if k not in known]
    if unknown:
        raise ConfigError(f"unknown {what}(s) {unknown}; valid keys are {sorted(known)}")


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
    """

    sigma_d: float = _default("sigma_d")
    pruning: Literal["paper", "authors", "none"] = _default("pruning")
    tau_s: float = _default("tau_s")
    tau_n: int = _default("tau_n")
    beta_threshold: float = _default("beta_threshold")
    feature_threshold: float = _default("feature_threshold")
    min_count: int = _default("min_count")
    max_kept: int = _default("max_kept")
    affinity_sigma: float = _default("affinity_sigma")
    max_instances: int | None = _default("max_instances")
    cluster_level: float | None = _default("cluster_level")
    max_rounds: int = _default("max_rounds")
    assignment: Literal["kmeans", "discretize"] = _default("assignment")
    kmeans_restarts: int = _default("kmeans_restarts")
    min_cluster_size: int = _default("min_cluster_size")
    ransac_iterations: int = _default("ransac_iterations")
    ransac_confidence: float = _default("ransac_confidence")
    max_nfa: float | None = _default("max_nfa")
    inlier_threshold: float = _default("inlier_threshold")
    refine: bool = _default("refine")
    merge_duplicates: bool = _default("merge_duplicates")

    def __post_init__(self) -> None:
        for name in _SCHEMA:
            if name in self.__dataclass_fields__:
                object.__setattr__(self, name, _checked(name, getattr(self, name)))
        # The Rust core is the single source of truth for valid ranges.
        _core.validate_config(self.to_dict())

    def to_dict(self) -> dict[str, Any]:
        """Fields as a plain dict (what the Rust core receives)."""
        # Every field is a scalar, a string or None: a shallow dict equals `asdict`'s deep
        # copy, at a tenth of its cost (this runs on every `register` call).
        return {name: getattr(self, name) for name in self.__dataclass_fields__}

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> Config:
        """A Config from a dict of some of its fields; unknown keys are a ConfigError naming
        them and the valid ones."""
        _unknown_keys(values, cls.__dataclass_fields__, "config key")
        return cls(**values)

    def with_overrides(self, overrides: Mapping[str, Any] | None) -> Config:
        """This config with `overrides` (some of its fields by name, in its units) in place of
        its values; unknown keys are a ConfigError naming them. None or empty: itself."""
        if not overrides:
            return self
        return self.from_dict({**self.to_dict(), **overrides})

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
        """The same settings with every length (the schema's, see the attributes) multiplied
        by `factor`."""
        real = not isinstance(factor, bool) and isinstance(
            factor, int | float | np.integer | np.floating
        )
        try:
            ok = real and factor > 0 and math.isfinite(factor)
        except OverflowError:  # an int beyond float range
            ok = False
        if not ok:
            raise InputError(f"scale factor must be a finite number > 0, got {factor!r}")
        return replace(self, **{name: getattr(self, name) * factor for name in _LENGTHS})


def _attributes(schema: Mapping[str, Mapping[str, Any]] = _SCHEMA) -> str:
    """The numpydoc "Attributes" section of `Config` (or of another struct the core declares,
    from its `schema`), from the Rust fields' docs."""
    lines = ["", "", "    Attributes", "    ----------"]
    for name, field in schema.items():
        if field["kind"] == "choice":
            kind = "{" + ", ".join(f'"{c}"' for c in field["choices"]) + "}"
        else:
            kind = {"float": "float", "count": "int", "bool": "bool"}[field["kind"]]
        kind += " or None" if field["optional"] else ""
        kind += ", a length" if field["length"] else ""
        lines.append(f"    {name} : {kind}")
        # rustdoc links name Rust items: [`Pruning`] -> `pointclm::Pruning` (Rust)
        doc = re.sub(r"\[`(?:crate::)?([^`]+)`\]", r"`pointclm::\1` (Rust)", field["doc"])
        lines += [f"        {line.strip()}" for line in doc.strip().splitlines()]
    return "\n".join(lines) + "\n"


if Config.__doc__ is not None:  # None under python -OO
    Config.__doc__ = Config.__doc__.rstrip() + _attributes()

"""`SceneRules`: the scene-wide rules of `register_point_clouds`, the typed Python view of the
Rust `pointclm::scene::SceneRules`.

The Rust struct is the one definition of the fields: their names, defaults, ranges and the
reasons for them reach Python through `_core.scene_rules_schema()`. Here each field is a typed
line whose default is read from that schema; the checks and the "Attributes" section of the
docstring are derived from it, and a test fails if the lines and the schema drift apart.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from . import _core
from .config import _attributes, _checked, _unknown_keys
from .errors import ConfigError

__all__ = ["SCENE_DEFAULTS", "SceneRules"]

#: The Rust core's description of every field of `SceneRules`, by name, in declaration order.
_SCHEMA: dict[str, dict[str, Any]] = {f["name"]: f for f in _core.scene_rules_schema()}


def _default(name: str) -> Any:
    """The Rust default of field `name` (a KeyError at import for a name the core lacks)."""
    return _SCHEMA[name]["default"]


@dataclass(frozen=True)
class SceneRules:
    """The scene-wide rules of :func:`pointclm.register_point_clouds`, checked by the Rust core
    when constructed: the voxel's floor, stray points, peeling, heaps, turned alternatives and
    the final ranking. Every field is unitless (a share, a count, a ratio, a number of voxels or
    of model diagonals, or degrees). Pass ``scene=SceneRules(...)`` or a dict of some fields to
    `register_point_clouds`, or ``--scene NAME=VALUE`` on the command line. The acceptance rules
    of one pose are :func:`pointclm.refinement.refine_poses`' arguments.
    """

    voxels_per_diagonal: float = _default("voxels_per_diagonal")
    min_voxel_spacings: float = _default("min_voxel_spacings")
    min_voxel_noises: float = _default("min_voxel_noises")
    noise_scale_voxels: float = _default("noise_scale_voxels")
    stray_neighbours: int = _default("stray_neighbours")
    max_stray_share: float = _default("max_stray_share")
    scene_extent: float = _default("scene_extent")
    peel_radius_voxels: float = _default("peel_radius_voxels")
    max_peel_rounds: int = _default("max_peel_rounds")
    heap_empty_rounds: int = _default("heap_empty_rounds")
    heap_min_copies: int = _default("heap_min_copies")
    heap_window: float = _default("heap_window")
    heap_voted_poses: int = _default("heap_voted_poses")
    voted_min_relative_fitness: float = _default("voted_min_relative_fitness")
    screen_points: int = _default("screen_points")
    peel_cluster_level: float = _default("peel_cluster_level")
    min_flip_change: float = _default("min_flip_change")
    min_flip_change_by_fitness: float = _default("min_flip_change_by_fitness")
    max_quarter_turn_change: float = _default("max_quarter_turn_change")
    flip_evidence_ratio: float = _default("flip_evidence_ratio")
    flip_evidence_sigmas: float = _default("flip_evidence_sigmas")
    scene_turn_deg: float = _default("scene_turn_deg")
    max_scene_turns: int = _default("max_scene_turns")
    max_relative_visible_rmse: float = _default("max_relative_visible_rmse")
    min_poses_to_compare: int = _default("min_poses_to_compare")
    min_planar_share: float = _default("min_planar_share")
    max_face_poses: int = _default("max_face_poses")

    def __post_init__(self) -> None:
        for name in _SCHEMA:
            value = _checked(name, getattr(self, name), _SCHEMA, "scene parameter")
            object.__setattr__(self, name, value)
        # The Rust core is the single source of truth for valid ranges.
        _core.validate_scene_rules(self.to_dict())

    def to_dict(self) -> dict[str, Any]:
        """Fields as a plain dict (what the Rust core receives)."""
        return {name: getattr(self, name) for name in self.__dataclass_fields__}

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> SceneRules:
        """SceneRules from a dict of some of its fields; unknown keys are a ConfigError naming
        them and the valid ones."""
        _unknown_keys(values, cls.__dataclass_fields__, "scene rule")
        return cls(**values)

    @classmethod
    def resolve(cls, value: SceneRules | Mapping[str, Any] | None) -> SceneRules:
        """`value` as SceneRules: itself, the defaults with a dict's fields, or the defaults
        (None); anything else is a ConfigError."""
        if value is None:
            return SCENE_DEFAULTS
        if isinstance(value, SceneRules):
            return value
        if isinstance(value, Mapping):
            return cls.from_dict(value)
        raise ConfigError(
            f"scene must be a pointclm.SceneRules, a dict or None, got {type(value).__name__}"
        )


if SceneRules.__doc__ is not None:  # None under python -OO
    SceneRules.__doc__ = SceneRules.__doc__.rstrip() + _attributes(_SCHEMA)

#: The defaults.
SCENE_DEFAULTS = SceneRules()

"""The scene's voxel, and the warning of a viewpoint the scan disputes. The scan's sensor,
viewpoint and description are the core's (``pointclm::scene::describe_scan``)."""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import ArrayLike

from .. import _core
from .. import preprocessing as pp
from ..errors import ViewpointDisagreementWarning
from ..scene_rules import SceneRules
from .results import _xyz


def default_voxel_size(
    model_points: ArrayLike, scan_points: ArrayLike | None = None, scene: SceneRules | None = None
) -> float:
    """The model's bounding-box diagonal over ``voxels_per_diagonal`` (40); with
    `scan_points`, at least ``min_voxel_spacings`` times the scan's point spacing
    (:func:`pointclm.preprocessing.point_spacing`) and ``min_voxel_noises`` times its noise
    (:func:`pointclm.preprocessing.noise_level`), the rules of `scene`
    (:class:`pointclm.SceneRules`). Computed by the core
    (``pointclm::scene::voxel::default_voxel_size``), as its own pipeline does."""
    rules = SceneRules.resolve(scene).to_dict()
    model = pp.as_points(model_points, "model_points")
    scan = None if scan_points is None else pp.as_points(scan_points, "scan_points")
    return float(_core.default_voxel_size(model, scan, rules))


def _voxel_size(
    src: np.ndarray, tgt: np.ndarray, voxel_size: float | None, scene: SceneRules
) -> float:
    """The given voxel, checked, or the clouds' default (:func:`default_voxel_size`)."""
    voxel = (
        default_voxel_size(src, tgt, scene)
        if voxel_size is None
        else pp.as_positive(voxel_size, "voxel_size")
    )
    if not voxel > 0:
        raise ValueError("the source model has zero extent: give voxel_size")
    return voxel


def warn_disputed(view: tuple[float, float, float], stated_by: str, stacklevel: int) -> None:
    """The :class:`pointclm.errors.ViewpointDisagreementWarning` of a disputed viewpoint
    (`stated_by` the scan, in those words, or "" for the caller's), attributed to the frame
    `stacklevel` up."""
    source = stated_by or "the viewpoint given"
    warnings.warn(
        f"the scan does not look like one view from {source} {_xyz(view)}: some of its "
        "points lie behind a surface that covers them all round as seen from there (a scan "
        "merged from several views, in another frame, or a wrong position). Verification "
        "uses it anyway; pass the sensor's position in the scan's frame, or viewpoint=None "
        "to let the scan decide.",
        ViewpointDisagreementWarning,
        stacklevel=stacklevel,
    )

"""Several part types in one scan: :func:`register_models`.

Each model's copies are found on its own (its own voxel, descriptors and rules), then judged
together in the core (``pointclm::scene::judge_jointly``): a scan region one model's copy
explains is not handed to another model's copy, and where two compete, the one that explains
more of the scan, with less of it where the sensor saw free space, wins.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .. import _core
from .. import preprocessing as pp
from ..refinement import MAX_SHARED
from ..registration import as_threads
from .results import CloudInstance, PointCloudRegistration
from .scans import read_scan

__all__ = ["register_models"]


def register_models(
    models: Sequence[ArrayLike | str | os.PathLike[str]],
    target: ArrayLike | str | os.PathLike[str],
    *,
    symmetry: Any = None,
    num_threads: int | None = None,
    **options: Any,
) -> list[PointCloudRegistration]:
    """Find every copy of each of `models` in `target`, judged together: one result per model,
    in order.

    Each model runs :func:`pointclm.register_point_clouds` with `options` (the same for every
    model; its voxel is each model's own unless ``voxel_size`` is given), then every copy of
    every model, best first, is kept unless more than half the scan points it explains are
    explained by a copy kept before it ("best": the scan points it explains times one minus
    its contradiction). A small box's pose on the top of a long box explains part of what the
    long box's pose does, and loses to it. The ambiguous (sliding) poses are judged after
    every copy and never displace one. `symmetry` is one value for every model or a list, one
    per model.
    """
    from ..point_clouds import register_point_clouds

    if isinstance(models, (str, os.PathLike, np.ndarray)) or len(models) == 0:
        raise ValueError("models must be a non-empty list of models (arrays or files)")
    per_model = symmetry if isinstance(symmetry, list) else [symmetry] * len(models)
    if len(per_model) != len(models):
        raise ValueError(f"{len(per_model)} symmetries for {len(models)} models: give one each")
    # Read once; the viewpoint the scan states (a file's, an organised frame's origin) is
    # passed on as given.
    given = options.pop("viewpoint", None)
    read = read_scan(target, None if given is None else pp.as_point(given, "viewpoint"))
    scan, options["viewpoint"] = read.points, read.viewpoint
    found = [
        register_point_clouds(m, scan, symmetry=s, num_threads=num_threads, **options)
        for m, s in zip(models, per_model, strict=True)
    ]
    finest = min(found, key=lambda r: r.voxel_size)
    judged = [
        (
            np.ascontiguousarray(r.source_points, dtype=np.float64),
            1.5 * r.voxel_size,
            *_poses(r.instances),
            *_poses(r.ambiguous),
        )
        for r in found
    ]
    copies, ambiguous = _core.judge_jointly(
        np.ascontiguousarray(finest.target_points, dtype=np.float64),
        judged,
        MAX_SHARED,
        num_threads=as_threads(num_threads),
    )
    return [
        replace(
            r,
            instances=[c for c, keep in zip(r.instances, ck, strict=True) if keep],
            ambiguous=[c for c, keep in zip(r.ambiguous, ak, strict=True) if keep],
        )
        for r, ck, ak in zip(found, copies, ambiguous, strict=True)
    ]


def _poses(instances: list[CloudInstance]) -> tuple[np.ndarray, np.ndarray]:
    """The poses (K, 4, 4) and their contradictions (NaN: not judged)."""
    if not instances:
        return np.zeros((0, 4, 4)), np.zeros(0)
    poses = np.stack([c.transformation for c in instances])
    return np.ascontiguousarray(poses, dtype=np.float64), np.array(
        [c.contradiction for c in instances], dtype=np.float64
    )

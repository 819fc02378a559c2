"""Which local descriptor point clouds are matched by: FPFH, the learned one, or both.

``register_point_clouds(descriptor=...)`` and ``pointclm register --descriptor`` take a name
or the path of a descriptor file:

- ``"auto"`` (the default): decided by the model's shape, with the rule that switches face
  proposals on: FPFH alone for a model with at least ``scene.min_planar_share`` (half) of its
  points in large flat faces (boxes, brackets), ``"fpfh+learned"`` for any other (organic and
  curved CAD parts). On a flat face every neighbourhood looks alike to any local descriptor,
  and the learned one only adds look-alikes there; on curved parts it finds most of the true
  matches FPFH misses. The result's ``descriptor`` says which ran;
- ``"fpfh"``: Open3D's FPFH over 5 voxels, no training, the reference every learned
  descriptor is measured against;
- ``"learned"``: the descriptor network shipped with the package (``weights/descriptor``),
  trained contrastively on partial views of the validation models and procedural shapes
  (``pointclm train-descriptor``); see the model card in BENCHMARKS.md for where it wins and
  where it does not;
- ``"fpfh+learned"``: both side by side, each of unit length, so a match must look alike to
  both: nearly all the true matches the learned one finds, fewer of its look-alikes;
- a path to a ``.safetensors`` file written by ``pointclm train-descriptor`` (its ``.json``
  beside it), or ``"fpfh+"`` or ``"auto+"`` and such a path.

The learned descriptor runs in the Rust core (no torch at run time), over the same points and
oriented normals FPFH was computed on.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from .errors import InputError

__all__ = [
    "DESCRIPTORS",
    "described_by",
    "descriptor_choice",
    "descriptor_weights",
    "learned_descriptors",
]

#: Names ``descriptor=`` accepts besides a path.
DESCRIPTORS: tuple[str, ...] = ("auto", "fpfh", "learned", "fpfh+learned")
_SHIPPED = Path(__file__).parent / "weights" / "descriptor.safetensors"


def descriptor_weights(descriptor: str | os.PathLike[str] | None) -> str | None:
    """The descriptor file `descriptor` names (None: FPFH).

    Raises InputError for an unknown name or a path that is not a ``.safetensors`` file with
    its ``.json`` beside it.
    """
    if descriptor is None or (isinstance(descriptor, str) and descriptor == "fpfh"):
        return None
    if isinstance(descriptor, str) and descriptor == "learned":
        path = _SHIPPED
    elif isinstance(descriptor, str | os.PathLike):
        path = Path(descriptor)
    else:
        raise InputError(
            f"descriptor must be one of {DESCRIPTORS} or a path to a descriptor file, "
            f"got {descriptor!r}"
        )
    if path.suffix != ".safetensors" or not path.is_file():
        raise InputError(
            f"descriptor {str(descriptor)!r} is neither one of {DESCRIPTORS} nor an existing "
            ".safetensors file (written by `pointclm train-descriptor`)"
        )
    if not path.with_suffix(".json").is_file():
        raise InputError(
            f"descriptor file {path} has no {path.with_suffix('.json').name} beside it"
        )
    return str(path)


def descriptor_choice(descriptor: str | os.PathLike[str] | None) -> tuple[str | None, str]:
    """What `descriptor` names: the learned descriptor's file (None: FPFH alone) and how it
    is used, as the core takes it: ``"learned"`` (alone), ``"fpfh+learned"`` (beside FPFH:
    ``"fpfh+learned"``, ``"fpfh+PATH"``) or ``"auto"`` (decided by the model's shape:
    ``"auto"``, ``"auto+PATH"``).

    Raises InputError as :func:`descriptor_weights` does, and for ``"fpfh+fpfh"``.
    """
    if isinstance(descriptor, str) and descriptor == "auto":
        descriptor = "auto+learned"
    for kind in ("fpfh", "auto"):
        if isinstance(descriptor, str) and descriptor.startswith(kind + "+"):
            weights = descriptor_weights(descriptor.removeprefix(kind + "+"))
            if weights is None:
                raise InputError(
                    f'"{kind}+" must be followed by a learned descriptor: "{kind}+learned"'
                )
            return weights, "fpfh+learned" if kind == "fpfh" else "auto"
    weights = descriptor_weights(descriptor)
    return weights, "fpfh" if weights is None else "learned"


def learned_descriptors(
    points: ArrayLike,
    normals: ArrayLike,
    voxel_size: float,
    descriptor: str | os.PathLike[str] = "learned",
    num_threads: int | None = None,
) -> np.ndarray:
    """Learned descriptors (N, D), unit length, of `points` with their unit `normals`, for
    clouds described at `voxel_size` (the neighbourhood radius is the network's, in voxels)."""
    from . import _core
    from .preprocessing import as_points

    path = descriptor_weights(descriptor)
    if path is None:
        raise InputError("learned_descriptors needs a learned descriptor, not 'fpfh'")
    pts, nrm = as_points(points, "points"), as_points(normals, "normals")
    return _core.learned_descriptors(pts, nrm, voxel_size, path, num_threads)


def described_by(
    descriptor: str | os.PathLike[str],
    points: ArrayLike,
    normals: ArrayLike,
    fpfh: ArrayLike,
    voxel_size: float,
    num_threads: int | None = None,
) -> np.ndarray:
    """The descriptors `descriptor` names for a cloud already described by FPFH (`points`,
    oriented `normals`, `fpfh` as :func:`pointclm.preprocessing.describe` returns them), as
    ``register_point_clouds(descriptor=...)`` matches them: FPFH as given, the learned ones,
    or, for ``"fpfh+..."``, FPFH scaled to unit length beside the learned ones."""
    weights, kind = descriptor_choice(descriptor)
    if kind == "auto":
        raise InputError(
            f"descriptor {str(descriptor)!r} is decided per model by register_point_clouds; "
            'name the one to use here: "fpfh", "learned" or "fpfh+learned"'
        )
    with_fpfh = kind == "fpfh+learned"
    f = np.asarray(fpfh, dtype=np.float64)
    if weights is None:
        return f
    learned = learned_descriptors(points, normals, voxel_size, weights, num_threads)
    if not with_fpfh:
        return learned
    norm = np.linalg.norm(f, axis=1, keepdims=True)
    unit = np.divide(f, norm, out=np.zeros_like(f), where=norm > 0)
    return np.hstack([unit, learned])

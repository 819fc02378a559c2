"""Per-correspondence cues beyond coordinates, for networks that take them.

A network's weights say which inputs it needs (``architecture.inputs`` in their JSON):

- ``"normals"``: the unit surface normals at both ends of each correspondence, (N, 6) rows
  (source normal | target normal), each rotated with its side's coordinates. The network
  takes them as channels and its attention multiplies the normal term of
  :meth:`pointclm.register`'s ``normals=`` into ``beta``, so that pairs are compared by the
  angle between their normals too.
- ``"similarity"``: how alike the two descriptors of each match are, (N,) in (0, 1]:
  ``m / (d + m)`` for descriptor distance ``d`` and ``m`` the median distance over the
  correspondences given, so 1 for identical descriptors and 1/2 at the median. Relative to
  the median because FPFH distances scale with the sampling density and the noise of a
  scan, which a network trained on other scans has not seen.

The packed layout a torch network reads (:func:`pack`) is ``[source xyz, target xyz,
source normal, target normal (if "normals"), similarity (if "similarity")]``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .errors import InputError

__all__ = ["INPUTS", "check_inputs", "input_channels", "needed", "pack", "similarity"]

#: The inputs a network may take besides the 6 coordinates, in their packed order.
INPUTS: tuple[str, ...] = ("normals", "similarity")


def check_inputs(inputs: Sequence[str]) -> tuple[str, ...]:
    """`inputs` validated and in canonical order; ValueError naming an unknown one."""
    unknown = [i for i in inputs if i not in INPUTS]
    if unknown or isinstance(inputs, str):
        raise ValueError(f"unknown network inputs {unknown or inputs!r}; choose from {INPUTS}")
    return tuple(i for i in INPUTS if i in inputs)


def input_channels(inputs: Sequence[str]) -> int:
    """Columns of the packed input: 6 coordinates, 6 for normals, 1 for similarity."""
    inputs = check_inputs(inputs)
    return 6 + 6 * ("normals" in inputs) + ("similarity" in inputs)


def similarity(distance: Any) -> np.ndarray:
    """Descriptor distances -> similarities ``m / (d + m)`` in (0, 1], ``m`` their median
    (see the module documentation). All-zero distances give 1 everywhere."""
    d = np.asarray(distance, dtype=np.float64).reshape(-1)
    if len(d) == 0:
        return d.copy()
    if not np.isfinite(d).all() or (d < 0).any():
        raise InputError("descriptor distances must be finite and >= 0")
    m = float(np.median(d))
    if m <= 0:
        # More than half the matches are exact: scale by the mean instead, or all are equal.
        m = float(d.mean()) or 1.0
    return m / (d + m)


def pack(
    corr: np.ndarray,
    inputs: Sequence[str],
    normals: Any = None,
    similarity: Any = None,
) -> np.ndarray:
    """(N, 6) coordinates and the cues the `inputs` name -> the (N, C) float64 rows a torch
    network reads. Cues the network does not take are ignored; a missing one raises
    :class:`pointclm.errors.InputError` naming it."""
    cues = needed(inputs, len(corr), normals, similarity)
    cols = [np.asarray(corr, dtype=np.float64)]
    if "normals" in cues:
        cols.append(_unit_pairs(cues["normals"]))
    if "similarity" in cues:
        cols.append(cues["similarity"][:, None])
    return np.ascontiguousarray(np.hstack(cols))


def needed(inputs: Sequence[str], n: int, normals: Any, similarity: Any) -> dict[str, np.ndarray]:
    """The cues `inputs` name, checked for `n` correspondences (float64), by input name;
    :class:`pointclm.errors.InputError` for a missing or malformed one."""
    inputs = check_inputs(inputs)
    out = {}
    if "normals" in inputs:
        out["normals"] = _required(normals, "normals", (n, 6))
    if "similarity" in inputs:
        out["similarity"] = _required(similarity, "similarity", (n,))
    return out


def _required(value: Any, name: str, shape: tuple[int, ...]) -> np.ndarray:
    if value is None:
        what = "(N, 6) surface normals at both ends" if name == "normals" else "(N,) similarities"
        raise InputError(
            f"this network takes {name} ({what}); pass {name}= with the correspondences "
            "(register_point_clouds computes them from the clouds)"
        )
    a = np.asarray(value, dtype=np.float64)
    if a.shape != shape:
        raise InputError(f"{name} must have shape {shape}, got {a.shape}")
    if not np.isfinite(a).all():
        raise InputError(f"{name} must be finite")
    return a


def _unit_pairs(normals: np.ndarray) -> np.ndarray:
    pairs = normals.reshape(-1, 2, 3)
    norm = np.linalg.norm(pairs, axis=2, keepdims=True)
    if (norm == 0).any():
        raise InputError("normals must be non-zero vectors")
    return (pairs / norm).reshape(-1, 6)

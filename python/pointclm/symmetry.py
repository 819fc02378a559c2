"""A model's proper (rotation) symmetries: BOP's ``models_info`` form read and checked,
detection from the model's points, and one canonical pose among equivalent ones.

A symmetry ``S`` (4 x 4, ``S model = model``) makes ``T`` and ``T @ S`` the same pose of the
part: registration cannot tell them apart, and neither should a score. Declare them as BOP
writes them in ``models_info.json`` (one entry passes as it is)::

    {"symmetries_discrete": [[16 numbers, row-major 4 x 4], ...],
     "symmetries_continuous": [{"axis": [x, y, z], "offset": [x, y, z]}, ...]}

Translations and offsets are in the **model's own units**: BOP writes millimetres, so a model
in metres needs ``from_bop(entry, scale=0.001)``. Or detect them: :func:`detect` (``"auto"``
where a function takes ``symmetry=``).

The group is closed under composition (the identity first; declared generators are enough),
and its canonical pose is the one whose rotation is nearest the identity
(:meth:`Symmetry.canonical`): every pose equivalent to another maps to the same one.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from . import _core

__all__ = ["Symmetry", "as_core", "canonical_for", "detect", "from_bop", "resolve"]


@dataclass(frozen=True)
class Symmetry:
    """Proper symmetries of a model, checked by the core.

    Attributes
    ----------
    discrete : numpy.ndarray
        (S, 4, 4) the finite group, identity first.
    axes, offsets : numpy.ndarray
        (A, 3) unit directions and points of the axes of continuous symmetry (several: they
        meet at one point, and every rotation about it is a symmetry).
    tolerance : float or None
        The tolerance detection used (model units); None for declared symmetries.
    """

    discrete: np.ndarray
    axes: np.ndarray
    offsets: np.ndarray
    tolerance: float | None = None

    @classmethod
    def _from_core(cls, d: Mapping[str, Any]) -> Symmetry:
        tol = d.get("tolerance")
        return cls(
            np.asarray(d["discrete"]),
            np.asarray(d["axes"]).reshape(-1, 3),
            np.asarray(d["offsets"]).reshape(-1, 3),
            None if tol is None else float(tol),
        )

    @classmethod
    def none(cls) -> Symmetry:
        """The identity alone."""
        return cls(np.eye(4)[None], np.empty((0, 3)), np.empty((0, 3)))

    @property
    def order(self) -> int | None:
        """The number of symmetries, None when infinite (continuous)."""
        return None if len(self.axes) else len(self.discrete)

    @property
    def is_trivial(self) -> bool:
        return len(self.discrete) == 1 and not len(self.axes)

    def as_core(self) -> dict[str, np.ndarray]:
        """The dict the core takes."""
        return {"discrete": self.discrete, "axes": self.axes, "offsets": self.offsets}

    def canonical(self, poses: ArrayLike) -> np.ndarray:
        """Each of `poses` ((4, 4) or (K, 4, 4) ``T_target_source``) as its canonical
        representative: among ``T @ S`` for every symmetry ``S``, the one whose rotation is
        nearest the identity (largest trace; about a continuous axis the angle in closed
        form; ties to the first group element). Equivalent poses give one pose (to rounding)."""
        arr = np.asarray(poses, dtype=np.float64)
        single = arr.shape == (4, 4)
        out = _core.canonical_poses(arr[None] if single else arr, self.as_core())
        return out[0] if single else out

    def to_bop(self, scale: float = 1.0) -> dict[str, Any]:
        """The ``models_info`` form (without the identity), translations times `scale`
        (1000 for a model in metres to BOP's millimetres)."""
        disc = []
        for s in self.discrete[1:]:
            m = np.array(s, dtype=np.float64)
            m[:3, 3] *= scale
            disc.append(m.reshape(16).tolist())
        cont = [
            {"axis": a.tolist(), "offset": (o * scale).tolist()}
            for a, o in zip(self.axes, self.offsets, strict=True)
        ]
        return {"symmetries_discrete": disc, "symmetries_continuous": cont}

    def __repr__(self) -> str:
        kind = f"{len(self.discrete)} discrete"
        if len(self.axes):
            kind += f", {len(self.axes)} continuous axis(es)"
        return f"Symmetry({kind})"


def _finite(values: ArrayLike, what: str, size: int) -> np.ndarray:
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what} must be numbers, got {values!r}") from e
    if arr.size != size:
        raise ValueError(f"{what} must hold {size} numbers, got {arr.size} (shape {arr.shape})")
    if not np.isfinite(arr).all():
        raise ValueError(f"{what} has a non-finite value (NaN or inf): {arr.ravel().tolist()}")
    return arr


def _discrete(entries: Any, scale: float) -> np.ndarray:
    """BOP's ``symmetries_discrete``: each 16 numbers (row-major) or a 4 x 4 array."""
    if isinstance(entries, np.ndarray) and entries.ndim == 3:
        entries = list(entries)
    if not isinstance(entries, Sequence | np.ndarray) or isinstance(entries, str):
        raise ValueError(f"symmetries_discrete must be a list of 4 x 4 transforms, got {entries!r}")
    out = np.empty((len(entries), 4, 4))
    for i, e in enumerate(entries):
        m = _finite(e, f"symmetries_discrete[{i}]", 16).reshape(4, 4).copy()
        if not np.allclose(m[3], [0, 0, 0, 1]):
            raise ValueError(
                f"symmetries_discrete[{i}]: a rigid transform's last row is 0 0 0 1, got "
                f"{m[3].tolist()}"
            )
        r = m[:3, :3]
        deviation = float(np.linalg.norm(r.T @ r - np.eye(3)))
        if deviation > _core.MAX_ROTATION_DEVIATION or np.linalg.det(r) <= 0:
            raise ValueError(
                f"symmetries_discrete[{i}]: its 3 x 3 block is not a rotation "
                f"(||R^T R - I|| = {deviation:.2e}, det = {np.linalg.det(r):.3g}); a proper "
                "symmetry is a rotation, orthonormal with determinant +1"
            )
        m[:3, 3] *= scale
        out[i] = m
    return out


def _continuous(entries: Any, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """BOP's ``symmetries_continuous``: each ``{"axis": 3 numbers, "offset": 3 numbers}``."""
    if not isinstance(entries, Sequence) or isinstance(entries, str):
        raise ValueError(
            'symmetries_continuous must be a list of {"axis": [x, y, z], "offset": [x, y, z]}'
            f", got {entries!r}"
        )
    axes, offsets = np.empty((len(entries), 3)), np.empty((len(entries), 3))
    for i, e in enumerate(entries):
        if not isinstance(e, Mapping) or "axis" not in e:
            raise ValueError(
                f'symmetries_continuous[{i}] must be {{"axis": [x, y, z], "offset": [x, y, z]}}'
                f", got {e!r}"
            )
        axes[i] = _finite(e["axis"], f"symmetries_continuous[{i}].axis", 3)
        if not np.linalg.norm(axes[i]) > 0:
            raise ValueError(f"symmetries_continuous[{i}].axis must not be zero")
        offsets[i] = _finite(e.get("offset", [0, 0, 0]), f"symmetries_continuous[{i}].offset", 3)
        offsets[i] *= scale
    return axes, offsets


def from_bop(info: Mapping[str, Any], scale: float = 1.0) -> Symmetry:
    """The symmetries of one ``models_info`` entry (other keys, e.g. ``diameter``, are
    ignored; none of the two keys: no symmetry).

    Parameters
    ----------
    info : mapping
        ``symmetries_discrete`` (list of 16 numbers, row-major, or 4 x 4 arrays) and/or
        ``symmetries_continuous`` (list of ``{"axis", "offset"}``).
    scale : float
        Multiplies translations and offsets into the model's units (0.001: BOP's mm for a
        model in metres).

    Raises
    ------
    ValueError
        Wrong lengths, non-finite values, a block that is not a rotation, a zero axis,
        axes that do not meet, or transforms generating no finite group.
    """
    if not isinstance(info, Mapping):
        raise ValueError(f"a symmetry must be a models_info mapping, got {type(info).__name__}")
    if not (isinstance(scale, int | float) and math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive finite number, got {scale!r}")
    disc = _discrete(info.get("symmetries_discrete", []), float(scale))
    axes, offsets = _continuous(info.get("symmetries_continuous", []), float(scale))
    return Symmetry._from_core(_core.symmetry_group(disc, axes, offsets))


def detect(
    points: ArrayLike, tolerance: float | None = None, *, num_threads: int | None = None
) -> Symmetry:
    """The proper symmetries of a model's points (``pointclm::symmetry::detect_symmetries``):
    rotations about its principal axes (n-fold, continuous, and half turns across an axis of
    equal perpendicular variances) that put at least 99 % of its points within `tolerance`
    of the model, refined by ICP of the model onto itself, closed into a group.

    Parameters
    ----------
    points : array_like
        (N, 3) the model (a complete object).
    tolerance : float, optional
        In the model's units; None: 3 median nearest-neighbour spacings of the points.
    """
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64))
    return Symmetry._from_core(_core.detect_symmetries(pts, tolerance, num_threads=num_threads))


def resolve(symmetry: Any) -> Symmetry | str | None:
    """`symmetry=` as the functions take it, checked: None; ``"auto"`` (detected later, on
    the model); a :class:`Symmetry`; a ``models_info`` mapping (:func:`from_bop`); or
    (S, 4, 4) transforms."""
    if symmetry is None or isinstance(symmetry, Symmetry):
        return symmetry
    if isinstance(symmetry, str):
        if symmetry != "auto":
            raise ValueError(
                f'symmetry must be "auto", a models_info entry or None, got {symmetry!r}'
            )
        return symmetry
    if isinstance(symmetry, Mapping):
        return from_bop(symmetry)
    try:
        arr = np.asarray(symmetry, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"symmetry must be a models_info entry, got {type(symmetry)}") from e
    if arr.ndim != 3 or arr.shape[1:] != (4, 4):
        raise ValueError(f"symmetry as an array must be (S, 4, 4) transforms, got {arr.shape}")
    return from_bop({"symmetries_discrete": list(arr)})


def canonical_for(
    symmetry: Any, model: ArrayLike, poses: ArrayLike, num_threads: int | None = None
) -> np.ndarray:
    """`poses` (K, 4, 4) made canonical by `symmetry` as :func:`resolve` takes it (``"auto"``:
    detected on `model`; declared: checked against `model`'s centroid, whose shift by more
    than a tenth of its diagonal means other units)."""
    declared = resolve(symmetry)
    if declared is None:
        return np.asarray(poses, dtype=np.float64)
    pts = np.ascontiguousarray(np.asarray(model, dtype=np.float64))
    spec = declared.as_core() if isinstance(declared, Symmetry) else declared
    found = Symmetry._from_core(
        _core.resolve_model_symmetry(pts, pts, spec, num_threads=num_threads)
    )
    return found.canonical(np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4))


def as_core(symmetry: Any) -> str | dict[str, np.ndarray] | None:
    """`symmetry` as the core takes it (:func:`resolve`d): None, "auto" or its dict."""
    declared = resolve(symmetry)
    return declared.as_core() if isinstance(declared, Symmetry) else declared

"""Errors between poses: rotation and translation errors, and their smallest over a part's
proper symmetries (discrete ones, and the angle about a continuous axis in closed form); the
average distance of the model's points (ADD) over the symmetry group. :mod:`pointclm.metrics`
re-exports them and builds its scene scores on them."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["add_s", "rotation_error_deg", "symmetric_errors", "translation_error"]


def rotation_error_deg(R_pred: ArrayLike, R_gt: ArrayLike) -> np.ndarray:
    """Angle of the relative rotation, in degrees.

    Parameters
    ----------
    R_pred, R_gt : numpy.ndarray
        (..., 3, 3) rotations (broadcast against each other).

    Returns
    -------
    numpy.ndarray
        ``arccos(clip((tr(R_pred^T R_gt) - 1) / 2, -1, 1))`` in degrees, shape (...).
    """
    a = np.asarray(R_pred, dtype=np.float64)
    b = np.asarray(R_gt, dtype=np.float64)
    trace = np.einsum("...ij,...ij->...", a, b)  # tr(A^T B)
    return np.degrees(np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0)))


def translation_error(t_pred: ArrayLike, t_gt: ArrayLike) -> np.ndarray:
    """Euclidean distance between translations.

    Parameters
    ----------
    t_pred, t_gt : numpy.ndarray
        (..., 3) translations (broadcast against each other).

    Returns
    -------
    numpy.ndarray
        ``||t_pred - t_gt||``, shape (...).
    """
    diff = np.asarray(t_pred, dtype=np.float64) - np.asarray(t_gt, dtype=np.float64)
    return np.linalg.norm(diff, axis=-1)


def _as_poses(poses: ArrayLike) -> np.ndarray:
    arr = np.asarray(poses, dtype=np.float64)
    if arr.size == 0:
        return np.empty((0, 4, 4))
    if arr.shape[-2:] != (4, 4):
        raise ValueError(f"expected poses of shape (K, 4, 4), got {arr.shape}")
    return arr.reshape(-1, 4, 4)


def _as_symmetries(symmetries: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(S, 4, 4) discrete symmetries, (A, 3) continuous axes and (A, 3) their offsets: from
    None (the identity), a :class:`pointclm.symmetry.Symmetry`, a BOP ``models_info`` entry
    (:func:`pointclm.symmetry.from_bop`) or (S, 4, 4) transforms (taken as given)."""
    none = np.empty((0, 3))
    if symmetries is None:
        return np.eye(4)[None], none, none
    if isinstance(symmetries, Mapping):
        from .symmetry import from_bop

        symmetries = from_bop(symmetries)
    if hasattr(symmetries, "discrete") and hasattr(symmetries, "axes"):
        return symmetries.discrete, symmetries.axes, symmetries.offsets
    sym = np.asarray(symmetries, dtype=np.float64)
    if sym.ndim != 3 or sym.shape[1:] != (4, 4) or len(sym) == 0:
        raise ValueError(f"symmetries must be (S, 4, 4) transforms, S >= 1, got shape {sym.shape}")
    if not np.isfinite(sym).all():
        raise ValueError("symmetries must be finite")
    return sym, none, none


def _skew(a: np.ndarray) -> np.ndarray:
    x, y, z = a
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def _fixed_point(disc: np.ndarray, axes: np.ndarray, offsets: np.ndarray) -> np.ndarray | None:
    """The point every symmetry leaves in place (least norm: the origin when the symmetries
    have no translation), or None when there is none (transforms that are not a group)."""
    rows = [s[:3, :3] - np.eye(3) for s in disc] + [np.eye(3) - np.outer(a, a) for a in axes]
    rhs = [-s[:3, 3] for s in disc]
    rhs += [(np.eye(3) - np.outer(a, a)) @ o for a, o in zip(axes, offsets, strict=True)]
    lhs, b = np.concatenate(rows), np.concatenate(rhs)
    c = np.linalg.lstsq(lhs, b, rcond=None)[0]
    scale = 1.0 + float(np.abs(b).max(initial=0.0)) + float(np.abs(c).max())
    return c if np.abs(lhs @ c - b).max(initial=0.0) <= 1e-6 * scale else None


def _equivalent_errors(
    p: np.ndarray, g: np.ndarray, symmetries: Any
) -> tuple[np.ndarray, np.ndarray]:
    """(P, G, S) rotation (degrees) and translation errors of each prediction against each
    truth made equivalent by each discrete symmetry ``D``. With one continuous axis, the
    truth is ``gt C(theta) D`` at the angle about the axis of least rotation error, in closed
    form (``tr(R_p^T R_g C(theta) R_D)`` is ``c + A cos(theta) + B sin(theta)``); with several
    (every rotation about their point), the rotation error is 0.

    The translation error is that of the point every symmetry leaves in place, ``||T_p c -
    T_g c||`` (the same for every equivalent truth): the origin, so the usual ``||t_p -
    t_g||``, when the symmetries have no translation. Why not the origin's always: with a
    symmetry about another point, the origin's error changes from one equivalent pose to
    another unless the rotations agree. Transforms leaving no point in place (not a group)
    get the origin's error at each."""
    disc, axes, offsets = _as_symmetries(symmetries)
    axes = np.asarray(axes, dtype=np.float64).reshape(-1, 3)
    axes = axes / np.linalg.norm(axes, axis=1, keepdims=True) if len(axes) else axes
    eq = g[:, None] @ disc[None]  # (G, S, 4, 4)
    if len(axes) == 0:
        re = rotation_error_deg(p[:, None, None, :3, :3], eq[None, :, :, :3, :3])
        t_eq = np.broadcast_to(eq[None, :, :, :3, 3], (len(p), *eq.shape[:2], 3))
    elif len(axes) > 1:
        re = np.zeros((len(p), len(g), 1))
        t_eq = None
    else:
        a, o = axes[0], offsets[0]
        # M = R_D R_p^T R_g, (P, G, S, 3, 3).
        m = disc[None, None, :, :3, :3] @ (
            np.swapaxes(p[:, None, None, :3, :3], -1, -2) @ g[None, :, None, :3, :3]
        )
        along = np.einsum("i,...ij,j->...", a, m, a)
        cos_part = np.trace(m, axis1=-2, axis2=-1) - along
        sin_part = np.trace(m @ _skew(a), axis1=-2, axis2=-1)
        theta = np.arctan2(sin_part, cos_part)
        k = _skew(a)
        rot = (
            np.eye(3)
            + np.sin(theta)[..., None, None] * k
            + (1.0 - np.cos(theta))[..., None, None] * (k @ k)
        )  # C(theta), (P, G, S, 3, 3)
        r_eq = g[None, :, None, :3, :3] @ rot @ disc[None, None, :, :3, :3]
        t_s = (rot @ disc[None, None, :, :3, 3, None])[..., 0] + o - rot @ o
        t_eq = (g[None, :, None, :3, :3] @ t_s[..., None])[..., 0] + g[None, :, None, :3, 3]
        re = rotation_error_deg(p[:, None, None, :3, :3], r_eq)
    c = _fixed_point(disc, axes, offsets)
    if c is None and t_eq is not None:
        return re, translation_error(p[:, None, None, :3, 3], t_eq)
    c = np.zeros(3) if c is None else c
    at_p = p[:, :3, :3] @ c + p[:, :3, 3]
    at_g = g[:, :3, :3] @ c + g[:, :3, 3]
    te = translation_error(at_p[:, None], at_g[None])[..., None]
    return re, np.broadcast_to(te, re.shape).copy()


def symmetric_errors(
    pred: ArrayLike, gt: ArrayLike, symmetries: Any = None
) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (degrees) and translation errors of every prediction against every ground
    truth, each the smallest over the part's symmetries (both taken at the same symmetry:
    the one of least rotation error, ties broken by translation; about a continuous axis the
    angle of least rotation error, in closed form). With symmetries about a point other than
    the origin, the translation error is that point's (``_equivalent_errors``).

    Parameters
    ----------
    pred, gt : array_like
        (P, 4, 4) and (G, 4, 4) poses ``T_target_source``.
    symmetries : optional
        The source's proper symmetries (``T @ S`` looks like ``T``): (S, 4, 4) transforms, a
        :class:`pointclm.symmetry.Symmetry`, or a BOP ``models_info`` entry; None: the
        identity alone.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        (P, G) rotation errors in degrees and (P, G) translation errors.
    """
    re, te = _equivalent_errors(_as_poses(pred), _as_poses(gt), symmetries)
    if re.size == 0:
        return re[..., 0], te[..., 0]
    # Lexicographic: least rotation error first, then least translation error.
    pick = np.lexsort((te, re), axis=-1)[..., :1]
    return np.take_along_axis(re, pick, -1)[..., 0], np.take_along_axis(te, pick, -1)[..., 0]


def add_s(pred: ArrayLike, gt: ArrayLike, points: ArrayLike, symmetries: Any = None) -> float:
    """The average distance of the model's points between two poses, the smallest over the
    part's symmetries (ADD with the symmetry group: ``min_S mean ||T_p x - T_g S x||``, the
    form BOP scores symmetric parts by; with no symmetry, plain ADD).

    Parameters
    ----------
    pred, gt : array_like
        (4, 4) poses ``T_target_source``.
    points : array_like
        (N, 3) model points, in the model's units.
    symmetries : optional
        As :func:`symmetric_errors` takes them. A continuous axis is sampled every degree,
        the best sample then refined by golden-section search within a degree either side
        (the mean distance is smooth in the angle; its minimum is found to about 1e-6 deg).

    Returns
    -------
    float
        In the points' units.
    """
    p, g = _as_poses(pred), _as_poses(gt)
    if p.shape != (1, 4, 4) or g.shape != (1, 4, 4):
        raise ValueError(f"add_s takes one pose each, got {p.shape} and {g.shape}")
    x = np.asarray(points, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or not len(x) or not np.isfinite(x).all():
        raise ValueError(f"points must be a finite (N, 3) array, N >= 1, got shape {x.shape}")
    disc, axes, offsets = _as_symmetries(symmetries)
    posed = x @ p[0, :3, :3].T + p[0, :3, 3]

    def add(s: np.ndarray) -> float:
        t = g[0] @ s
        return float(np.linalg.norm(posed - (x @ t[:3, :3].T + t[:3, 3]), axis=1).mean())

    if len(axes) > 1:
        raise ValueError(
            "add_s: every rotation about a point is a symmetry (a sphere); give the distance "
            "of the centres instead"
        )
    if len(axes) == 0:
        return min(add(s) for s in disc)
    return min(
        _least_about_axis(add, axes[0] / np.linalg.norm(axes[0]), offsets[0], s) for s in disc
    )


def _least_about_axis(add: Any, a: np.ndarray, o: np.ndarray, s: np.ndarray) -> float:
    """The least of ``add(C(theta) s)`` over the angle about the axis `a` through `o`: every
    degree, then golden-section search within a degree of the best."""
    k = _skew(a)

    def turned(theta: float) -> float:
        c = np.eye(4)
        c[:3, :3] = np.eye(3) + np.sin(theta) * k + (1 - np.cos(theta)) * (k @ k)
        c[:3, 3] = o - c[:3, :3] @ o
        return add(c @ s)

    grid = np.radians(np.arange(360.0))
    values = [turned(t) for t in grid]
    best = grid[int(np.argmin(values))]
    lo, hi = best - np.radians(1), best + np.radians(1)
    ratio = (np.sqrt(5) - 1) / 2
    while hi - lo > 1e-8:
        m1, m2 = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
        if turned(m1) < turned(m2):
            hi = m2
        else:
            lo = m1
    return min(min(values), turned((lo + hi) / 2))

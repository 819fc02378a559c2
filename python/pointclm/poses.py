"""A pose in the forms other tools take: rotation matrix, translation, unit quaternion.

Every pose pointclm returns is ``T_target_source`` (4 x 4): it maps model points onto the
copy in the scan, ``p_scan = R @ p_model + t``. These functions take such a matrix or
anything with a ``transformation`` attribute (:class:`pointclm.CloudInstance`,
:class:`pointclm.Instance`); :class:`PoseForms` gives a class holding a ``transformation``
the same forms as methods and properties.

Quaternions follow :class:`scipy.spatial.transform.Rotation`: Hamilton convention, active
rotation, unit norm, ``order="xyzw"`` (scalar last, scipy's and ROS's
``geometry_msgs/Quaternion`` order) or ``"wxyz"`` (scalar first, Eigen's constructor and
transforms3d's order). ``q`` and ``-q`` are the same rotation; the sign returned is the
canonical one, ``w >= 0`` (and, when ``w == 0``, the first non-zero of ``x, y, z``
positive), so equal rotations give equal quaternions.

>>> import numpy as np
>>> from pointclm.poses import quaternion
>>> T = np.eye(4); T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]   # 90 degrees about z
>>> np.round(quaternion(T), 6).tolist()
[0.0, 0.0, 0.707107, 0.707107]
>>> np.round(quaternion(T, order="wxyz"), 6).tolist()
[0.707107, 0.0, 0.0, 0.707107]
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import InputError

__all__ = ["ORDERS", "PoseForms", "quaternion", "rotation", "translation"]

#: The quaternion component orders :func:`quaternion` writes.
ORDERS = ("xyzw", "wxyz")


def _matrix(pose: Any) -> np.ndarray:
    """The 4 x 4 float64 matrix of `pose` (a matrix or an object with ``transformation``),
    checked to be finite."""
    raw = getattr(pose, "transformation", pose)
    try:
        T = np.array(raw, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"a pose must be a 4 x 4 matrix, got {type(raw).__name__}") from None
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise InputError(f"a pose must be a finite 4 x 4 matrix, got shape {T.shape}")
    return T


def rotation(pose: Any) -> np.ndarray:
    """The (3, 3) rotation block of `pose` (a copy)."""
    return _matrix(pose)[:3, :3].copy()


def translation(pose: Any) -> np.ndarray:
    """The (3,) translation of `pose` (a copy), in the clouds' unit."""
    return _matrix(pose)[:3, 3].copy()


def quaternion(pose: Any, order: str = "xyzw") -> np.ndarray:
    """The (4,) unit quaternion of `pose`'s rotation, in `order` ``"xyzw"`` (default) or
    ``"wxyz"``, with the canonical sign (module documentation). A rotation block off by
    rounding gives the quaternion of the nearest rotation (scipy's ``from_matrix``)."""
    from scipy.spatial.transform import Rotation

    if order not in ORDERS:
        raise InputError(f'order must be "xyzw" or "wxyz", got {order!r}')
    q = Rotation.from_matrix(_matrix(pose)[:3, :3]).as_quat()
    q /= np.linalg.norm(q)
    # The canonical sign, written out: scipy's `canonical=` keyword is newer than its
    # oldest release this package supports.
    lead = q[3] if q[3] != 0 else q[np.flatnonzero(q[:3])[0]]
    q = -q if lead < 0 else q
    return q if order == "xyzw" else np.roll(q, 1)


class PoseForms:
    """``quaternion()``, ``rotation`` and ``translation`` of a class's ``transformation``
    (``T_target_source``, 4 x 4), as :mod:`pointclm.poses` defines them."""

    transformation: Any

    def quaternion(self, order: str = "xyzw") -> np.ndarray:
        """The unit quaternion of the rotation, ``"xyzw"`` (default) or ``"wxyz"``, sign
        canonical (``w >= 0``): :func:`pointclm.poses.quaternion`."""
        return quaternion(self.transformation, order)

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) rotation block of ``transformation`` (a copy)."""
        return rotation(self.transformation)

    @property
    def translation(self) -> np.ndarray:
        """(3,) translation of ``transformation`` (a copy), in the clouds' unit."""
        return translation(self.transformation)

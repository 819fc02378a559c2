"""Boxes seen by their top face alone are found by the face proposals, whatever their sides:
also those whose sides divide one another (a 0.2 x 0.12 x 0.03 box's 0.2 x 0.03 side four
times over is its top), those with a square section and cubes, turned and moved anywhere."""

from __future__ import annotations

import itertools

import numpy as np
import pointclm
import pytest
from helpers import box_surface
from pointclm.metrics import symmetric_errors

SENSOR = (0.0, 0.0, 1.0)


def _symmetries(size: tuple[float, float, float]) -> np.ndarray:
    """The box's proper symmetries: the signed axis permutations of determinant 1 that map its
    sides onto sides of the same length (4 for distinct sides, 8 for a square section, 24
    for a cube)."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((-1.0, 1.0), repeat=3):
            r = np.zeros((3, 3))
            r[range(3), perm] = signs
            if np.linalg.det(r) > 0 and np.allclose(np.abs(r) @ size, size):
                s = np.eye(4)
                s[:3, :3] = r
                out.append(s)
    return np.array(out)


def _pose(yaw: float, at: tuple[float, float, float]) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    t = np.eye(4)
    t[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    t[:3, 3] = at
    return t


@pytest.mark.parametrize(
    "size",
    [
        (0.2, 0.12, 0.03),  # the top is four of the long side, and the long side is 0.2
        (0.2, 0.1, 0.05),  # the top is two of the long side
        (0.1, 0.05, 0.05),  # a square section: the top is two ends
        (0.12, 0.04, 0.04),  # a square section: the top is three ends
        (0.1, 0.1, 0.1),  # a cube
        (0.16, 0.1, 0.045),  # no side divides another
    ],
)
@pytest.mark.parametrize("yaw", [0.0, 0.7])
def test_a_box_seen_by_its_top_alone_is_found_where_it_is(size, yaw) -> None:  # type: ignore[no-untyped-def]
    box = box_surface(size)
    truth = _pose(yaw, (0.03, -0.02, 0.01))
    top = box[box[:, 2] > size[2] / 2 - 1e-9] @ truth[:3, :3].T + truth[:3, 3]
    reg = pointclm.register_point_clouds(box, top, viewpoint=SENSOR, num_threads=1)
    assert len(reg.passes[0].faces) > 0
    (copy,) = reg.instances
    rotation, translation = symmetric_errors(
        np.asarray(reg.transformations), truth[None], _symmetries(size)
    )
    assert rotation[0, 0] < 3.0, rotation
    assert translation[0, 0] < 2 * reg.voxel_size, (translation, reg.voxel_size)

"""The mesh primitives of :mod:`pointclm.datasets.procedural` (parametric grids, fans, rings,
boxes) and the six fixed shapes of its ``PROCEDURAL_SHAPES`` built from them.

Kept apart from the random families because the fixed shapes never change with a seed: this
part is plain geometry, the families' part is the seeded drawing on top of it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

Mesh = tuple[np.ndarray, np.ndarray]


def _grid_faces(nu: int, nv: int, wrap_u: bool, wrap_v: bool) -> np.ndarray:
    """Triangulate an ``nu x nv`` vertex grid (row-major, index ``i * nv + j``)."""
    iu = np.arange(nu if wrap_u else nu - 1)
    jv = np.arange(nv if wrap_v else nv - 1)
    gi, gj = np.meshgrid(iu, jv, indexing="ij")
    i, j = gi.ravel(), gj.ravel()
    i1, j1 = (i + 1) % nu, (j + 1) % nv
    a, b, c, d = i * nv + j, i1 * nv + j, i1 * nv + j1, i * nv + j1
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)


def _grid(
    fn: Callable[[np.ndarray, np.ndarray], np.ndarray],
    u: np.ndarray,
    v: np.ndarray,
    wrap_u: bool,
    wrap_v: bool,
) -> Mesh:
    """Mesh of the parametric surface ``fn(u, v) -> (..., 3)`` sampled on a grid."""
    uu, vv = np.meshgrid(u, v, indexing="ij")
    verts = fn(uu, vv).reshape(-1, 3)
    return verts, _grid_faces(len(u), len(v), wrap_u, wrap_v)


def _fan(ring: np.ndarray, centre: np.ndarray) -> Mesh:
    """Close a planar ring of vertices with a triangle fan around ``centre``."""
    n = len(ring)
    verts = np.vstack([ring, centre[None]])
    k = np.arange(n)
    faces = np.stack([np.full(n, n), k, (k + 1) % n], 1).astype(np.int32)
    return verts, faces


def _merge(*meshes: Mesh) -> Mesh:
    """Concatenate meshes (vertices are not welded; sampling by area does not need it)."""
    verts, faces, offset = [], [], 0
    for v, f in meshes:
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
    return np.vstack(verts).astype(np.float64), np.vstack(faces).astype(np.int32)


def _ring(n: int = 64) -> np.ndarray:
    return np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)


def _torus() -> Mesh:
    # Tube radius varies around the ring: no rotational symmetry about the axis.
    def fn(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        r = 0.3 + 0.12 * np.cos(u)
        return np.stack(
            [(1 + r * np.cos(v)) * np.cos(u), (1 + r * np.cos(v)) * np.sin(u), r * np.sin(v)], -1
        )

    return _grid(fn, _ring(96), _ring(32), True, True)


def _cuboid(lo: np.ndarray, hi: np.ndarray, open_bottom: bool = False) -> Mesh:
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    verts = lo + corners * (hi - lo)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (1, 5, 7, 3), (0, 2, 6, 4)]
    if open_bottom:
        quads = [q for q in quads if q != (0, 2, 6, 4)]
    faces = [[a, b, c] for a, b, c, _ in quads] + [[a, c, d] for a, _, c, d in quads]
    return verts, np.array(faces, np.int32)


def _box() -> Mesh:
    # A cuboid with a smaller block on one corner of its top face.
    base = _cuboid(np.array([0.0, 0.0, 0.0]), np.array([1.2, 0.7, 0.4]))
    block = _cuboid(np.array([0.75, 0.35, 0.4]), np.array([1.1, 0.65, 0.75]), open_bottom=True)
    return _merge(base, block)


def _cylinder() -> Mesh:
    a, b, h = 0.5, 0.32, 1.6
    u = _ring()

    def fn(uu: np.ndarray, vv: np.ndarray) -> np.ndarray:
        return np.stack([a * np.cos(uu), b * np.sin(uu), h * vv], -1)

    side = _grid(fn, u, np.linspace(0.0, 1.0, 12), True, False)
    ring = np.stack([a * np.cos(u), b * np.sin(u), np.zeros_like(u)], 1)
    top = ring + [0.0, 0.0, h]
    return _merge(side, _fan(ring, np.zeros(3)), _fan(top, np.array([0.0, 0.0, h])))


def _cone() -> Mesh:
    # Oblique cone over an elliptic base.
    a, b = 0.6, 0.4
    apex = np.array([0.3, 0.15, 1.3])
    u = _ring()

    def fn(uu: np.ndarray, vv: np.ndarray) -> np.ndarray:
        base = np.stack([a * np.cos(uu), b * np.sin(uu), np.zeros_like(uu)], -1)
        return (1 - vv)[..., None] * base + vv[..., None] * apex

    side = _grid(fn, u, np.linspace(0.0, 1.0, 16), True, False)
    ring = np.stack([a * np.cos(u), b * np.sin(u), np.zeros_like(u)], 1)
    return _merge(side, _fan(ring, np.zeros(3)))


def _capsule() -> Mesh:
    # Elliptic cross-section, one cap longer than the other.
    a, b, h = 0.4, 0.28, 1.0

    def fn(uu: np.ndarray, vv: np.ndarray) -> np.ndarray:
        # vv in [-pi/2, pi/2 + 1]: lower cap, straight part of length h, upper cap.
        lower = vv < 0
        upper = vv > 1
        phi = np.where(lower, vv, np.where(upper, vv - 1, 0.0))
        s = np.cos(phi)
        z = np.where(lower, 0.6 * np.sin(phi), np.where(upper, h + 1.0 * np.sin(phi), h * vv))
        return np.stack([a * s * np.cos(uu), b * s * np.sin(uu), z], -1)

    v = np.concatenate(
        [
            np.linspace(-np.pi / 2, 0, 12, endpoint=False),
            np.linspace(0, 1, 8),
            np.linspace(1, 1 + np.pi / 2, 13)[1:],
        ]
    )
    return _grid(fn, _ring(), v, True, False)


def _helix_tube() -> Mesh:
    # A tube around a helix: chiral, so no rotation maps it onto itself.
    radius, pitch, rt = 1.0, 0.18, 0.14
    s = np.linspace(0.0, 3.0 * np.pi, 160)
    c = np.stack([radius * np.cos(s), radius * np.sin(s), pitch * s], -1)
    tangent = np.stack([-radius * np.sin(s), radius * np.cos(s), np.full_like(s, pitch)], -1)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.stack([-np.cos(s), -np.sin(s), np.zeros_like(s)], -1)
    binormal = np.cross(tangent, normal)
    v = _ring(24)
    verts = c[:, None] + rt * (
        np.cos(v)[None, :, None] * normal[:, None] + np.sin(v)[None, :, None] * binormal[:, None]
    )
    return verts.reshape(-1, 3), _grid_faces(len(s), len(v), False, True)

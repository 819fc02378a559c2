"""Meshes as files hold them, and turning one into a point cloud by uniform area sampling.

Why sample instead of returning the vertices: registration compares point densities, and a
mesh's vertices are dense where the modeller needed detail, not where the surface is. Area
weighting gives the uniform surface density a depth sensor would.

:func:`sample_mesh` is the project's only surface sampler: :func:`pointclm.io.read_point_cloud`
samples PLY and OFF meshes with it, and :func:`pointclm.datasets.sample_surface` (the shapes
and realistic scenes) calls it, so a given seed gives the same points through every entry
point.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .pointcloud import PointCloud, finite_cloud

__all__ = ["Mesh", "check_n_samples", "default_n_samples", "sample_mesh", "triangulate"]

#: Fewest points :func:`sample_mesh` draws by default (more for meshes with more vertices).
MIN_DEFAULT_SAMPLES = 10_000
#: Most points one call may draw (about 5 GB of points, normals and draws): a larger count
#: is refused up front rather than left to fail, or to swap, inside numpy.
MAX_SAMPLES = 100_000_000


def default_n_samples(n_vertices: int) -> int:
    """``max(10_000, n_vertices)``: never sparser than the mesh's own vertices."""
    return max(MIN_DEFAULT_SAMPLES, int(n_vertices))


def triangulate(counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Fan-triangulate polygons given as per-face vertex counts and their flat indices.

    Faces with fewer than three vertices have no area and are dropped. Fans are exact for
    the convex polygons mesh files hold in practice.

    Returns
    -------
    numpy.ndarray
        (T, 3) int64 vertex indices.
    """
    counts = np.asarray(counts, dtype=np.int64)
    flat = np.asarray(indices, dtype=np.int64)
    if len(counts) and counts.min() == counts.max():
        c = int(counts[0])
        if c < 3:
            return np.empty((0, 3), dtype=np.int64)
        polys = flat.reshape(len(counts), c)
        if c == 3:
            return np.ascontiguousarray(polys)
        k = np.arange(1, c - 1)
        return np.stack(
            [np.repeat(polys[:, 0], c - 2), polys[:, k].ravel(), polys[:, k + 1].ravel()], axis=1
        )
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    n_tri = np.clip(counts - 2, 0, None)
    first = np.repeat(starts, n_tri)
    # For triangle j of a face: vertices 0, j + 1, j + 2 of that face.
    j = np.arange(int(n_tri.sum())) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri)
    return np.stack([flat[first], flat[first + j + 1], flat[first + j + 2]], axis=1)


@dataclass(frozen=True, eq=False)
class Mesh:
    """A mesh or point file's content before sampling.

    Attributes
    ----------
    vertices : numpy.ndarray
        (V, 3) float64 positions as stored (non-finite rows kept: they are the caller's to
        reject or drop).
    triangles : numpy.ndarray or None
        (T, 3) int64 vertex indices (polygons fan-triangulated), or None for a file without
        faces (a point cloud).
    normals, colors : numpy.ndarray or None
        (V, 3) per-vertex normals and colours in [0, 1] when the file stores them.
    """

    vertices: np.ndarray
    triangles: np.ndarray | None = None
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None

    def sampled(self, n_samples: int | None = None, seed: int | None = 0) -> PointCloud:
        """A mesh sampled by area (:func:`sample_mesh`); a point file's finite vertices."""
        if self.triangles is None:
            return finite_cloud(self.vertices, self.normals, self.colors)
        cloud = sample_mesh(
            self.vertices, self.triangles, n_samples, seed, vertex_colors=self.colors
        )
        bad = int((~np.isfinite(np.asarray(self.vertices, dtype=np.float64)).all(axis=1)).sum())
        return dataclasses.replace(cloud, dropped=bad) if bad else cloud


def sample_mesh(
    vertices: np.ndarray,
    triangles: np.ndarray,
    n_samples: int | None = None,
    seed: int | np.random.Generator | None = 0,
    vertex_colors: np.ndarray | None = None,
) -> PointCloud:
    """Draw points uniformly by area on a triangle mesh.

    One area-weighted ``Generator.choice`` of triangles, then ``sqrt(r1)``/``r2``
    barycentric coordinates: the draws, and so the points of a seed, never change.

    Parameters
    ----------
    vertices : numpy.ndarray
        (V, 3) positions. Triangles touching a non-finite vertex get no samples.
    triangles : numpy.ndarray
        (T, 3) integer vertex indices.
    n_samples : int, optional
        Number of points; default ``max(10_000, V)``.
    seed : int or numpy.random.Generator or None
        Seed of :func:`numpy.random.default_rng`, or a generator to draw from; the same seed
        gives the same points.
    vertex_colors : numpy.ndarray, optional
        (V, 3) in [0, 1], interpolated barycentrically onto the samples.

    Returns
    -------
    PointCloud
        Samples with the unit normal of the triangle each lies on.

    Raises
    ------
    ValueError
        Indices out of range, a non-positive ``n_samples``, or no triangle of positive,
        finite area.
    """
    verts = np.asarray(vertices, dtype=np.float64)
    tris = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    n = default_n_samples(len(verts)) if n_samples is None else check_n_samples(n_samples)
    if len(tris) and (tris.min() < 0 or tris.max() >= len(verts)):
        bad = tris.min() if tris.min() < 0 else tris.max()
        raise ValueError(f"a face uses vertex index {bad}, but the mesh has {len(verts)} vertices")
    corners = verts[tris]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    cross_norm = np.linalg.norm(cross, axis=1)
    face, r1, r2 = _draw(0.5 * cross_norm, n, np.random.default_rng(seed))
    a, b, c = corners[face, 0], corners[face, 1], corners[face, 2]
    points = (1 - r1) * a + r1 * (1 - r2) * b + r1 * r2 * c
    normals = cross[face] / cross_norm[face, None]
    colors = None
    if vertex_colors is not None:
        vc = np.asarray(vertex_colors, dtype=np.float64)
        ca, cb, cc = vc[tris[face, 0]], vc[tris[face, 1]], vc[tris[face, 2]]
        colors = np.clip((1 - r1) * ca + r1 * (1 - r2) * cb + r1 * r2 * cc, 0.0, 1.0)
    return PointCloud(points=points, normals=normals, colors=colors)


def _draw(
    area: np.ndarray, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The triangle of each sample (by area) and its barycentric draws ``sqrt(r1)``, ``r2``,
    drawn in this order: every seeded mesh sample in the project depends on it."""
    area[~np.isfinite(area)] = 0.0
    total = area.sum()
    if not (np.isfinite(total) and total > 0):
        raise ValueError(
            f"the mesh's {len(area)} triangles have no positive, finite area to sample from"
        )
    face = rng.choice(len(area), size=n, p=area / total)
    r1 = np.sqrt(rng.random(n))[:, None]
    r2 = rng.random(n)[:, None]
    return face, r1, r2


def check_n_samples(n_samples: int) -> int:
    """Validate a sample count up front, so a bad one fails the same way for every format."""
    if isinstance(n_samples, bool) or not isinstance(n_samples, int | np.integer):
        raise ValueError(f"n_samples must be an int, got {type(n_samples).__name__}")
    if not 1 <= n_samples <= MAX_SAMPLES:
        raise ValueError(f"n_samples must lie in [1, {MAX_SAMPLES:_}], got {n_samples}")
    return int(n_samples)

"""Open3D geometries in and out, without importing Open3D unless the caller holds one.

An Open3D object is recognised by its class's module (``open3d...geometry``) and name, never
by ``import open3d``: that import took 2.8 s and 90 MB more memory than numpy's (open3d-cpu
0.20, a busy 2-core machine), which pointclm's users without Open3D should not pay.
Accepted wherever pointclm takes points (:func:`pointclm.register_point_clouds`,
:func:`pointclm.refine_poses`, :func:`pointclm.io.read_point_cloud`,
:func:`pointclm.io.load_points`):

- ``open3d.geometry.PointCloud`` and ``open3d.t.geometry.PointCloud``: the points, and the
  normals and colours when the cloud has them;
- ``open3d.geometry.TriangleMesh`` and ``open3d.t.geometry.TriangleMesh``: the surface
  sampled by area with :func:`pointclm.io.sample_mesh`, exactly as a mesh file is (default
  ``max(10_000, vertices)`` points, seed 0), with each sample's triangle normal; a mesh
  without triangles gives its vertices (and vertex normals).

Points with NaN/inf coordinates are dropped with a
:class:`~pointclm.io.NonFinitePointsWarning` giving the count, as the file readers drop a
scanner's missing returns: an Open3D cloud is data read from somewhere, like a file. Numpy
arrays passed to pointclm are never cleaned (a NaN raises). A tensor cloud on a GPU is
copied to the host, as is an ``open3d.core.Tensor`` of points (then checked as an array is).
The caller's object is only read, never changed.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import InputError

if TYPE_CHECKING:
    from ..io.pointcloud import PointCloud

__all__ = [
    "from_open3d",
    "is_open3d_geometry",
    "open3d_points",
    "to_open3d",
    "with_open3d_normals",
]

#: The geometry classes read here, by name (legacy and tensor forms share the names).
KINDS = ("PointCloud", "TriangleMesh")


def _open3d_kind(obj: Any) -> tuple[str, bool] | None:
    """(class name, tensor form) of an Open3D geometry, or None for anything else."""
    for cls in type(obj).__mro__:
        module = getattr(cls, "__module__", None) or ""
        if module.split(".")[0] == "open3d" and module.endswith("geometry"):
            return cls.__name__, ".t." in f".{module}."
    return None


def is_open3d_geometry(obj: Any) -> bool:
    """Whether `obj` is an Open3D geometry (any class of ``open3d.geometry`` or
    ``open3d.t.geometry``), told by its class's module without importing Open3D."""
    return _open3d_kind(obj) is not None


def open3d_points(obj: Any, name: str = "points") -> Any:
    """The (N, 3) float64 points of an Open3D geometry (:func:`from_open3d`), or the host
    array of an ``open3d.core.Tensor``; anything else is returned as it is, for the usual
    checks of arrays (which a tensor's array gets too)."""
    if _open3d_kind(obj) is None:
        module = getattr(type(obj), "__module__", None) or ""
        if module.startswith("open3d.") and type(obj).__name__ == "Tensor":
            return _host(obj)
        return obj
    return from_open3d(obj, name=name).points


def with_open3d_normals(obj: Any, normals: Any, name: str = "points") -> tuple[Any, Any]:
    """`obj` and `normals` as given, except for an Open3D geometry: its points, and its
    normals (:func:`from_open3d`) when `normals` is None."""
    if _open3d_kind(obj) is None:
        return obj, normals
    cloud = from_open3d(obj, name=name)
    return cloud.points, cloud.normals if normals is None else normals


def from_open3d(
    obj: Any, *, n_samples: int | None = None, seed: int | None = 0, name: str = "cloud"
) -> PointCloud:
    """A :class:`pointclm.io.PointCloud` (points, normals, colours) of an Open3D
    ``PointCloud`` or ``TriangleMesh``, legacy or tensor form (module documentation).

    Parameters
    ----------
    obj : open3d geometry
        The cloud or mesh; read, never changed.
    n_samples, seed : int, optional
        A mesh's samples, as :func:`pointclm.io.read_point_cloud` draws them from a mesh
        file; ignored for a cloud.
    name : str
        What the messages call `obj` (an argument's name).

    Raises
    ------
    InputError
        `obj` is another kind of Open3D geometry, is empty, or has no finite point.
    """
    from ..io.mesh import check_n_samples, sample_mesh
    from ..io.pointcloud import NonFinitePointsWarning, finite_cloud

    kind = _open3d_kind(obj)
    label = _label(kind, name)
    if kind is None or kind[0] not in KINDS:
        shown = type(obj).__name__ if kind is None else label
        raise InputError(
            f"{name}: cannot read {shown}; pass an Open3D PointCloud or TriangleMesh "
            "(open3d.geometry or open3d.t.geometry), an (N, 3) array or a file path"
        )
    if n_samples is not None:
        check_n_samples(n_samples)
    arrays = _tensor_arrays(obj, kind[0]) if kind[1] else _legacy_arrays(obj, kind[0])
    points, normals, colors, triangles = arrays
    if len(points) == 0:
        raise InputError(f"{label} has no points")
    try:
        if triangles is not None and len(triangles):
            cloud = sample_mesh(points, triangles, n_samples, seed, colors)
            dropped = int((~np.isfinite(points).all(axis=1)).sum())
        else:
            cloud = finite_cloud(points, normals, colors)
            dropped = cloud.dropped
    except ValueError as e:
        raise InputError(f"{label}: {e}") from None
    if dropped:
        warnings.warn(
            f"{label}: dropped {dropped} {'point' if dropped == 1 else 'points'} with NaN/inf "
            f"coordinates, kept {len(cloud)}",
            NonFinitePointsWarning,
            stacklevel=3,
        )
    return cloud


def _label(kind: tuple[str, bool] | None, name: str) -> str:
    if kind is None:
        return name
    module = "open3d.t.geometry" if kind[1] else "open3d.geometry"
    return f"{name} ({module}.{kind[0]})"


Arrays = tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]


def _legacy_arrays(obj: Any, kind: str) -> Arrays:
    """Copies of a legacy cloud's or mesh's points, normals, colours and triangles (Open3D's
    vectors are views into its own memory)."""
    if kind == "PointCloud":
        normals = _copy(obj.normals) if obj.has_normals() else None
        colors = _colors(obj.colors) if obj.has_colors() else None
        return _copy(obj.points), normals, colors, None
    normals = _copy(obj.vertex_normals) if obj.has_vertex_normals() else None
    colors = _colors(obj.vertex_colors) if obj.has_vertex_colors() else None
    triangles = np.array(obj.triangles, dtype=np.int64).reshape(-1, 3)
    return _copy(obj.vertices), normals, colors, triangles


def _tensor_arrays(obj: Any, kind: str) -> Arrays:
    """A tensor cloud's or mesh's attributes as float64 host arrays."""
    attrs = obj.point if kind == "PointCloud" else obj.vertex
    if "positions" not in attrs:
        return np.empty((0, 3)), None, None, None
    normals = _copy(_host(attrs["normals"])) if "normals" in attrs else None
    colors = _colors(_host(attrs["colors"])) if "colors" in attrs else None
    triangles = None
    if kind == "TriangleMesh" and "indices" in obj.triangle:
        triangles = np.array(_host(obj.triangle["indices"]), dtype=np.int64).reshape(-1, 3)
    return _copy(_host(attrs["positions"])), normals, colors, triangles


def _host(tensor: Any) -> np.ndarray:
    return np.asarray(tensor.cpu().numpy())


def _copy(values: Any) -> np.ndarray:
    return np.array(values, dtype=np.float64).reshape(-1, 3)


def _colors(values: Any) -> np.ndarray:
    from ..io.pointcloud import unit_colors

    return unit_colors(np.asarray(values).reshape(-1, 3))


def import_open3d() -> Any:
    """``open3d``, or an ImportError saying how to install it."""
    try:
        import open3d
    except ImportError as e:
        raise ImportError(
            "this needs Open3D: pip install open3d-cpu (Linux x86-64) or pip install open3d"
        ) from e
    return open3d


def to_open3d(
    points: Any, normals: ArrayLike | None = None, colors: ArrayLike | None = None
) -> Any:
    """An ``open3d.geometry.PointCloud`` of (N, 3) `points` (or of a
    :class:`pointclm.io.PointCloud`, with its normals and colours), with `normals` and
    `colors` ((N, 3), RGB in [0, 1]; one RGB triple paints every point) when given. Imports
    Open3D."""
    o3d = import_open3d()
    if all(hasattr(points, a) for a in ("points", "normals", "colors")):
        normals = points.normals if normals is None else normals
        colors = points.colors if colors is None else colors
        points = points.points
    pts = np.array(points, dtype=np.float64).reshape(-1, 3)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    if normals is not None:
        nrm = np.array(normals, dtype=np.float64).reshape(-1, 3)
        cloud.normals = o3d.utility.Vector3dVector(nrm)
    if colors is not None:
        rgb = np.array(colors, dtype=np.float64).reshape(-1, 3)
        rgb = np.broadcast_to(rgb, pts.shape) if len(rgb) == 1 else rgb
        cloud.colors = o3d.utility.Vector3dVector(np.ascontiguousarray(rgb))
    return cloud

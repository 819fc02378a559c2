"""Reading point clouds and meshes from files, and writing PLY.

>>> from pointclm.io import read_point_cloud, load_points, write_ply   # doctest: +SKIP
>>> cloud = read_point_cloud("scene.pcd")            # PointCloud(points, normals, colors)
>>> src = load_points("model.ply", n_samples=5000)   # (N, 3) float64, mesh sampled by area
>>> mesh = read_mesh("model.off")                    # Mesh(vertices, triangles), unsampled

Formats: PLY (ASCII, binary little/big endian), PCD (ascii, binary, binary_compressed),
OFF, ``.xyz``/``.txt``/``.pts`` text, ``.npy``/``.npz``; plus Open3D's feature ``.bin``
files (:func:`read_open3d_feature`). Open3D's own clouds and meshes are read in memory
(:func:`from_open3d`, and :func:`read_point_cloud` given one; Open3D is never imported for
that) and written with :func:`to_open3d`. Poses go out and back in the BOP challenge's CSV
(:func:`write_bop_csv`, :func:`read_bop_csv`).

Design decisions
----------------
- **numpy only, no optional dependency.** ``pip install pointclm`` (numpy + tqdm) reads every
  format above; nothing here imports a PCD library, and trimesh only as the fallback of
  :func:`read_mesh` for OBJ and STL, which no reader here parses. PLY, OFF and PCD are short
  specifications, and one implementation means a file gives the same cloud, and a seed the
  same samples, whether or not the ``[io]`` extra is installed. trimesh (MIT) was the
  candidate for PLY/OFF; it was not used at runtime because (a) it would make the default
  install either fail on meshes or behave differently from the extra, (b) for a face-less
  PLY it returns a ``trimesh.PointCloud`` whose normals are reachable only through private
  metadata (``metadata["_ply_raw"]``), and (c) it reads no PCD. The test suite checks these
  readers against trimesh on real files instead.
- **PCD**: ``pypcd4`` (BSD-3-Clause, maintained) reads binary_compressed, but needs pydantic
  and the C extension ``python-neo-lzf``; :mod:`pointclm.io.lzf` is a pure-Python LZF
  decoder instead (a 640x480 organised Kinect cloud, 2.5 MB compressed, decodes in about a
  quarter of a second).
- **One mesh path**: :func:`read_mesh` returns a file's vertices and triangles unsampled
  (:mod:`pointclm.datasets` reads every mesh through it), and :func:`sample_mesh` is the one
  surface sampler. :func:`read_point_cloud` samples meshes rather than returning their
  vertices: a PLY or OFF file with faces gives ``n_samples`` points drawn uniformly by area
  (default ``max(10_000, vertices)``), seeded, with the normal of the triangle each point
  lies on; a file without faces gives its vertices (with normals and colours when stored).
- **Only finite points, and a warning**: rows of a file with NaN/inf coordinates are dropped
  (scanners write NaN for a missing return, organised clouds for a missing pixel), keeping
  normals and colours aligned, and :func:`read_point_cloud` (so :func:`load_points` and
  every command that reads files) warns with :class:`NonFinitePointsWarning`, naming the
  file and the count (``PointCloud.dropped``); a mesh's non-finite vertices are dropped the
  same way. A file with no finite point is an error, never an empty cloud. Arrays passed to
  ``pointclm.register`` or ``register_point_clouds`` directly are not files: a NaN in them
  raises :class:`~pointclm.errors.InputError`.
- **Errors name the file**: a missing file raises
  :class:`~pointclm.errors.PathNotFoundError` (a :class:`FileNotFoundError`); an empty,
  truncated or malformed file, an unsupported extension, or a cloud without finite points
  raises :class:`ValueError` whose message starts with the path.
- **Hostile files are safe to read** (``tests/test_hostile_files.py``): only regular files
  are opened (a FIFO would block, ``/dev/zero`` never ends); every size a file declares
  (PCD points, counts and compressed block sizes against LZF's 88x bound, PLY element
  counts and list lengths, OFF counts, ``.npy`` shapes, ``.npz`` member sizes against
  deflate's 1032x bound) is checked against the file's length before anything is
  allocated, so memory stays proportional to the file; an ``.npz`` is read member by
  member, only those needed; nothing is unpickled; an ASCII integer that its declared type
  cannot hold (``uchar`` 300, ``int`` 2**40, NaN, 2.5, a face index that names no vertex)
  is an error naming the element and line, never wrapped around.
"""

from __future__ import annotations

from ..interop.open3d import from_open3d, to_open3d
from .bop import BopEstimate, read_bop_csv, write_bop_csv
from .features import read_open3d_feature
from .mesh import Mesh, sample_mesh
from .ply import write_ply
from .pointcloud import NonFinitePointsWarning, PointCloud
from .reader import MESH_SUFFIXES, SUPPORTED_SUFFIXES, load_points, read_mesh, read_point_cloud

__all__ = [
    "MESH_SUFFIXES",
    "SUPPORTED_SUFFIXES",
    "BopEstimate",
    "Mesh",
    "NonFinitePointsWarning",
    "PointCloud",
    "from_open3d",
    "load_points",
    "read_bop_csv",
    "read_mesh",
    "read_open3d_feature",
    "read_point_cloud",
    "sample_mesh",
    "to_open3d",
    "write_bop_csv",
    "write_ply",
]

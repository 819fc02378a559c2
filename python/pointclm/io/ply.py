"""The PLY format: a numpy reader (ASCII, binary little and big endian) and a binary writer.

Why our own reader rather than trimesh's: pointclm's default install is numpy-only and a
PLY header is a few lines of text, so one reader gives every user the same result whether or
not the ``[io]`` extra is installed; trimesh also returns a face-less PLY as a
``trimesh.PointCloud`` whose normals are reachable only through private metadata. The tests
check our reader against trimesh on the project's real files.

Speed: element tables whose records all have the same layout (every vertex table, and face
tables of triangles only) are read with one structured :func:`numpy.frombuffer` (binary) or
:func:`numpy.loadtxt` (ASCII); only tables with lists of varying length (mixed polygons,
range grids) fall back to a per-record loop, and elements after the last one needed (e.g.
a range scan's ``range_grid``) are never parsed.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from .files import atomic_path, check_output_path
from .mesh import Mesh, triangulate
from .ply_tables import _ascii_table, _binary_table, _Element, _ListValues, _Property, _Table
from .pointcloud import PointCloud, unit_colors

__all__ = ["parse_ply", "ply_mesh", "write_ply"]

_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
_MAX_HEADER_LINES = 10_000
#: Elements a reader needs; anything stored after the last of them is not parsed.
_NEEDED = ("vertex", "face")
_COLOR_NAMES = (("red", "green", "blue"), ("diffuse_red", "diffuse_green", "diffuse_blue"))


def _type_code(name: str, line: str) -> str:
    code = _TYPES.get(name)
    if code is None:
        raise ValueError(f"PLY header has unknown property type {name!r} in {line!r}")
    return code


def _parse_header(raw: bytes) -> tuple[str, list[_Element], int]:
    """Return the format name, the elements in file order, and where the data starts."""
    if not raw.startswith(b"ply"):
        raise ValueError("not a PLY file (does not start with 'ply')")
    fmt: str | None = None
    elements: list[_Element] = []
    current: list[_Property] = []
    pos = 0
    for _ in range(_MAX_HEADER_LINES):
        end = raw.find(b"\n", pos)
        if end < 0:
            raise ValueError("PLY header has no end_header line (file truncated?)")
        try:
            line = raw[pos:end].decode("ascii").strip()
        except UnicodeDecodeError:
            raise ValueError("PLY header is not ASCII text") from None
        pos = end + 1
        words = line.split()
        if not words or words[0] in ("comment", "obj_info", "ply"):
            continue
        key = words[0]
        if key == "end_header":
            break
        if key == "format":
            if len(words) < 2 or words[1] not in _FORMATS:
                raise ValueError(f"unsupported PLY format line {line!r}")
            fmt = words[1]
        elif key == "element":
            if len(words) != 3 or not (words[2].isascii() and words[2].isdigit()):
                raise ValueError(f"malformed PLY element line {line!r}")
            if len(words[2]) > 19:  # beyond int64: no file holds that many records
                raise ValueError(f"PLY element count too large in {line!r}")
            current = []
            elements.append(_Element(words[1], int(words[2]), ()))
        elif key == "property":
            if not elements:
                raise ValueError(f"PLY property before any element: {line!r}")
            if len(words) == 5 and words[1] == "list":
                prop = _Property(words[4], _type_code(words[3], line), _type_code(words[2], line))
            elif len(words) == 3:
                prop = _Property(words[2], _type_code(words[1], line))
            else:
                raise ValueError(f"malformed PLY property line {line!r}")
            current.append(prop)
            last = elements[-1]
            elements[-1] = _Element(last.name, last.count, tuple(current))
        else:
            raise ValueError(f"unexpected PLY header line {line!r}")
    else:
        raise ValueError(f"PLY header has no end_header in its first {_MAX_HEADER_LINES} lines")
    if fmt is None:
        raise ValueError("PLY header has no format line")
    return fmt, elements, pos


def _read_tables(raw: bytes) -> tuple[dict[str, _Table], dict[str, int | None]]:
    """Tables of the needed elements (the first of each name), parsed in file order, and
    for ASCII files the file line number of each one's first record (None for binary)."""
    fmt, elements, start = _parse_header(raw)
    wanted = [i for i, el in enumerate(elements) if el.name in _NEEDED]
    stop = max(wanted) + 1 if wanted else 0
    tables: dict[str, _Table] = {}
    first_lines: dict[str, int | None] = {}
    if fmt == "ascii":
        lines = raw[start:].decode("latin-1").splitlines()
        header_lines = raw.count(b"\n", 0, start)
        line = 0
        for el in elements[:stop]:
            if el.name in _NEEDED and el.name not in tables:
                first = header_lines + line + 1
                tables[el.name] = _ascii_table(lines, line, el, first)
                first_lines[el.name] = first
            line += el.count
    else:
        offset = start
        endian = _FORMATS[fmt]
        for el in elements[:stop]:
            table, offset = _binary_table(raw, offset, el, endian)
            if el.name not in tables:
                tables[el.name] = table
                first_lines[el.name] = None
    return tables, first_lines


def _check_face_indices(faces: _ListValues, n_vertices: int, first_line: int | None) -> None:
    """Every face index names a vertex; the message says which record (or line) does not."""
    items = faces.items
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(items) | (items != np.round(items)) | (items < 0)
        bad |= items >= n_vertices
    if not bad.any():
        return
    flat = int(np.argmax(bad))
    record = int(np.searchsorted(np.cumsum(faces.counts), flat, side="right"))
    where = f"line {first_line + record}" if first_line is not None else f"record {record}"
    value = items[flat]
    raise ValueError(
        f"PLY element 'face', {where}: vertex index {value} is not a vertex of the "
        f"{n_vertices} in the file"
    )


def parse_ply(raw: bytes, n_samples: int | None = None, seed: int | None = 0) -> PointCloud:
    """Read a PLY file's bytes: a mesh is sampled by area, a point cloud returned as is.

    Raises
    ------
    ValueError
        Malformed header, truncated data, no x/y/z vertex properties, face indices out of
        range, or no finite point (messages without the path; the caller adds it).
    """
    return ply_mesh(raw).sampled(n_samples, seed)


def ply_mesh(raw: bytes) -> Mesh:
    """Read a PLY file's bytes as stored: vertices, triangles (None without faces) and the
    vertices' normals and colours.

    Raises
    ------
    ValueError
        As :func:`parse_ply`, except that non-finite vertices are kept.
    """
    tables, first_lines = _read_tables(raw)
    vertex = tables.get("vertex")
    if vertex is None:
        raise ValueError("PLY file has no 'vertex' element")

    def stack(names: tuple[str, ...]) -> np.ndarray | None:
        if not all(isinstance(vertex.get(n), np.ndarray) for n in names):
            return None
        return np.stack([vertex[n] for n in names], axis=1)

    points = stack(("x", "y", "z"))
    if points is None:
        raise ValueError(f"PLY vertex element has no x, y, z properties (has: {', '.join(vertex)})")
    points = points.astype(np.float64)
    normals = stack(("nx", "ny", "nz"))
    colors = None
    for names in _COLOR_NAMES:
        channels = stack(names)
        if channels is not None:
            colors = unit_colors(channels)
            break
    triangles = _triangles(tables.get("face"), len(points), first_lines.get("face"))
    return Mesh(points, triangles, None if normals is None else normals.astype(np.float64), colors)


def _triangles(face: _Table | None, n_vertices: int, first_line: int | None) -> np.ndarray | None:
    """The face element's polygons as triangles, or None when there is no face to sample."""
    if face is None:
        return None
    lists = [v for v in face.values() if isinstance(v, _ListValues)]
    named = face.get("vertex_indices", face.get("vertex_index"))
    faces = named if isinstance(named, _ListValues) else (lists[0] if lists else None)
    if faces is None and face:
        raise ValueError("PLY face element has no list of vertex indices")
    if faces is None or not len(faces.counts):
        return None
    _check_face_indices(faces, n_vertices, first_line)
    return triangulate(faces.counts, faces.items.astype(np.int64))


def write_ply(
    path: str | os.PathLike[str],
    points: np.ndarray | PointCloud,
    colors: np.ndarray | None = None,
    normals: np.ndarray | None = None,
) -> None:
    """Write a point cloud as binary little-endian PLY.

    Coordinates and normals are stored as ``double`` so a cloud reads back bit for bit
    (float32 would round georeferenced coordinates to decimetres); colours as ``uchar``
    ``red``/``green``/``blue``, the layout every viewer (MeshLab, CloudCompare, Open3D,
    trimesh) understands.

    Parameters
    ----------
    path : str or os.PathLike
        Output file (overwritten).
    points : numpy.ndarray or PointCloud
        (N, 3) finite coordinates, N >= 1; a :class:`PointCloud` also supplies its normals
        and colours unless they are passed explicitly.
    colors : numpy.ndarray, optional
        (N, 3) floats in [0, 1] (rounded to 8 bits) or integers in [0, 255].
    normals : numpy.ndarray, optional
        (N, 3) finite normals.

    Raises
    ------
    ValueError
        On a wrong shape, non-finite values, colours out of range, or a path that is not a
        writable file name (checked before anything is written). The file is written to a
        temporary name and renamed, so a failure never leaves a partial PLY behind.
    """
    file = check_output_path(path, "path")
    if isinstance(points, PointCloud):
        colors = points.colors if colors is None else colors
        normals = points.normals if normals is None else normals
        points = points.points
    record, fields = _vertex_records(*_checked_columns(points, colors, normals))
    names = {"<f8": "double", "u1": "uchar"}
    header = [
        "ply",
        "format binary_little_endian 1.0",
        "comment written by pointclm",
        f"element vertex {len(record)}",
        *(f"property {names[code]} {name}" for name, code in fields),
        "end_header",
    ]
    with atomic_path(file) as tmp, open(tmp, "wb") as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        fh.write(record.tobytes())


def _checked_columns(
    points: Any, colors: Any, normals: Any
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Points, normals and 8-bit colours checked (all before anything is written)."""
    pts = _real(points, "points")
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise ValueError(f"points must be a non-empty (N, 3) array, got shape {pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError("points must be finite (PLY readers would choke on NaN/inf)")
    nrm = None
    if normals is not None:
        nrm = _real(normals, "normals")
        if nrm.shape != pts.shape:
            raise ValueError(f"normals must have shape {pts.shape}, got {nrm.shape}")
        if not np.isfinite(nrm).all():
            raise ValueError("normals must be finite")
    col = None if colors is None else _colors_u8(colors, pts.shape)
    return pts, nrm, col


def _vertex_records(
    pts: np.ndarray, nrm: np.ndarray | None, col: np.ndarray | None
) -> tuple[np.ndarray, list[tuple[str, str]]]:
    """One little-endian record per vertex (x y z, then nx ny nz, then red green blue) and
    the fields' names and types."""
    fields: list[tuple[str, str]] = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    if nrm is not None:
        fields += [("nx", "<f8"), ("ny", "<f8"), ("nz", "<f8")]
    if col is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    record = np.empty(len(pts), dtype=fields)
    for i, axis in enumerate("xyz"):
        record[axis] = pts[:, i]
        if nrm is not None:
            record[f"n{axis}"] = nrm[:, i]
    if col is not None:
        for i, channel in enumerate(("red", "green", "blue")):
            record[channel] = col[:, i]
    return record, fields


def _real(values: Any, name: str) -> np.ndarray:
    try:
        arr = np.asarray(values)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} could not be read as an array: {e}") from None
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"{name} must hold real numbers, got dtype {arr.dtype}")
    return arr.astype(np.float64)


def _colors_u8(colors: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    arr = np.asarray(colors)
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"colors must hold real numbers, got dtype {arr.dtype}")
    if arr.shape != shape:
        raise ValueError(f"colors must have shape {shape}, got {arr.shape}")
    if np.issubdtype(arr.dtype, np.integer):
        if arr.min() < 0 or arr.max() > 255:
            raise ValueError("integer colors must lie in [0, 255]")
        return arr.astype(np.uint8)
    values = arr.astype(np.float64)
    if not np.isfinite(values).all() or values.min() < 0.0 or values.max() > 1.0:
        raise ValueError("float colors must be finite and lie in [0, 1]")
    return np.round(values * 255.0).astype(np.uint8)

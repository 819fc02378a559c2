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
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from .files import atomic_path, check_output_path
from .mesh import Mesh, triangulate
from .pointcloud import PointCloud, check_integers, unit_colors

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


@dataclass(frozen=True)
class _Property:
    name: str
    code: str  # numpy type code of the value (of each item, for a list)
    count_code: str | None = None  # numpy type code of a list's length; None: scalar


@dataclass(frozen=True)
class _Element:
    name: str
    count: int
    props: tuple[_Property, ...]


@dataclass(frozen=True)
class _ListValues:
    """A list property of one element table: per-record lengths and all items, flat."""

    counts: np.ndarray
    items: np.ndarray


_Table = dict[str, Any]  # property name -> ndarray (scalar) or _ListValues


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


def _empty_table(el: _Element, endian: str = "<") -> _Table:
    out: _Table = {}
    for p in el.props:
        dt = np.dtype(endian + p.code)
        out[p.name] = (
            np.empty(0, dt)
            if p.count_code is None
            else _ListValues(np.empty(0, np.int64), np.empty(0, dt))
        )
    return out


def _first_record_layout(
    raw: bytes, offset: int, el: _Element, endian: str
) -> tuple[np.dtype[Any], list[int]] | None:
    """Record dtype if every record had the first one's list lengths (None: can't tell)."""
    lengths: list[int] = []
    fields: list[tuple[Any, ...]] = []
    pos = offset
    for i, p in enumerate(el.props):
        if p.count_code is None:
            fields.append((f"p{i}", endian + p.code))
            pos += np.dtype(p.code).itemsize
            continue
        count_dt = np.dtype(endian + p.count_code)
        if pos + count_dt.itemsize > len(raw):
            return None
        n = int(np.frombuffer(raw, count_dt, 1, pos)[0])
        if n < 0:
            raise ValueError(f"PLY element {el.name!r} has a list of negative length {n}")
        if pos + count_dt.itemsize + n * np.dtype(p.code).itemsize > len(raw):
            return None  # longer than the file: the record-by-record reader reports where
        lengths.append(n)
        fields.append((f"n{i}", count_dt))
        if n > 0:
            fields.append((f"p{i}", endian + p.code, (n,)))
        pos += count_dt.itemsize + n * np.dtype(p.code).itemsize
    return np.dtype(fields), lengths


def _min_record_size(el: _Element) -> int:
    """Bytes of the smallest possible record: scalars, and each list's length field."""
    return sum(np.dtype(p.count_code or p.code).itemsize for p in el.props)


def _binary_table(raw: bytes, offset: int, el: _Element, endian: str) -> tuple[_Table, int]:
    """Read one element table from binary data; returns it and the offset after it."""
    if el.count == 0 or not el.props:  # a record without properties holds no bytes
        return _empty_table(el, endian), offset
    # Checked before anything is allocated: every record takes at least this many bytes, so
    # a count the remaining bytes cannot hold is a lie (or a truncated file).
    need = el.count * _min_record_size(el)
    if need > len(raw) - offset:
        raise ValueError(
            f"binary PLY data is truncated: element {el.name!r} declares {el.count} records "
            f"of at least {_min_record_size(el)} bytes ({need} bytes), "
            f"{max(len(raw) - offset, 0)} remain"
        )
    layout = _first_record_layout(raw, offset, el, endian)
    if layout is not None:
        record, lengths = layout
        end = offset + el.count * record.itemsize
        if end > len(raw) and not lengths:
            raise ValueError(
                f"binary PLY data is truncated: element {el.name!r} needs "
                f"{el.count * record.itemsize} bytes, {max(len(raw) - offset, 0)} remain"
            )
        if end <= len(raw):
            table = np.frombuffer(raw, record, el.count, offset)
            list_ids = [i for i, p in enumerate(el.props) if p.count_code is not None]
            if all((table[f"n{i}"] == n).all() for i, n in zip(list_ids, lengths, strict=True)):
                out: _Table = {}
                for i, p in enumerate(el.props):
                    if p.count_code is None:
                        out[p.name] = table[f"p{i}"]
                        continue
                    n = lengths[list_ids.index(i)]
                    items = table[f"p{i}"].reshape(-1) if n else np.empty(0, endian + p.code)
                    out[p.name] = _ListValues(np.full(el.count, n, np.int64), items)
                return out, end
    return _binary_table_slow(raw, offset, el, endian)


#: Records the record-by-record readers hold as Python objects before packing them into
#: arrays: memory stays a small multiple of the file's size, not ~40 bytes per value.
_CHUNK = 65_536


class _Columns:
    """Per-property values of an element table, packed into typed arrays every `_CHUNK`
    records."""

    def __init__(self, el: _Element, endian: str = "") -> None:
        self.el, self.endian = el, endian
        self.scalars: list[list[Any]] = [[] for _ in el.props]
        self.counts: list[list[int]] = [[] for _ in el.props]
        self.items: list[list[Any]] = [[] for _ in el.props]
        self.done: list[list[Any]] = [[] for _ in el.props]

    def pack(self) -> None:
        for i, p in enumerate(self.el.props):
            dt = np.dtype(self.endian + p.code) if self.endian else np.float64
            if p.count_code is None:
                self.done[i].append(np.asarray(self.scalars[i], dtype=dt))
            else:
                counts = np.asarray(self.counts[i], np.int64)
                self.done[i].append((counts, np.asarray(self.items[i], dtype=dt)))
            self.scalars[i], self.counts[i], self.items[i] = [], [], []

    def table(self) -> dict[int, Any]:
        self.pack()
        out: dict[int, Any] = {}
        for i, p in enumerate(self.el.props):
            if p.count_code is None:
                out[i] = np.concatenate(self.done[i])
            else:
                counts = np.concatenate([c for c, _ in self.done[i]])
                out[i] = (counts, np.concatenate([v for _, v in self.done[i]]))
        return out


def _binary_table_slow(raw: bytes, offset: int, el: _Element, endian: str) -> tuple[_Table, int]:
    """Record-by-record reading, for lists whose lengths vary."""
    cols = _Columns(el, endian)
    formats = []
    for p in el.props:
        value = struct.Struct(endian + _struct_char(p.code))
        count = struct.Struct(endian + _struct_char(p.count_code)) if p.count_code else None
        formats.append((value, count, _struct_char(p.code)))
    pos = offset
    size = len(raw)
    for record in range(el.count):
        if record and record % _CHUNK == 0:
            cols.pack()
        for i, (value, count, char) in enumerate(formats):
            if count is None:
                if pos + value.size > size:
                    raise _truncated(el, record)
                cols.scalars[i].append(value.unpack_from(raw, pos)[0])
                pos += value.size
                continue
            if pos + count.size > size:
                raise _truncated(el, record)
            n = count.unpack_from(raw, pos)[0]
            if n < 0:
                raise ValueError(
                    f"PLY element {el.name!r} record {record} has a list of negative length {n}"
                )
            pos += count.size
            if pos + n * value.size > size:  # checked before struct builds an n-item tuple
                raise _truncated(el, record)
            cols.counts[i].append(n)
            cols.items[i].extend(struct.unpack_from(f"{endian}{n}{char}", raw, pos))
            pos += n * value.size
    table = cols.table()
    out: _Table = {}
    for i, p in enumerate(el.props):
        if p.count_code is None:
            out[p.name] = table[i]
        else:
            out[p.name] = _ListValues(*table[i])
    return out, pos


def _truncated(el: _Element, record: int) -> ValueError:
    return ValueError(
        f"binary PLY data is truncated inside element {el.name!r} at record {record} "
        f"({el.count} records expected)"
    )


def _struct_char(code: str | None) -> str:
    return {
        "i1": "b",
        "u1": "B",
        "i2": "h",
        "u2": "H",
        "i4": "i",
        "u4": "I",
        "f4": "f",
        "f8": "d",
    }[code or ""]


def _ascii_table(lines: list[str], start: int, el: _Element, first_line: int) -> _Table:
    """Read one element table from ASCII lines (one record per line, as writers do);
    ``first_line`` is the file line number of ``lines[start]``, for error messages."""
    rows = lines[start : start + el.count]
    if len(rows) < el.count:
        raise ValueError(
            f"ASCII PLY data is truncated: element {el.name!r} needs {el.count} lines, "
            f"{len(rows)} remain"
        )
    if el.count == 0:
        return _empty_table(el)
    try:
        table = np.loadtxt(rows, dtype=np.float64, ndmin=2, comments=None)
    except ValueError:
        table = None  # ragged (lists of varying length) or malformed: the slow path tells
    if table is not None and table.shape[0] == el.count:
        columns = _split_uniform(table, el, first_line)
        if columns is not None:
            return columns
    return _ascii_table_slow(rows, el, first_line)


def _as_declared(values: np.ndarray, code: str, el: _Element, name: str, lines: Any) -> np.ndarray:
    """Round ASCII values to their declared type, as a binary file of the same data would
    hold them (and as other readers do): ``float`` properties become float32. An integer
    value the type cannot hold (uchar 300, NaN, 2.5) is an error naming its line, never
    wrapped around. ``lines`` maps a row of ``values`` to its file line number."""
    if code[0] == "f":
        return values.astype(code)
    bad = check_integers(values, code)
    if bad is not None:
        row, value, why = bad
        raise ValueError(
            f"ASCII PLY element {el.name!r}, property {name!r}, line {lines(row)}: {value} is {why}"
        )
    return values.astype(code)


def _split_uniform(table: np.ndarray, el: _Element, first_line: int) -> _Table | None:
    """Cut a rectangular ASCII table into properties (None: lists vary in length)."""
    out: _Table = {}
    col = 0

    def line(row: int) -> int:
        return first_line + row

    for p in el.props:
        if col >= table.shape[1]:
            return None
        if p.count_code is None:
            out[p.name] = _as_declared(table[:, col], p.code, el, p.name, line)
            col += 1
            continue
        n = table[0, col]
        if not (np.isfinite(n) and n >= 0 and n == int(n)) or not (table[:, col] == n).all():
            return None
        n = int(n)
        if col + 1 + n > table.shape[1]:
            return None
        _as_declared(table[:, col], p.count_code, el, p.name, line)
        items = _as_declared(table[:, col + 1 : col + 1 + n], p.code, el, p.name, line)
        out[p.name] = _ListValues(np.full(el.count, n, np.int64), items.reshape(-1))
        col += 1 + n
    return out if col == table.shape[1] else None


def _ascii_table_slow(rows: list[str], el: _Element, first_line: int) -> _Table:
    """Record-by-record reading, for lists whose lengths vary."""
    cols = _Columns(el)
    row = ""
    k_row = 0
    try:
        for k_row, row in enumerate(rows):
            if k_row and k_row % _CHUNK == 0:
                cols.pack()
            words = row.split()
            k = 0
            for i, p in enumerate(el.props):
                if p.count_code is None:
                    cols.scalars[i].append(float(words[k]))
                    k += 1
                else:
                    n = int(words[k])
                    if n < 0 or k + 1 + n > len(words):
                        raise IndexError
                    cols.counts[i].append(n)
                    cols.items[i].extend(float(w) for w in words[k + 1 : k + 1 + n])
                    k += 1 + n
    except (IndexError, ValueError, OverflowError):
        props = " ".join(p.name if p.count_code is None else f"[{p.name}]" for p in el.props)
        raise ValueError(
            f"malformed ASCII PLY data in element {el.name!r} (properties: {props}) "
            f"on line {first_line + k_row}: {row[:80]!r}"
        ) from None
    table = cols.table()
    out: _Table = {}
    for i, p in enumerate(el.props):
        if p.count_code is None:

            def line(r: int) -> int:
                return first_line + r

            out[p.name] = _as_declared(table[i], p.code, el, p.name, line)
        else:
            counts, flat = table[i]
            ends = np.cumsum(counts)

            def item_line(r: int, ends: np.ndarray = ends) -> int:
                return first_line + int(np.searchsorted(ends, r, side="right"))

            out[p.name] = _ListValues(counts, _as_declared(flat, p.code, el, p.name, item_line))
    return out


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

"""PCL's PCD format (v0.5 to v0.7): ``DATA ascii``, ``binary`` and ``binary_compressed``.

Why our own reader: the maintained pure-Python option on PyPI, ``pypcd4`` (BSD-3-Clause),
pulls in pydantic and the C extension ``python-neo-lzf`` for one decompression call; the
format itself is a dozen header lines and three data layouts, so a numpy reader with our
pure-Python LZF decoder (:mod:`pointclm.io.lzf`) keeps ``pip install pointclm`` enough.

Layouts, as PCL writes them:

- ``ascii``: one point per line, the fields' values in header order.
- ``binary``: packed records (array of structs), little-endian.
- ``binary_compressed``: uint32 compressed size, uint32 raw size, then one LZF block whose
  raw bytes hold each field for all points in turn (struct of arrays).

Organised clouds (HEIGHT > 1, from depth cameras) mark missing pixels with NaN xyz; those
points are dropped, and the normals and colours stay aligned with the kept points.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass

import numpy as np

from .lzf import LZF_MAX_EXPANSION, lzf_decompress
from .pointcloud import PointCloud, check_integers, finite_cloud

__all__ = ["parse_pcd", "pcd_is_organised", "pcd_viewpoint", "read_pcd_viewpoint"]

_MAX_HEADER_LINES = 256
_TYPE_CHARS = {("F", 4): "f4", ("F", 8): "f8"}
_TYPE_CHARS.update({("I", s): f"i{s}" for s in (1, 2, 4, 8)})
_TYPE_CHARS.update({("U", s): f"u{s}" for s in (1, 2, 4, 8)})


@dataclass(frozen=True)
class _Field:
    name: str
    dtype: np.dtype
    count: int


@dataclass(frozen=True)
class _Header:
    fields: tuple[_Field, ...]
    n_points: int
    data: str
    data_start: int
    #: The VIEWPOINT line's words (tx ty tz qw qx qy qz), () when the header has none.
    viewpoint: tuple[str, ...] = ()
    #: Rows of an organised cloud (a depth frame); 1 for an unorganised one.
    height: int = 1


def _parse_header(raw: bytes) -> _Header:
    """Read the header lines up to and including ``DATA``."""
    entries, pos = _header_entries(raw)
    for key in ("FIELDS", "SIZE", "TYPE", "WIDTH"):
        if key not in entries:
            raise ValueError(f"PCD header has no {key} line")
    columns = _field_columns(entries)
    width = _header_int(entries, "WIDTH")
    height = _header_int(entries, "HEIGHT") if "HEIGHT" in entries else 1
    n_points = _header_int(entries, "POINTS") if "POINTS" in entries else width * height
    fields = _header_fields(columns, len(raw))
    if n_points < 0 or width < 0 or height < 0:
        raise ValueError("malformed PCD header (negative WIDTH, HEIGHT or POINTS)")
    data = entries["DATA"][0].lower() if entries["DATA"] else ""
    viewpoint = tuple(entries.get("VIEWPOINT", ()))
    return _Header(tuple(fields), n_points, data, pos, viewpoint, height)


#: The header's keywords (any other line means this is not a PCD file).
_HEADER_KEYS = frozenset(
    ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")
)


def _header_entries(raw: bytes) -> tuple[dict[str, list[str]], int]:
    """Each header keyword's words, up to the ``DATA`` line, and the offset after it."""
    entries: dict[str, list[str]] = {}
    pos = 0
    for _ in range(_MAX_HEADER_LINES):
        end = raw.find(b"\n", pos)
        if end < 0:
            raise ValueError("PCD header has no DATA line (file truncated or not a PCD file)")
        try:
            line = raw[pos:end].decode("ascii").strip()
        except UnicodeDecodeError:
            raise ValueError("not a PCD file (header is not ASCII text)") from None
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        key = key.upper()
        if key not in _HEADER_KEYS:
            raise ValueError(f"not a PCD file (unexpected header line {line[:60]!r})")
        entries[key] = values
        if key == "DATA":
            return entries, pos
    raise ValueError(f"PCD header has no DATA line in its first {_MAX_HEADER_LINES} lines")


def _field_columns(entries: dict[str, list[str]]) -> list[tuple[str, str, str, str]]:
    """Per field: the words of its FIELDS, SIZE, TYPE and COUNT lines (COUNT 1 if absent)."""
    names = entries["FIELDS"]
    sizes = entries["SIZE"]
    types = entries["TYPE"]
    counts = entries.get("COUNT", ["1"] * len(names))
    if not (len(names) == len(sizes) == len(types) == len(counts)) or not names:
        raise ValueError(
            "PCD header's FIELDS, SIZE, TYPE and COUNT lines have different lengths "
            f"({len(names)}, {len(sizes)}, {len(types)}, {len(counts)})"
        )
    return list(zip(names, sizes, types, counts, strict=True))


def _header_fields(columns: list[tuple[str, str, str, str]], file_size: int) -> list[_Field]:
    """The fields typed, each checked against the file's size."""
    fields = []
    for name, size, kind, count in columns:
        char = _TYPE_CHARS.get((kind.upper(), _as_int(size, f"SIZE of field {name!r}")))
        if char is None:
            raise ValueError(f"PCD field {name!r} has unsupported TYPE {kind} SIZE {size}")
        n = _as_int(count, f"COUNT of field {name!r}")
        if n < 1:
            raise ValueError(f"malformed PCD header: COUNT of field {name!r} is {n}, need >= 1")
        if n * int(size) > file_size:
            # No point can be longer than the whole file (and numpy could not even describe
            # a record that size): a lying COUNT is refused before any allocation.
            raise ValueError(
                f"malformed PCD header: field {name!r} has COUNT {n} ({n * int(size)} bytes "
                f"per point), more than the file's {file_size} bytes"
            )
        fields.append(_Field(name, np.dtype("<" + char), n))
    return fields


def _header_int(entries: dict[str, list[str]], key: str) -> int:
    values = entries[key]
    if not values:
        raise ValueError(f"malformed PCD header: {key} has no value")
    return _as_int(values[0], key)


def _as_int(word: str, what: str) -> int:
    # int() alone accepts "1_000" and unbounded digit strings; a header holds plain decimals.
    if not (word.isascii() and word.lstrip("+-").isdigit()) or len(word) > 20:
        raise ValueError(f"malformed PCD header: {what} is {word[:30]!r}, not an integer")
    return int(word)


def _record_size(header: _Header) -> int:
    return sum(f.count * f.dtype.itemsize for f in header.fields)


def _columns_binary(raw: bytes, header: _Header) -> list[np.ndarray]:
    size = _record_size(header)
    need = header.n_points * size
    have = len(raw) - header.data_start
    if have < need:
        raise ValueError(
            f"binary PCD data is truncated: {header.n_points} points of {size} "
            f"bytes need {need} bytes, the file has {have}"
        )
    record = np.dtype(
        [(f"f{i}", f.dtype, (f.count,)) for i, f in enumerate(header.fields)], align=False
    )
    table = np.frombuffer(raw, dtype=record, count=header.n_points, offset=header.data_start)
    return [table[f"f{i}"] for i in range(len(header.fields))]


def _columns_compressed(raw: bytes, header: _Header) -> list[np.ndarray]:
    start = header.data_start
    if len(raw) < start + 8:
        raise ValueError("binary_compressed PCD data is truncated (no block sizes)")
    packed, unpacked = struct.unpack_from("<II", raw, start)
    expected = header.n_points * _record_size(header)
    if unpacked != expected:
        raise ValueError(
            f"binary_compressed PCD block holds {unpacked} bytes, but {header.n_points} points "
            f"of these fields need {expected}"
        )
    have = len(raw) - start - 8
    if packed > have:
        raise ValueError(
            f"binary_compressed PCD data is truncated: the block is {packed} bytes, "
            f"the file has {have}"
        )
    # Checked before the output buffer is allocated: LZF cannot expand more than this, so a
    # header claiming more is lying (a few hundred bytes must not reserve gigabytes).
    if unpacked > LZF_MAX_EXPANSION * packed:
        raise ValueError(
            f"binary_compressed PCD block claims {unpacked} bytes from {packed} compressed "
            f"bytes; LZF expands at most {LZF_MAX_EXPANSION}x"
        )
    block = raw[start + 8 : start + 8 + packed]
    data = lzf_decompress(block, unpacked) if unpacked else b""
    columns = []
    offset = 0
    for f in header.fields:
        n = header.n_points * f.count
        col = np.frombuffer(data, dtype=f.dtype, count=n, offset=offset)
        columns.append(col.reshape(header.n_points, f.count))
        offset += n * f.dtype.itemsize
    return columns


def _columns_ascii(raw: bytes, header: _Header) -> list[np.ndarray]:
    first_line = raw.count(b"\n", 0, header.data_start) + 1  # file line of the first row
    text = raw[header.data_start :].decode("ascii", errors="replace").splitlines()
    width = sum(f.count for f in header.fields)
    numbered = [(first_line + i, line) for i, line in enumerate(text) if line.strip()]
    numbered = numbered[: header.n_points]
    if len(numbered) < header.n_points:
        raise ValueError(
            f"ASCII PCD data is truncated: header says {header.n_points} points, "
            f"found {len(numbered)} lines"
        )
    lines = [line for _, line in numbered]
    try:
        table = np.loadtxt(lines, dtype=np.float64, ndmin=2) if lines else np.empty((0, width))
    except ValueError as exc:
        raise ValueError(f"malformed ASCII PCD data ({exc})") from None
    if table.shape[1] != width:
        raise ValueError(f"ASCII PCD rows have {table.shape[1]} values, the fields need {width}")
    columns = []
    col = 0
    for f in header.fields:
        values = table[:, col : col + f.count]
        if f.dtype.kind == "f":
            columns.append(values.astype(f.dtype))
        else:
            # Integer fields (e.g. rgb written as uint32) are exact in float64 up to 2**53.
            bad = check_integers(values, f.dtype)
            if bad is not None:
                row, value, why = bad
                raise ValueError(
                    f"ASCII PCD field {f.name!r} on line {numbered[row][0]} holds {value}, {why}"
                )
            columns.append(values.astype(f.dtype))
        col += f.count
    return columns


def _packed_rgb(column: np.ndarray) -> np.ndarray:
    """Unpack PCL's 0x00RRGGBB (rgb) / 0xAARRGGBB (rgba), stored as float32 or uint32 bits."""
    flat = np.ascontiguousarray(column[:, 0])
    bits = flat.view(np.uint32) if flat.dtype.itemsize == 4 else flat.astype(np.uint32)
    rgb = np.stack([(bits >> 16) & 0xFF, (bits >> 8) & 0xFF, bits & 0xFF], axis=1)
    return rgb.astype(np.float64) / 255.0


def parse_pcd(raw: bytes) -> PointCloud:
    """Read a PCD file's bytes into a cloud of its finite points.

    Raises
    ------
    ValueError
        Malformed header, unsupported DATA layout, truncated data, no x/y/z fields, or no
        finite point (messages without the path; :func:`pointclm.io.read_point_cloud`
        adds it).
    """
    header = _parse_header(raw)
    if header.data == "ascii":
        columns = _columns_ascii(raw, header)
    elif header.data == "binary":
        columns = _columns_binary(raw, header)
    elif header.data == "binary_compressed":
        columns = _columns_compressed(raw, header)
    else:
        raise ValueError(
            f"unsupported PCD DATA {header.data!r} (supported: ascii, binary, binary_compressed)"
        )
    by_name: dict[str, np.ndarray] = {}
    for f, col in zip(header.fields, columns, strict=True):
        by_name.setdefault(f.name, col)

    def stack(names: tuple[str, str, str]) -> np.ndarray | None:
        if not all(n in by_name for n in names):
            return None
        return np.concatenate([by_name[n][:, :1] for n in names], axis=1).astype(np.float64)

    points = stack(("x", "y", "z"))
    if points is None:
        raise ValueError(f"PCD file has no x y z fields (fields: {' '.join(by_name)})")
    normals = stack(("normal_x", "normal_y", "normal_z"))
    colors: np.ndarray | None = None
    for name in ("rgb", "rgba"):
        packed = by_name.get(name)
        if packed is not None and packed.dtype.itemsize == 4:
            colors = _packed_rgb(packed)
            break
    return finite_cloud(points, normals, colors)


#: PCL's VIEWPOINT when nothing set it (sensor at the origin, no rotation): every PCL cloud
#: carries it, so it says nothing about where a sensor stood.
_DEFAULT_VIEWPOINT = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)


def pcd_viewpoint(raw: bytes) -> np.ndarray | None:
    """The sensor position (3,) a PCD file's header records in its ``VIEWPOINT`` line (the
    translation ``tx ty tz``; the orientation ``qw qx qy qz`` is not needed to know where the
    sensor was). PCL writes its default (the origin, no rotation) whatever the sensor, so that
    default (or no line) says where the sensor was only for an organised cloud (``HEIGHT`` >
    1): a depth frame in its sensor's coordinates, whose sensor is the origin; for an
    unorganised one it gives None.

    Raises ValueError for a malformed header or a VIEWPOINT that is not 7 finite numbers.
    """
    header = _parse_header(raw)
    words = header.viewpoint
    values: tuple[float, ...] = _DEFAULT_VIEWPOINT
    if words:
        try:
            values = tuple(float(w) for w in words)
        except ValueError:
            values = ()
        if len(values) != 7 or not np.isfinite(values).all():
            raise ValueError(
                f"malformed PCD header: VIEWPOINT needs 7 numbers, got {' '.join(words)!r}"
            )
    if values == _DEFAULT_VIEWPOINT:
        return np.zeros(3) if header.height > 1 else None
    return np.array(values[:3])


#: The header is read from at most this many leading bytes (256 lines of a few words each).
_HEADER_BYTES = 1 << 16


def read_pcd_viewpoint(path: str | os.PathLike[str]) -> np.ndarray | None:
    """:func:`pcd_viewpoint` of the PCD file at `path`, reading only its header."""
    try:
        return pcd_viewpoint(_head(path))
    except ValueError as e:
        raise ValueError(f"{os.fspath(path)}: {e}") from None


def pcd_is_organised(path: str | os.PathLike[str]) -> bool:
    """Whether the PCD file at `path` holds an organised cloud (``HEIGHT`` > 1), reading
    only its header."""
    try:
        return _parse_header(_head(path)).height > 1
    except ValueError as e:
        raise ValueError(f"{os.fspath(path)}: {e}") from None


def _head(path: str | os.PathLike[str]) -> bytes:
    with open(path, "rb") as f:
        return f.read(_HEADER_BYTES)

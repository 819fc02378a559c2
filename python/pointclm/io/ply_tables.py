"""PLY element tables: the header's element and property types, and the readers that turn
one element's records (binary or ASCII) into per-property numpy arrays.

Kept apart from :mod:`pointclm.io.ply` because decoding records is the bulk of the reader and
has no need of the header grammar or of the mesh built from the tables.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from .pointcloud import check_integers


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

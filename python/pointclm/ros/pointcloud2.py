"""Reading a ``sensor_msgs/PointCloud2`` from its bytes and layout, without ROS.

A PointCloud2 is ``height`` rows of ``width`` points; each point is ``point_step`` bytes
holding the named ``fields`` at their offsets, each row ``row_step`` bytes (a row may end
with padding), in the byte order ``is_bigendian`` gives. Organised clouds (height > 1, from
depth cameras) mark a pixel without a return with NaN coordinates; those points are dropped
and counted in :attr:`PointCloud.dropped` (no warning: every organised frame has them).

Only the fields read are checked: ``x``, ``y``, ``z`` (required), ``normal_x``, ``normal_y``,
``normal_z`` (all three or none) as FLOAT32 or FLOAT64, and a packed ``rgb``/``rgba``
colour (FLOAT32 or UINT32, PCL's layout) when present. Other fields (intensity, ring,
time) are skipped. Every size is checked against the data's length before anything is
read, so a wrong layout is a :class:`ValueError` saying what does not fit, never a crash.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..io.pointcloud import PointCloud, finite_cloud

__all__ = ["DATATYPES", "parse_pointcloud2", "read_pointcloud2"]

#: ``sensor_msgs/PointField`` datatype constants and their numpy types.
DATATYPES: dict[int, str] = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
_FLOATS = (7, 8)
_XYZ = ("x", "y", "z")
_NORMALS = ("normal_x", "normal_y", "normal_z")
_MESSAGE_KEYS = ("height", "width", "fields", "is_bigendian", "point_step", "row_step", "data")


def read_pointcloud2(message: Any) -> PointCloud:
    """The points of a ``sensor_msgs/PointCloud2`` message.

    Parameters
    ----------
    message : message object or mapping
        An rclpy message, a message deserialised by ``rosbags``, any object with the
        message's attributes, or a dict with its keys (``height``, ``width``, ``fields``,
        ``is_bigendian``, ``point_step``, ``row_step``, ``data``). ``fields`` are
        ``PointField`` objects or dicts (``name``, ``offset``, ``datatype``, ``count``);
        ``data`` is bytes, a bytearray, a memoryview, an ``array.array('B')`` or a uint8
        numpy array.

    Returns
    -------
    PointCloud
        Finite points (N, 3) float64, with normals and colours when the message has them;
        ``dropped`` counts the points with NaN/inf coordinates (missing returns).

    Raises
    ------
    ValueError
        If a key is missing, the layout does not fit the data, x/y/z are missing or not
        FLOAT32/FLOAT64, or no point is finite.
    """
    values: dict[str, Any]
    if isinstance(message, Mapping):
        missing = [k for k in _MESSAGE_KEYS if k not in message]
        values = {k: message.get(k) for k in _MESSAGE_KEYS}
    else:
        missing = [k for k in _MESSAGE_KEYS if not hasattr(message, k)]
        values = {k: getattr(message, k, None) for k in _MESSAGE_KEYS}
    if missing:
        raise ValueError(
            f"not a sensor_msgs/PointCloud2: {type(message).__name__} has no {', '.join(missing)}"
        )
    return parse_pointcloud2(
        values["data"],
        fields=values["fields"],
        height=values["height"],
        width=values["width"],
        point_step=values["point_step"],
        row_step=values["row_step"],
        is_bigendian=values["is_bigendian"],
    )


def parse_pointcloud2(
    data: Any,
    *,
    fields: Sequence[Any],
    height: int,
    width: int,
    point_step: int,
    row_step: int | None = None,
    is_bigendian: bool = False,
) -> PointCloud:
    """The points of a PointCloud2 given as its raw ``data`` bytes and its layout (the
    message's other fields); see :func:`read_pointcloud2`. ``row_step`` defaults to
    ``width * point_step`` (no row padding)."""
    height = _count(height, "height")
    width = _count(width, "width")
    point_step = _count(point_step, "point_step")
    row_step = width * point_step if row_step is None else _count(row_step, "row_step")
    if point_step == 0:
        raise ValueError("point_step must be > 0")
    if row_step < width * point_step:
        raise ValueError(
            f"row_step {row_step} is shorter than a row of {width} points of {point_step} bytes"
        )
    buf = _byte_array(data)
    if height == 0 or width == 0:
        raise ValueError(f"the cloud is empty (height {height}, width {width})")
    need = (height - 1) * row_step + width * point_step
    if not need <= len(buf) <= height * row_step:
        raise ValueError(
            f"data holds {len(buf)} bytes, but height {height} x row_step {row_step} is "
            f"{height * row_step} (at least {need}): the layout does not describe this data"
        )
    layout = _layout(fields, point_step)
    order = ">" if is_bigendian else "<"
    dtype = np.dtype(
        {
            "names": list(layout),
            "formats": [order + fmt for fmt, _ in layout.values()],
            "offsets": [off for _, off in layout.values()],
            "itemsize": point_step,
        }
    )
    grid = np.ndarray((height, width), dtype, buffer=buf, strides=(row_step, point_step))
    table = grid.reshape(-1)

    def stack(names: tuple[str, ...]) -> np.ndarray:
        return np.column_stack([table[n].astype(np.float64) for n in names])

    points = stack(_XYZ)
    normals = stack(_NORMALS) if _NORMALS[0] in layout else None
    colors = _colors(table, layout)
    return finite_cloud(points, normals, colors)


def _count(value: Any, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
        raise ValueError(f"{name} must be a non-negative int, got {value!r}")
    return int(value)


def _byte_array(data: Any) -> np.ndarray:
    """The message's data as a flat uint8 array (no copy for bytes-like data)."""
    if isinstance(data, np.ndarray) and data.dtype.itemsize != 1:
        raise ValueError(f"data must be bytes or uint8 values, got a {data.dtype} array")
    try:
        view = memoryview(data)
    except TypeError:
        view = None
    if view is not None:
        if not view.contiguous:
            return np.frombuffer(view.tobytes(), np.uint8)
        return np.frombuffer(view.cast("B"), np.uint8)
    values = np.asarray(data)
    if values.ndim != 1 or values.dtype.kind not in "iu" and values.size:
        raise ValueError(f"data must be bytes or uint8 values, got {type(data).__name__}")
    if values.size and (values.min() < 0 or values.max() > 255):
        raise ValueError("data values must lie in [0, 255] (bytes)")
    return values.astype(np.uint8)


def _field(field: Any) -> tuple[str, int, int, int]:
    def get(key: str, default: Any = None) -> Any:
        if isinstance(field, Mapping):
            return field.get(key, default)
        return getattr(field, key, default)

    name, offset, datatype, count = get("name"), get("offset"), get("datatype"), get("count", 1)
    if not isinstance(name, str):
        raise ValueError(f"a PointField has no name: {field!r}")
    for what, value in (("offset", offset), ("datatype", datatype), ("count", count)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise ValueError(f"field {name!r}: {what} must be an int, got {value!r}")
    return name, int(offset), int(datatype), int(count)


def _layout(fields: Sequence[Any], point_step: int) -> dict[str, tuple[str, int]]:
    """numpy format and offset of each field read, checked to lie inside a point."""
    if isinstance(fields, str | bytes) or not isinstance(fields, Sequence | np.ndarray):
        raise ValueError(f"fields must be a list of PointFields, got {type(fields).__name__}")
    found: dict[str, tuple[int, int, int]] = {}
    for f in fields:
        name, offset, datatype, count = _field(f)
        if name in found:
            raise ValueError(f"the field {name!r} appears twice")
        found[name] = (offset, datatype, count)
    missing = [n for n in _XYZ if n not in found]
    if missing:
        raise ValueError(
            f"no {', '.join(missing)} field (fields: {', '.join(found) or 'none'}); a "
            "PointCloud2 of points needs x, y and z"
        )
    wanted = list(_XYZ)
    present = [n for n in _NORMALS if n in found]
    if present and len(present) != 3:
        raise ValueError(f"normals need normal_x, normal_y and normal_z; got {present}")
    wanted += present
    colour = next((n for n in ("rgb", "rgba") if n in found), None)
    layout = {}
    for name in [*wanted, *([colour] if colour else [])]:
        offset, datatype, count = found[name]
        allowed = _FLOATS if name != colour else (6, 7)
        if datatype not in allowed:
            kinds = "FLOAT32 (7) or FLOAT64 (8)" if name != colour else "UINT32 (6) or FLOAT32 (7)"
            raise ValueError(f"field {name!r} has datatype {datatype}; expected {kinds}")
        if count != 1:
            raise ValueError(f"field {name!r} has count {count}; expected 1")
        fmt = DATATYPES[datatype] if name != colour else "u4"
        size = np.dtype(fmt).itemsize
        if offset < 0 or offset + size > point_step:
            raise ValueError(
                f"field {name!r} at offset {offset} ({size} bytes) does not fit in a point of "
                f"point_step {point_step} bytes"
            )
        layout[name] = (fmt, offset)
    return layout


def _colors(table: np.ndarray, layout: dict[str, tuple[str, int]]) -> np.ndarray | None:
    """PCL's packed colour: 0x00RRGGBB (rgba: 0xAARRGGBB) in one 32-bit word."""
    name = next((n for n in ("rgb", "rgba") if n in layout), None)
    if name is None:
        return None
    packed = table[name].astype(np.uint32)
    rgb = np.column_stack([(packed >> s) & 0xFF for s in (16, 8, 0)])
    return rgb.astype(np.float64) / 255.0

"""Terrestrial and airborne scanner files: LAS/LAZ through laspy, E57 through pye57.

Both libraries are optional (``pip install 'pointclm[io]'``) and imported only when such a
file is read; without them the error names the extra to install. ``.laz`` also needs a LAZ
backend for laspy (``lazrs``, in the same extra).

The hardening rules of the other readers hold here too, applied before the libraries
allocate anything: only regular, non-empty files are opened, and the number of points a
file declares is checked against its length.

- **LAS** stores fixed-size records: the header's point count times the record size must
  fit between the point data offset and the end of the file (a truncated file is refused,
  naming both sizes).
- **LAZ** compresses them, by 4 to 8 times on real scans; a file of identical points
  compresses by thousands, which is also what a hostile header would claim. A LAZ file may
  declare at most :data:`LAZ_MAX_POINTS_PER_BYTE` points per byte (half a bit per point, far
  below any real scan), which bounds memory to a fixed multiple of the file's length.
- **E57** encodes each coordinate in at least a few bits on real scans (scaled integers or
  floats); a file may declare at most one point per byte of its length.

Points are returned in the file's own frame: LAS coordinates with their scale and offset
applied, E57 scans moved by their pose into the file's common frame and concatenated.
Colours come along where the file has them; LAS and E57 carry no normals. Invalid E57
points (``cartesianInvalidState`` or ``sphericalInvalidState`` not 0) and NaN coordinates
are dropped and counted in :attr:`PointCloud.dropped`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from .files import regular_file
from .pointcloud import PointCloud, finite_cloud

__all__ = ["LAZ_MAX_POINTS_PER_BYTE", "SCANNER_SUFFIXES", "read_scanner_file"]

#: Extensions read here, by a library of the ``[io]`` extra.
SCANNER_SUFFIXES: tuple[str, ...] = (".las", ".laz", ".e57")

#: Points a LAZ file may declare per byte of its length (see the module documentation).
LAZ_MAX_POINTS_PER_BYTE = 16
_INSTALL = "pip install 'pointclm[io]'"


def read_scanner_file(path: str | os.PathLike[str]) -> tuple[Path, PointCloud]:
    """Read a ``.las``, ``.laz`` or ``.e57`` file into a :class:`PointCloud`.

    Returns
    -------
    tuple
        The path (as a :class:`~pathlib.Path`) and the cloud.

    Raises
    ------
    PathNotFoundError
        If the file is missing.
    ValueError
        If it is empty, not a regular file, truncated, malformed, declares more points than
        its length can hold, or has no finite point; the message starts with the path.
    ImportError
        If laspy (``.las``/``.laz``), a LAZ backend (``.laz``) or pye57 (``.e57``) is not
        installed; the message names ``pip install 'pointclm[io]'``.
    """
    file = regular_file(path, "point cloud file")
    size = file.stat().st_size
    if size == 0:
        raise ValueError(f"{file}: the file is empty (0 bytes)")
    suffix = file.suffix.lower()
    if suffix not in SCANNER_SUFFIXES:
        raise ValueError(f"{file}: not a scanner file ({', '.join(SCANNER_SUFFIXES)})")
    reader = _read_e57 if suffix == ".e57" else _read_las
    try:
        return file, reader(file, size)
    except ImportError:
        raise
    except Exception as err:  # noqa: BLE001 - the libraries' own errors become ValueErrors
        if isinstance(err, ValueError) and str(err).startswith(str(file)):
            raise  # ours, already naming the file
        raise ValueError(
            f"{file}: cannot read it as {suffix[1:].upper()} "
            f"({type(err).__name__}: {_first_line(err)}); "
            "check that the file is complete and was written by a scanner or a LAS/E57 library"
        ) from err


def _first_line(err: BaseException) -> str:
    # libE57Format appends a multi-line debug trace to its messages.
    lines = str(err).strip().splitlines()
    return lines[0] if lines else type(err).__name__


def _laspy() -> Any:
    try:
        import laspy
    except ImportError:
        raise ImportError(f"reading .las/.laz files needs laspy: {_INSTALL}") from None
    return laspy


def _read_las(file: Path, size: int) -> PointCloud:
    laspy = _laspy()
    try:
        reader = laspy.open(str(file))
    except laspy.errors.LaspyException as err:
        raise ValueError(f"{file}: not a valid LAS/LAZ file ({err})") from None
    with reader:
        header = reader.header
        count = int(header.point_count)
        record = int(header.point_format.size)
        start = int(header.offset_to_point_data)
        if header.are_points_compressed:
            _check_laz(file, size, count, laspy)
        elif start + count * record > size:
            raise ValueError(
                f"{file}: truncated: the header declares {count} points of {record} bytes "
                f"from byte {start} ({start + count * record} bytes), the file has {size}"
            )
        if count == 0:
            raise ValueError(f"{file}: the file holds no point (its header declares 0)")
        las = reader.read()
    points = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)])
    if len(points) != count:
        raise ValueError(f"{file}: truncated: {len(points)} of the {count} points declared")
    return finite_cloud(points, colors=_las_colors(las))


def _check_laz(file: Path, size: int, count: int, laspy: Any) -> None:
    if count > LAZ_MAX_POINTS_PER_BYTE * size:
        raise ValueError(
            f"{file}: the header declares {count} points, more than a {size}-byte LAZ file "
            f"can hold (at most {LAZ_MAX_POINTS_PER_BYTE} per byte); the file is damaged"
        )
    if not laspy.LazBackend.detect_available():
        raise ImportError(
            f"{file}: reading .laz files needs a LAZ backend for laspy (lazrs): {_INSTALL} "
            "(or pip install 'laspy[lazrs]')"
        )


def _las_colors(las: Any) -> np.ndarray | None:
    names = set(las.point_format.dimension_names)
    if not {"red", "green", "blue"} <= names:
        return None
    rgb = np.column_stack([np.asarray(las[c], dtype=np.float64) for c in ("red", "green", "blue")])
    # LAS colours are 16-bit, but many writers store 8-bit values in them unscaled.
    top = 255.0 if rgb.size and rgb.max() <= 255 else 65535.0
    return np.clip(rgb / top, 0.0, 1.0)


def _pye57() -> Any:
    try:
        import pye57
    except ImportError:
        raise ImportError(f"reading .e57 files needs pye57: {_INSTALL}") from None
    return pye57


def _read_e57(file: Path, size: int) -> PointCloud:
    pye57 = _pye57()
    try:
        e57 = pye57.E57(str(file))
    except Exception as err:  # noqa: BLE001 - libE57Format's errors for a damaged file
        raise ValueError(f"{file}: not a valid E57 file ({_first_line(err)})") from None
    try:
        headers = [e57.get_header(i) for i in range(e57.scan_count)]
        declared = sum(int(h.point_count) for h in headers)
        if declared > size:
            raise ValueError(
                f"{file}: its scans declare {declared} points, more than a {size}-byte file "
                "can hold; the file is damaged"
            )
        if declared == 0:
            raise ValueError(f"{file}: the file holds no point ({len(headers)} scans)")
        parts = [_e57_scan(e57, i, h) for i, h in enumerate(headers)]
    finally:
        e57.close()
    points = np.concatenate([p for p, _ in parts])
    with_colour = all(c is not None for _, c in parts)
    colors = np.concatenate([c for _, c in parts if c is not None]) if with_colour else None
    cloud = finite_cloud(points, colors=colors)
    invalid = declared - len(points)
    return PointCloud(cloud.points, cloud.normals, cloud.colors, cloud.dropped + invalid)


def _e57_scan(e57: Any, index: int, header: Any) -> tuple[np.ndarray, np.ndarray | None]:
    """One scan's points in the file's frame (invalid points left out), and its colours."""
    fields = set(header.point_fields)
    colors = {"colorRed", "colorGreen", "colorBlue"} <= fields
    data = e57.read_scan(index, colors=colors, ignore_missing_fields=True, transform=True)
    points = np.column_stack([data["cartesianX"], data["cartesianY"], data["cartesianZ"]])
    if not colors:
        return points.astype(np.float64), None
    rgb = np.column_stack([data[c] for c in ("colorRed", "colorGreen", "colorBlue")])
    return points.astype(np.float64), np.clip(rgb.astype(np.float64) / 255.0, 0.0, 1.0)

"""Plain-text point lists (``.xyz``, ``.txt``, ``.pts``): ``x y z`` or ``x y z nx ny nz``.

These files have no header to say what the columns mean, so only the two layouts that are
unambiguous are accepted: 3 columns (positions) and 6 (positions, then normals). Anything
else (intensity, colours, labels) fails with a message rather than being guessed at.
Values may be separated by whitespace or commas; ``#`` starts a comment; a first line that
is a single integer (the point count some ``.pts`` writers put there) is skipped.
"""

from __future__ import annotations

import numpy as np

from .pointcloud import PointCloud, finite_cloud

__all__ = ["parse_text"]


def parse_text(raw: bytes) -> PointCloud:
    """Read a text point list's bytes into a cloud of its finite points.

    Raises
    ------
    ValueError
        Non-numeric values, rows of different lengths, a column count other than 3 or 6,
        or no finite point.
    """
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError("not a text file (it is not UTF-8/ASCII; binary data?)") from None
    lines = [line.split("#", 1)[0].replace(",", " ").strip() for line in text.splitlines()]
    lines = [line for line in lines if line]
    if lines and len(lines[0].split()) == 1 and lines[0].isdigit():
        lines = lines[1:]
    if not lines:
        raise ValueError("no data rows (only blank or comment lines)")
    try:
        table = np.loadtxt(lines, dtype=np.float64, ndmin=2, comments=None)
    except ValueError as exc:
        raise ValueError(f"malformed text point data ({exc})") from None
    if table.shape[1] not in (3, 6):
        raise ValueError(
            f"rows have {table.shape[1]} columns; expected 3 (x y z) or 6 (x y z nx ny nz)"
        )
    normals = table[:, 3:6] if table.shape[1] == 6 else None
    return finite_cloud(table[:, :3], normals)

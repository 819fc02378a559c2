"""Poses in the BOP challenge's CSV format, out and back in.

The format (https://bop.felk.cvut.cz/challenges/, "Format of results"): a header line
``scene_id,im_id,obj_id,score,R,t,time``, then one line per estimated pose: ``R`` the 3 x 3
rotation row-major as 9 space-separated numbers, ``t`` the translation in millimetres as 3
space-separated numbers, and ``time`` the wall-clock seconds spent on the whole image (the
same on every line of an image; BOP's evaluation refuses a file where it differs). The pose
maps model coordinates to camera coordinates, which is pointclm's ``T_target_source`` when the
scan is in the camera's frame (as a depth image's cloud is).

Units: pointclm does not know the clouds' unit, so the caller says it with `unit_to_mm`,
the millimetres in one unit of the clouds: 1000 (the default) for metres, which Open3D, ROS
and most depth pipelines use; 1 for clouds in millimetres, such as BOP's own models and depth
images. Only translations are scaled.
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InputError
from .files import atomic_path, check_output_path, read_checked

__all__ = ["BOP_HEADER", "BopEstimate", "read_bop_csv", "write_bop_csv"]

#: The header line BOP's evaluation expects, field for field.
BOP_HEADER = ("scene_id", "im_id", "obj_id", "score", "R", "t", "time")


@dataclass(frozen=True)
class BopEstimate:
    """One line of a BOP CSV: an object's pose in one image, with its score and the image's
    time. ``rotation`` (3, 3) and ``translation`` (3,) in the unit :func:`read_bop_csv`
    was given (metres by default)."""

    scene_id: int
    im_id: int
    obj_id: int
    score: float
    rotation: np.ndarray
    translation: np.ndarray
    time: float

    @property
    def transformation(self) -> np.ndarray:
        """The 4 x 4 pose (model to camera), as pointclm's ``T_target_source``."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.rotation, self.translation
        return T


def _unit(unit_to_mm: float) -> float:
    ok = isinstance(unit_to_mm, int | float | np.integer | np.floating) and not isinstance(
        unit_to_mm, bool
    )
    if not ok or not (math.isfinite(float(unit_to_mm)) and unit_to_mm > 0):
        raise InputError(
            "unit_to_mm must be the millimetres in one unit of the clouds (1000 for metres, "
            f"1 for millimetres), a positive number; got {unit_to_mm!r}"
        )
    return float(unit_to_mm)


def _ids(value: int | Sequence[int], n: int, name: str) -> list[int]:
    """One id per result: `value` for all, or a sequence of `n`."""
    values = [value] * n if isinstance(value, int | np.integer) else list(value)
    if len(values) != n:
        raise InputError(f"{name} must be an int or one per result ({n}), got {len(values)}")
    for v in values:
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 0:
            raise InputError(f"{name} must be non-negative ints, got {v!r}")
    return [int(v) for v in values]


def _score(inst: Any) -> float:
    """The instance's confidence, else its fitness (a `pointclm.register` instance has no
    confidence)."""
    for name in ("confidence", "fitness"):
        value = float(getattr(inst, name, math.nan))
        if math.isfinite(value):
            return value
    return 0.0


def _seconds(result: Any) -> float:
    timings = getattr(result, "timings", None) or {}
    total = timings.get("total")
    if total is None:
        total = sum(timings.values()) if timings else math.nan
    return float(total)


def _numbers(values: np.ndarray) -> str:
    # repr of a float is the shortest text that reads back to the same double.
    return " ".join(repr(float(v)) for v in values)


def write_bop_csv(
    results: Any,
    path: str | os.PathLike[str],
    scene_id: int | Sequence[int],
    im_id: int | Sequence[int],
    obj_id: int | Sequence[int],
    *,
    unit_to_mm: float = 1000.0,
    time: float | None = None,
) -> int:
    """Write the poses of `results` to `path` in the BOP challenge's CSV (module
    documentation); returns the number of poses written.

    Parameters
    ----------
    results : result or sequence of results
        :class:`pointclm.point_clouds.PointCloudRegistration` (score: each instance's
        ``confidence``) or :class:`pointclm.RegistrationResult` (score: ``fitness``), or a
        list of them, e.g. one per image or per object.
    path : str or os.PathLike
        The CSV file, written whole or not at all.
    scene_id, im_id, obj_id : int or sequence of int
        BOP's ids, the same for every result or one per result.
    unit_to_mm : float
        Millimetres in one unit of the clouds: 1000 (default) for metres, 1 for millimetres.
    time : float, optional
        Seconds to record per image; default: the results' own ``timings["total"]``, summed
        over the results of one image (BOP times the whole image), -1 when unknown.
    """
    many = isinstance(results, list | tuple)
    items = list(results) if many else [results]
    scale = _unit(unit_to_mm)
    scenes = _ids(scene_id, len(items), "scene_id")
    images = _ids(im_id, len(items), "im_id")
    objects = _ids(obj_id, len(items), "obj_id")
    per_image: dict[tuple[int, int], float] = {}
    for r, key in zip(items, zip(scenes, images, strict=True), strict=True):
        per_image[key] = per_image.get(key, 0.0) + _seconds(r)
    if time is not None:
        per_image = dict.fromkeys(per_image, float(time))
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(BOP_HEADER)
    rows = 0
    for r, s, i, o in zip(items, scenes, images, objects, strict=True):
        seconds = per_image[(s, i)]
        seconds = seconds if math.isfinite(seconds) else -1.0
        for inst in getattr(r, "instances", []):
            T = np.asarray(inst.transformation, dtype=np.float64)
            R, t = _numbers(T[:3, :3].reshape(-1)), _numbers(T[:3, 3] * scale)
            writer.writerow([s, i, o, repr(_score(inst)), R, t, repr(seconds)])
            rows += 1
    target = check_output_path(path, "BOP CSV")
    with atomic_path(target) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            fh.write(out.getvalue())
    return rows


def read_bop_csv(path: str | os.PathLike[str], *, unit_to_mm: float = 1000.0) -> list[BopEstimate]:
    """The poses of a BOP challenge CSV, in file order, translations divided by
    `unit_to_mm` (1000, the default: metres; 1: millimetres as stored).

    Raises
    ------
    FileNotFoundError
        If the file is missing.
    ValueError
        If the header is not BOP's, a line has not 7 fields, an id is not a non-negative
        integer, or a number is missing or not finite; the message names the file and line.
    """
    scale = _unit(unit_to_mm)
    file, raw = read_checked(path, "BOP CSV")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(f"{file}: not a text file") from None
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or tuple(c.strip() for c in rows[0]) != BOP_HEADER:
        raise ValueError(f"{file}: the first line must be the header {','.join(BOP_HEADER)}")
    out = []
    for n, row in enumerate(rows[1:], start=2):
        if not row or not "".join(row).strip():
            continue
        try:
            out.append(_estimate(row, scale))
        except ValueError as e:
            raise ValueError(f"{file}, line {n}: {e}") from None
    return out


def _estimate(row: list[str], scale: float) -> BopEstimate:
    if len(row) != len(BOP_HEADER):
        raise ValueError(f"{len(row)} fields, expected {len(BOP_HEADER)} ({','.join(BOP_HEADER)})")
    ids = []
    for name, cell in zip(BOP_HEADER[:3], row[:3], strict=True):
        if not cell.strip().isdigit():
            raise ValueError(f"{name} must be a non-negative integer, got {cell!r}")
        ids.append(int(cell))
    R = _floats(row[4], 9, "R").reshape(3, 3)
    t = _floats(row[5], 3, "t") / scale
    score, seconds = _floats(row[3], 1, "score")[0], _floats(row[6], 1, "time")[0]
    return BopEstimate(ids[0], ids[1], ids[2], float(score), R, t, float(seconds))


def _floats(cell: str, n: int, name: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in cell.split()], dtype=np.float64)
    except ValueError:
        raise ValueError(f"{name} must be {n} numbers, got {cell!r}") from None
    if values.shape != (n,) or not np.isfinite(values).all():
        raise ValueError(f"{name} must be {n} finite numbers, got {cell!r}")
    return values

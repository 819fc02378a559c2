"""A batch's poses in one BOP challenge CSV (``pointclm batch --bop-csv``), read from its
JSON lines once the batch is through, so a resumed batch's CSV holds every scan.

Each scan is one BOP image: ``scene_id`` is the caller's (one for the batch), ``im_id`` the
scan's position in the scan list (0, 1, ...; ``im_id_from="index"``) or the number its file
is named by (``"stem"``: BOP's own images are named so, ``000042.ply`` being image 42). A scan
recorded with an error has no line; nor does a scan no copy was found in.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from ..errors import InputError
from ..io.bop import write_bop_csv
from .results import _existing_records

__all__ = ["IM_ID_RULES", "write_batch_bop_csv"]

#: How a scan's BOP image id is chosen: its position in the scan list, or its file's name.
IM_ID_RULES = ("index", "stem")


def _im_id(scan: str, index: int, rule: str) -> int:
    if rule == "index":
        return index
    stem = Path(scan).stem
    if not stem.isdigit():
        raise InputError(
            f"--im-id-from stem: the scan {scan} is not named by a number (as BOP's "
            "000042.ply is); name the scans so, or use --im-id-from index"
        )
    return int(stem)


def _result(record: dict[str, Any]) -> Any:
    """A record as :func:`pointclm.io.write_bop_csv` reads a result: instances with a pose
    and scores, and timings."""
    instances = [
        SimpleNamespace(
            transformation=np.asarray(inst["T_target_source"], dtype=np.float64),
            confidence=np.nan if inst.get("confidence") is None else inst["confidence"],
            fitness=np.nan if inst.get("fitness") is None else inst["fitness"],
        )
        for inst in record.get("instances", [])
    ]
    return SimpleNamespace(instances=instances, timings=record.get("timings_s") or {})


def write_batch_bop_csv(
    out: str | os.PathLike[str],
    scans: list[str],
    path: str | os.PathLike[str],
    *,
    scene_id: int = 0,
    obj_id: int | Sequence[int] = 1,
    im_id_from: str = "index",
    unit_to_mm: float = 1000.0,
) -> int:
    """Write the poses of the batch output `out` (JSON lines) for the scans of `scans` (the
    batch's expanded scan list, which numbers them) to `path` in the BOP challenge's CSV;
    returns the number of poses written. `im_id_from`: "index" (the scan's position in
    `scans`) or "stem" (the number its file is named by). ``time`` is each scan's own total
    (loading included); ``score`` its confidence. A batch of several models: `obj_id` one per
    model, in order, and each image's ``time`` the scan's whole seconds.

    Raises
    ------
    ValueError
        If `out` is not a batch output, two scans get the same image id, or an argument is
        malformed.
    """
    if im_id_from not in IM_ID_RULES:
        raise InputError(f"im_id_from must be one of {', '.join(IM_ID_RULES)}, got {im_id_from!r}")
    records, _ = _existing_records(Path(os.fspath(out)))
    by_scan = {r["scan"]: r for r in records}
    results, images, objects = [], [], []
    owner: dict[int, str] = {}
    for index, scan in enumerate(scans):
        image = _im_id(scan, index, im_id_from)
        if image in owner:
            raise InputError(
                f"--bop-csv: the scans {owner[image]} and {scan} are both image {image}"
            )
        owner[image] = scan
        record = by_scan.get(scan)
        if record is not None and record.get("status") == "ok":
            found = _results(record)
            ids = _obj_ids(obj_id, len(found))
            results += found
            images += [image] * len(found)
            objects += ids
    return write_bop_csv(results, path, scene_id, images, objects, unit_to_mm=unit_to_mm)


def _results(record: dict[str, Any]) -> list[Any]:
    """A line's results, one per model: with several, the first carries the scan's seconds
    and the others none, so the image's time (their sum) is the scan's."""
    if "results" not in record:
        return [_result(record)]
    found = [_result(r) for r in record["results"]]
    for k, r in enumerate(found):
        r.timings = {"total": float(record.get("seconds", 0.0)) if k == 0 else 0.0}
    return found


def _obj_ids(obj_id: int | Sequence[int], n: int) -> list[int]:
    """The object ids of a line's `n` results: `obj_id` for one, else one per model."""
    if isinstance(obj_id, int):
        obj_id = [obj_id]
    ids = list(obj_id)
    if len(ids) != n:
        raise InputError(
            f"--bop-csv: the batch has {n} model(s) per scan, and {len(ids)} object id(s) "
            "(--obj-id) were given: give one per model, in the models' order"
        )
    return ids

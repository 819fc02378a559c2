"""The JSON content of one registration, shared by `pointclm register --out` and each line
of a batch's output, so the two agree field for field."""

from __future__ import annotations

import math
from typing import Any

__all__ = [
    "FORMAT_VERSION",
    "TIMING_FIELDS",
    "error_record",
    "registration_record",
    "without_timings",
]

#: The version of the JSON `register --out` and `batch` write, their first field:
#: MAJOR.MINOR, the minor one raised when fields are added, the major one when a field is
#: renamed, removed or changes meaning. `pointclm/schemas/result.schema.json` describes it.
FORMAT_VERSION = "1.4"

#: The fields of a batch line that change from run to run; everything else is fixed by the
#: scan, the model, the options and the seed.
TIMING_FIELDS = ("timings_s", "seconds")


def _number(value: float) -> float | None:
    # JSON has no NaN; a score that could not be measured is null.
    return None if not math.isfinite(value) else float(value)


def _matrix(value: Any) -> list[list[float]] | None:
    if value is None:
        return None
    return [[float(v) for v in row] for row in value]


def registration_record(reg: Any, diagnosis: str) -> dict[str, Any]:
    """Voxel, config, instances (``T_target_source`` 4x4 lists, surest first, with their
    scores), the viewpoint verification judged from (given, recorded or guessed and confirmed;
    null: none), how the scan's normals were oriented, the descriptor matched by,
    `diagnosis` ("" when there is nothing to say) and timings of a
    :class:`pointclm.point_clouds.PointCloudRegistration`; the poses that slide along a face
    apart, under ``ambiguous``."""
    return {
        "voxel_size": reg.voxel_size,
        "config": reg.config.to_dict(),
        "instances": [_instance(inst) for inst in reg.instances],
        "ambiguous": [_instance(inst) for inst in getattr(reg, "ambiguous", [])],
        "viewpoint": None if reg.viewpoint is None else [float(v) for v in reg.viewpoint],
        "scan_normals": reg.orientation,
        "descriptor": getattr(reg, "descriptor", ""),
        "diagnosis": diagnosis,
        "timings_s": dict(reg.timings),
    }


def _instance(inst: Any) -> dict[str, Any]:
    """One copy, as the result JSON holds it."""
    return {
        "T_target_source": inst.transformation.tolist(),
        "inliers": len(inst),
        # Proposed by point pair voting in a heap (no correspondence inliers).
        "voted": inst.matches is None,
        "fitness": _number(inst.fitness),
        "inlier_rmse": _number(inst.inlier_rmse),
        "confidence": _number(inst.confidence),
        # What the sensor at the viewpoint could see of the copy (null without one).
        "visible_fitness": _number(inst.visible_fitness),
        "contradiction": _number(inst.contradiction),
        "visible_rmse": _number(inst.visible_rmse),
        "pass": inst.pass_index,
        # Order (rx, ry, rz, x, y, z), finite (pointclm.covariance); null when not computed.
        "covariance": _matrix(getattr(inst, "covariance", None)),
        "unobservable": int(getattr(inst, "unobservable", 0)),
        "slid_fitness": _number(getattr(inst, "slid_fitness", math.nan)),
    }


def error_record(error: BaseException) -> dict[str, Any]:
    """Why a scan has no result: the exception's class and its one-line message."""
    message = " ".join(str(error).split()) or type(error).__name__
    return {"error": type(error).__name__, "message": message}


def without_timings(record: dict[str, Any]) -> dict[str, Any]:
    """`record` without the fields that differ between two runs of the same batch (in each
    model's result too, with several models)."""
    out = {k: v for k, v in record.items() if k not in TIMING_FIELDS}
    if isinstance(out.get("results"), list):
        out["results"] = [without_timings(r) for r in out["results"]]
    return out

"""A result as a ``vision_msgs/Detection3DArray`` (vision_msgs 4, ROS 2 Humble and later).

One ``Detection3D`` per copy found, surest first, each with one hypothesis: the class id
given, the copy's ``confidence`` as its score (its ``fitness`` where no confidence is
known), and its pose with covariance. The pose is the copy's ``T_target_source``: the
model's own frame placed in the scan's frame, which is the frame the header names. The
bounding box is the model's axis-aligned box in its own frame, carried by that pose (its
``center`` is the box centre, which is the pose's position only for a centred model).

Covariance: ROS orders it (x, y, z, rotation about X, about Y, about Z), row-major, in the
header's frame, metres and radians. An instance that carries a 6 x 6 ``covariance`` gives it,
in pointclm's order (rotation about X, Y, Z, then x, y, z; :mod:`pointclm.covariance`, the
rotation about the model's origin in the header's axes, as ROS means it), reordered here to
ROS's translation-first order; otherwise the message holds :data:`UNKNOWN_COVARIANCE`: -1
on the diagonal and 0 elsewhere, ROS's mark for "no estimate" (as ``sensor_msgs/Imu``
documents for its first element, here on every variance so no consumer can take it for a real
one).

The message is built as rclpy objects when ``rclpy`` and ``vision_msgs`` import, as objects
of a ``rosbags`` typestore when one is given (:func:`add_vision_msgs` registers the types, so
detections can be written to a bag without ROS), and otherwise as nested dicts with the
same field names (``stamp`` as ``{"sec", "nanosec"}``, the covariance as 36 floats).
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

__all__ = ["OUTPUTS", "UNKNOWN_COVARIANCE", "VISION_MSGS", "add_vision_msgs", "detection3d_array"]

#: Row-major 6 x 6 covariance meaning "unknown" (see the module documentation).
UNKNOWN_COVARIANCE: tuple[float, ...] = tuple(-1.0 if i % 7 == 0 else 0.0 for i in range(36))

#: ROS's covariance rows and columns as indices into pointclm's (rotation first).
_ROS_ORDER = [3, 4, 5, 0, 1, 2]

#: What :func:`detection3d_array` builds: rclpy messages where importable ("auto"), always
#: dicts, or rclpy messages or an ImportError.
OUTPUTS = ("auto", "dict", "rclpy")

#: The vision_msgs 4 definitions of the messages built here, to register with rosbags.
VISION_MSGS: dict[str, str] = {
    "vision_msgs/msg/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/msg/ObjectHypothesisWithPose": (
        "vision_msgs/ObjectHypothesis hypothesis\ngeometry_msgs/PoseWithCovariance pose\n"
    ),
    "vision_msgs/msg/BoundingBox3D": "geometry_msgs/Pose center\ngeometry_msgs/Vector3 size\n",
    "vision_msgs/msg/Detection3D": (
        "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\n"
        "vision_msgs/BoundingBox3D bbox\nstring id\n"
    ),
    "vision_msgs/msg/Detection3DArray": (
        "std_msgs/Header header\nvision_msgs/Detection3D[] detections\n"
    ),
}

Make = Callable[..., Any]


def add_vision_msgs(typestore: Any) -> Any:
    """Register :data:`VISION_MSGS` in a ``rosbags`` typestore (which ships no vision_msgs)
    and return it, so :func:`detection3d_array` can build messages a bag writer serialises."""
    from rosbags.typesys import get_types_from_msg

    types: dict[str, Any] = {}
    for name, text in VISION_MSGS.items():
        types.update(get_types_from_msg(text, name))
    typestore.register(types)
    return typestore


def detection3d_array(
    result: Any,
    *,
    class_id: str = "object",
    header: Any = None,
    frame_id: str = "",
    stamp: Any = None,
    output: str = "auto",
    typestore: Any = None,
) -> Any:
    """The ``vision_msgs/Detection3DArray`` of a :class:`pointclm.PointCloudRegistration`.

    Parameters
    ----------
    result : PointCloudRegistration
        Or any object with ``instances`` (each with ``transformation`` and ``confidence``
        or ``fitness``, optionally ``covariance``) and ``source_points`` (the model).
    class_id : str
        The hypothesis' class id of every copy (the model's name).
    header : message or mapping, optional
        A header to copy (``stamp`` and ``frame_id``): the scan's own, so the detections
        line up with it. Overrides `frame_id` and `stamp`.
    frame_id : str
        The scan's frame.
    stamp : optional
        Nanoseconds (int), seconds (float), ``(sec, nanosec)``, or a Time-like object or
        mapping; default 0.
    output : {"auto", "dict", "rclpy"}
        See :data:`OUTPUTS`.
    typestore : rosbags Typestore, optional
        Build that typestore's message objects instead (after :func:`add_vision_msgs`).

    Raises
    ------
    ValueError
        If an argument is malformed or an instance's covariance is not 6 x 6.
    ImportError
        If ``output="rclpy"`` and rclpy or vision_msgs does not import.
    """
    if not isinstance(class_id, str):
        raise ValueError(f"class_id must be a str, got {type(class_id).__name__}")
    make, as_array = _maker(output, typestore)
    if header is not None:
        frame_id, stamp = _get(header, "frame_id", ""), _get(header, "stamp", None)
    if not isinstance(frame_id, str):
        raise ValueError(f"frame_id must be a str, got {type(frame_id).__name__}")
    sec, nanosec = _stamp(stamp)

    def head() -> Any:  # one per message: no two share an object a caller could mutate
        time = make("builtin_interfaces", "Time", sec=sec, nanosec=nanosec)
        return make("std_msgs", "Header", stamp=time, frame_id=frame_id)

    box = _model_box(getattr(result, "source_points", None))
    detections = [
        _detection(make, as_array, head(), k, inst, class_id, box)
        for k, inst in enumerate(getattr(result, "instances", None) or [])
    ]
    return make("vision_msgs", "Detection3DArray", header=head(), detections=detections)


def _maker(output: str, typestore: Any) -> tuple[Make, Callable[[np.ndarray], Any]]:
    """The constructor of each message (package, name, fields) and of its float arrays."""
    if output not in OUTPUTS:
        raise ValueError(f"output must be one of {', '.join(OUTPUTS)}, got {output!r}")
    if typestore is not None:
        types = typestore.types

        def from_store(pkg: str, name: str, **fields: Any) -> Any:
            key = f"{pkg}/msg/{name}"
            if key not in types:
                raise ValueError(
                    f"the typestore has no {key}; register vision_msgs with add_vision_msgs"
                )
            return types[key](**fields)

        return from_store, lambda a: a
    if output == "dict" or (output == "auto" and not _ros_available()):
        return (lambda pkg, name, **fields: fields), lambda a: [float(v) for v in a]
    if not _ros_available():
        raise ImportError(
            "output='rclpy' needs a ROS 2 environment with rclpy and vision_msgs (source "
            "its setup.bash); output='dict' needs neither"
        )

    def from_rclpy(pkg: str, name: str, **fields: Any) -> Any:
        return getattr(importlib.import_module(f"{pkg}.msg"), name)(**fields)

    return from_rclpy, lambda a: a


def _ros_available() -> bool:
    try:
        return all(importlib.util.find_spec(m) is not None for m in ("rclpy", "vision_msgs"))
    except (ImportError, ValueError):  # a broken or half-installed ROS environment
        return False


def _get(obj: Any, key: str, default: Any) -> Any:
    return obj.get(key, default) if isinstance(obj, Mapping) else getattr(obj, key, default)


def _stamp(stamp: Any) -> tuple[int, int]:
    """(sec, nanosec) of a stamp given in any of the forms :func:`detection3d_array` takes."""
    if stamp is None:
        return 0, 0
    if isinstance(stamp, bool):
        raise ValueError(f"stamp must be a time, got {stamp!r}")
    if isinstance(stamp, int | np.integer):
        if stamp < 0:
            raise ValueError(f"stamp must be >= 0 nanoseconds, got {stamp}")
        return int(stamp) // 10**9, int(stamp) % 10**9
    if isinstance(stamp, float | np.floating):
        if not np.isfinite(stamp) or stamp < 0:
            raise ValueError(f"stamp must be finite seconds >= 0, got {stamp}")
        ns = round(float(stamp) * 1e9)
        return ns // 10**9, ns % 10**9
    if isinstance(stamp, tuple | list) and len(stamp) == 2:
        sec, nanosec = stamp
    else:
        sec, nanosec = _get(stamp, "sec", None), _get(stamp, "nanosec", None)
    ok = all(isinstance(v, int | np.integer) and not isinstance(v, bool) for v in (sec, nanosec))
    if not ok or not 0 <= nanosec < 10**9:
        raise ValueError(
            f"stamp must be nanoseconds, seconds, (sec, nanosec) or a Time, got {stamp!r}"
        )
    return int(sec), int(nanosec)


def _model_box(model: Any) -> tuple[np.ndarray, np.ndarray]:
    """The centre and size of the model's axis-aligned box in its own frame."""
    if model is None:
        return np.zeros(3), np.zeros(3)
    pts = np.asarray(model, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:
        return np.zeros(3), np.zeros(3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    return (lo + hi) / 2, hi - lo


def _covariance(inst: Any, k: int) -> np.ndarray:
    cov = getattr(inst, "covariance", None)
    if cov is None:
        return np.array(UNKNOWN_COVARIANCE)
    arr = np.asarray(cov, dtype=np.float64)
    if arr.shape != (6, 6):
        raise ValueError(f"instance {k}: covariance must be 6 x 6, got shape {arr.shape}")
    # pointclm's (rx, ry, rz, x, y, z) to ROS's (x, y, z, rx, ry, rz).
    ros = arr[np.ix_(_ROS_ORDER, _ROS_ORDER)]
    return np.ascontiguousarray(ros).reshape(36)


def _quaternion_xyzw(rotation: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(rotation).as_quat()
    return -q if q[3] < 0 else q


def _pose(make: Make, rotation: np.ndarray, position: np.ndarray) -> Any:
    q = _quaternion_xyzw(rotation)
    x, y, z = (float(v) for v in position)
    return make(
        "geometry_msgs",
        "Pose",
        position=make("geometry_msgs", "Point", x=x, y=y, z=z),
        orientation=make(
            "geometry_msgs", "Quaternion", **dict(zip("xyzw", map(float, q), strict=True))
        ),
    )


def _detection(
    make: Make,
    as_array: Callable[[np.ndarray], Any],
    head: Any,
    k: int,
    inst: Any,
    class_id: str,
    box: tuple[np.ndarray, np.ndarray],
) -> Any:
    T = np.asarray(inst.transformation, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise ValueError(f"instance {k}: transformation must be a finite 4 x 4 matrix")
    rotation, translation = T[:3, :3], T[:3, 3]
    score = float(getattr(inst, "confidence", float("nan")))
    if not np.isfinite(score):
        score = float(getattr(inst, "fitness", 0.0))
    hypothesis = make(
        "vision_msgs",
        "ObjectHypothesisWithPose",
        hypothesis=make("vision_msgs", "ObjectHypothesis", class_id=class_id, score=score),
        pose=make(
            "geometry_msgs",
            "PoseWithCovariance",
            pose=_pose(make, rotation, translation),
            covariance=as_array(_covariance(inst, k)),
        ),
    )
    centre, size = box
    bbox = make(
        "vision_msgs",
        "BoundingBox3D",
        center=_pose(make, rotation, rotation @ centre + translation),
        size=make("geometry_msgs", "Vector3", **dict(zip("xyz", map(float, size), strict=True))),
    )
    return make(
        "vision_msgs", "Detection3D", header=head, results=[hypothesis], bbox=bbox, id=str(k)
    )

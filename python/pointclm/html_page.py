"""A result as one self-contained HTML page: the scan and every copy found, in 3D, to turn
around in any browser.

The page (:mod:`pointclm.html_viewer`) holds a small point viewer in plain JavaScript and
the points, so it opens with no network and no library, can be mailed or attached to a
ticket as it is, and is on screen in well under a second where a plotly page took several
(BENCHMARKS.md). The scan is drawn in grey, subsampled for display to at most
:data:`MAX_SCAN_POINTS` points, one per cell of a voxel grid (the legend says how many of
how many, and the cell); each copy found is the model placed by its pose, in its own colour
(the PNG's palette, :func:`pointclm.visualize.palette`), numbered from 0 in the order of the
result (surest first) with its confidence in the legend (its fitness where no confidence is
known); clicking a legend entry hides or shows it. Given the ground-truth poses, each true
copy that no found pose matches (as the benchmarks score a pose: rotation under 15 degrees,
translation under a tenth of the model's diagonal) is outlined in black dashes: the edges of
the model's bounding box at that pose. Points are stored as float32 in base64.

:func:`registration_figure` draws the same layers as a plotly figure, for a notebook
(``pip install 'pointclm[viz]'``).
"""

from __future__ import annotations

import base64
import html
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .html_viewer import page
from .io.files import atomic_path, check_output_path
from .metrics import pose_match_matrix
from .visualize import MATCH_DEG, MATCH_DIAMETERS, _empty_reason, palette

__all__ = ["MAX_MODEL_POINTS", "MAX_SCAN_POINTS", "registration_figure", "write_html"]

#: Scan points drawn at most: more adds megabytes and time, not detail on a screen.
MAX_SCAN_POINTS = 20_000
#: Model points drawn per copy.
MAX_MODEL_POINTS = 400
_SCAN_GREY = (160, 160, 160)
_MISSED = (0, 0, 0)
#: The 12 edges of a box, as pairs of corner indices (corner bits: x, y, z).
_BOX_EDGES = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]


def _plotly() -> Any:
    try:
        import plotly.graph_objects as go
    except ImportError:
        raise ImportError("the plotly figure needs plotly: pip install 'pointclm[viz]'") from None
    return go


def _voxel_count(points: np.ndarray, cell: float) -> tuple[int, np.ndarray]:
    keys = np.floor((points - points.min(axis=0)) / cell).astype(np.int64)
    span = keys.max(axis=0) + 1
    flat = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
    _, first = np.unique(flat, return_index=True)
    return len(first), np.sort(first)


def voxel_subsample(points: np.ndarray, limit: int) -> tuple[np.ndarray, float]:
    """At most `limit` of `points`, the first of each cell of a voxel grid, and the cell
    (0 where every point is kept): the smallest cell, to 2 %, that leaves no more than
    `limit`. Spread over the cloud as a stride is not, and the same page each time."""
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) <= limit:
        return points, 0.0
    diagonal = float(np.linalg.norm(np.ptp(points, axis=0)))
    if diagonal == 0.0:
        return points[:limit], 0.0
    # Too many at `small` (where the keys still fit an int64), few enough at `big` (one
    # cell); halve the ratio, in logarithms, until it is under 2 %.
    small, big = diagonal * 1e-6, diagonal * 2
    while big / small > 1.02:
        cell = float(np.sqrt(small * big))
        if _voxel_count(points, cell)[0] > limit:
            small = cell
        else:
            big = cell
    return points[_voxel_count(points, big)[1]], big


def _rgb(colour: np.ndarray) -> tuple[int, int, int]:
    r, g, b = (int(round(255 * float(c))) for c in colour)
    return r, g, b


def _copy_name(k: int, inst: Any) -> str:
    confidence = float(getattr(inst, "confidence", float("nan")))
    if np.isfinite(confidence):
        return f"copy {k}: confidence {confidence:.2f}"
    return f"copy {k}: fitness {float(getattr(inst, 'fitness', float('nan'))):.2f}"


def _placed(model: np.ndarray, T: np.ndarray) -> np.ndarray:
    return model @ T[:3, :3].T + T[:3, 3]


def _box_lines(model: np.ndarray, T: np.ndarray) -> np.ndarray:
    """The model's bounding box edges at pose `T`, as one polyline with NaN breaks."""
    lo, hi = model.min(axis=0), model.max(axis=0)
    bits = (np.arange(8)[:, None] >> np.arange(3)) & 1
    corners = _placed(np.where(bits == 1, hi, lo), T)
    nan = np.full(3, np.nan)
    return np.array([p for a, b in _BOX_EDGES for p in (corners[a], corners[b], nan)])


def _missed(model: np.ndarray, poses: np.ndarray, ground_truth: ArrayLike) -> list[int]:
    """Indices of the true poses no found pose matches."""
    gt = np.asarray(ground_truth, dtype=np.float64)
    if gt.ndim != 3 or gt.shape[1:] != (4, 4) or not np.isfinite(gt).all():
        raise ValueError(f"ground_truth must be finite (G, 4, 4) poses, got shape {gt.shape}")
    diameter = float(np.linalg.norm(np.ptp(model, axis=0))) if len(model) else 0.0
    match = pose_match_matrix(poses, gt, MATCH_DEG, MATCH_DIAMETERS * diameter)
    hit = np.asarray(match, dtype=bool).reshape(len(poses), len(gt)).any(axis=0)
    return [int(j) for j in np.flatnonzero(~hit)]


def _summary(reg: Any, missed: list[int] | None, n_true: int) -> str:
    found = len(reg.instances)
    text = f"{found} {'copy' if found == 1 else 'copies'} found"
    if missed is not None:
        text += f"; {n_true - len(missed)} of {n_true} true copies found, {len(missed)} missed"
    if not reg.instances:
        text += f" (no copy found: {_empty_reason(reg) or 'nothing found'})"
    return text


def _scan_name(shown: int, total: int, cell: float) -> str:
    if cell == 0.0:
        return f"scan ({shown} of {total} points)"
    return f"scan ({shown} of {total} points, one per {cell:.3g} voxel)"


def _layers(
    reg: Any, ground_truth: ArrayLike | None, max_scan_points: int
) -> tuple[list[dict[str, Any]], str]:
    """What the page and the figure draw: the scan, each copy, each missed true copy (name,
    kind, colour, size, dash, points), and the summary line."""
    if isinstance(max_scan_points, bool) or not isinstance(max_scan_points, int):
        raise ValueError(f"max_scan_points must be an int >= 1, got {max_scan_points!r}")
    if max_scan_points < 1:
        raise ValueError(f"max_scan_points must be an int >= 1, got {max_scan_points!r}")
    scan = np.asarray(reg.target_points, dtype=np.float64).reshape(-1, 3)
    model = np.asarray(reg.source_points, dtype=np.float64).reshape(-1, 3)
    poses = np.asarray(reg.transformations, dtype=np.float64).reshape(-1, 4, 4)
    missed = None if ground_truth is None else _missed(model, poses, ground_truth)
    shown, cell = voxel_subsample(scan, max_scan_points)
    layers = [_layer(_scan_name(len(shown), len(scan), cell), shown, _SCAN_GREY, 2)]
    sub, _ = voxel_subsample(model, MAX_MODEL_POINTS)
    colours = palette(len(poses))
    for k, (inst, T, colour) in enumerate(zip(reg.instances, poses, colours, strict=True)):
        layers.append(_layer(_copy_name(k, inst), _placed(sub, T), _rgb(colour), 4))
    for j in missed or []:
        box = _box_lines(model, np.asarray(ground_truth, dtype=np.float64)[j])
        layers.append(_layer(f"missed ground truth {j}", box, _MISSED, 2, kind="lines"))
    n_true = 0 if ground_truth is None else len(np.asarray(ground_truth).reshape(-1, 16))
    return layers, _summary(reg, missed, n_true)


def _layer(
    name: str, points: np.ndarray, colour: tuple[int, int, int], size: float, kind: str = "points"
) -> dict[str, Any]:
    xyz = np.ascontiguousarray(points, dtype="<f4").reshape(-1, 3)
    return {"name": name, "kind": kind, "colour": list(colour), "size": size, "xyz": xyz}


def _view(reg: Any, layers: list[dict[str, Any]]) -> tuple[list[float], list[float]]:
    """The first view (toward the viewer, and up): from the sensor where the result knows
    it, else from the origin when it lies outside the scan (a scan in its sensor's frame),
    else from above at an angle. Looking along z means a camera's frame: its y points down."""
    scan = layers[0]["xyz"].astype(np.float64)
    if not len(scan):
        return [1.0, -1.0, 1.0], [0.0, 0.0, 1.0]
    centre = (scan.min(axis=0) + scan.max(axis=0)) / 2
    viewpoint = getattr(reg, "viewpoint", None)
    eye = None if viewpoint is None else np.asarray(viewpoint, dtype=np.float64).reshape(3)
    inside = bool(((scan.min(axis=0) <= 0) & (0 <= scan.max(axis=0))).all())
    if eye is None and not inside:
        eye = np.zeros(3)
    back = None if eye is None else eye - centre
    if back is None or not np.isfinite(back).all() or np.linalg.norm(back) == 0:
        return [1.0, -1.0, 1.0], [0.0, 0.0, 1.0]
    back = back / np.linalg.norm(back)
    up = [0.0, -1.0, 0.0] if abs(back[2]) > 0.7 else [0.0, 0.0, 1.0]
    return [float(v) for v in back], up


def registration_figure(
    reg: Any,
    *,
    ground_truth: ArrayLike | None = None,
    title: str = "",
    max_scan_points: int = MAX_SCAN_POINTS,
) -> Any:
    """The plotly figure of a :class:`pointclm.PointCloudRegistration`, the page's layers
    (see the module documentation), for a notebook; needs plotly."""
    go = _plotly()
    layers, summary = _layers(reg, ground_truth, max_scan_points)
    traces = []
    for layer in layers:
        xyz, colour = layer["xyz"], "rgb({},{},{})".format(*layer["colour"])
        style: dict[str, Any] = {"mode": "markers", "marker": {"size": layer["size"] * 0.7}}
        style["marker"]["color"] = colour
        if layer["kind"] == "lines":
            style = {"mode": "lines", "line": {"color": colour, "width": 4, "dash": "dash"}}
        traces.append(
            go.Scatter3d(x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2], name=layer["name"], **style)
        )
    heading = f"{html.escape(title)}<br><sub>{html.escape(summary)}</sub>" if title else summary
    fig = go.Figure(traces)
    fig.update_layout(
        title={"text": heading},
        scene={"aspectmode": "data", "xaxis_title": "x", "yaxis_title": "y", "zaxis_title": "z"},
        legend={"itemsizing": "constant"},
        margin={"l": 0, "r": 0, "t": 60, "b": 0},
        paper_bgcolor="white",
    )
    return fig


def html_content(
    reg: Any,
    *,
    ground_truth: ArrayLike | None = None,
    title: str = "",
    max_scan_points: int = MAX_SCAN_POINTS,
) -> dict[str, Any]:
    """What the page embeds (:func:`pointclm.html_viewer.page` documents the keys)."""
    layers, summary = _layers(reg, ground_truth, max_scan_points)
    back, up = _view(reg, layers)
    for layer in layers:
        layer["points"] = base64.b64encode(layer.pop("xyz").tobytes()).decode("ascii")
        layer["dash"] = layer["kind"] == "lines"
        layer["front"] = not layer["name"].startswith("scan")
    return {"title": title, "summary": summary, "back": back, "up": up, "layers": layers}


def write_html(
    path: str | os.PathLike[str],
    reg: Any,
    *,
    ground_truth: ArrayLike | None = None,
    title: str = "",
    max_scan_points: int = MAX_SCAN_POINTS,
) -> Path:
    """Write the page of a :class:`pointclm.PointCloudRegistration` to `path` (one HTML
    file, needing no network and no library to open) and return the path.

    `ground_truth` (G, 4, 4): the true ``T_target_source`` poses; those no found pose
    matches are outlined. `title` heads the page above the summary. `max_scan_points`:
    the most scan points drawn (a voxel grid's subsample).

    Raises
    ------
    ValueError
        If `path` cannot be written (its folder is missing or not writable) or an argument
        is malformed.
    """
    file = check_output_path(path, "HTML page")
    content = html_content(
        reg, ground_truth=ground_truth, title=title, max_scan_points=max_scan_points
    )
    text = page(content)
    with atomic_path(file) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return file

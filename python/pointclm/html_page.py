"""A result as one self-contained HTML page: the scan and every copy found, in 3D, to turn
around in any browser (``pip install 'pointclm[viz]'`` for plotly).

The page embeds plotly.js (about 4.7 MB) and the points, so it opens with no network and
can be mailed or attached to a ticket as it is. The scan is drawn in grey, decimated to at
most :data:`MAX_SCAN_POINTS` points; each copy found is the model placed by its pose, in its
own colour (the PNG's palette, :func:`pointclm.visualize.palette`), numbered from 0 in the
order of the result (surest first) with its confidence in the legend (its fitness where
no confidence is known); clicking a legend entry hides or shows it. Given the ground-truth
poses, each true copy that no found pose matches (as the benchmarks score a pose: rotation
under 15 degrees, translation under a tenth of the model's diagonal) is outlined in black
dashes: the edges of the model's bounding box at that pose. Points are stored as float32
in base64, so a page of 20 copies stays a few megabytes (BENCHMARKS.md).
"""

from __future__ import annotations

import html
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .io.files import atomic_path, check_output_path
from .metrics import pose_match_matrix
from .visualize import MATCH_DEG, MATCH_DIAMETERS, _empty_reason, palette

__all__ = ["MAX_MODEL_POINTS", "MAX_SCAN_POINTS", "registration_figure", "write_html"]

#: Scan points drawn at most: more adds megabytes and seconds, not detail on a screen.
MAX_SCAN_POINTS = 20_000
#: Model points drawn per copy.
MAX_MODEL_POINTS = 400
_SCAN_GREY = "rgb(160,160,160)"
_MISSED = "rgb(0,0,0)"
#: The 12 edges of a box, as pairs of corner indices (corner bits: x, y, z).
_BOX_EDGES = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]


def _plotly() -> Any:
    try:
        import plotly.graph_objects as go
    except ImportError:
        raise ImportError("the HTML page needs plotly: pip install 'pointclm[viz]'") from None
    return go


def _decimated(points: np.ndarray, limit: int) -> np.ndarray:
    """Every k-th point, at most `limit` of them (a fixed stride: the same page each time)."""
    step = max(1, -(-len(points) // limit))
    return points[::step]


def _trace_points(points: np.ndarray) -> dict[str, np.ndarray]:
    p = np.ascontiguousarray(points, dtype=np.float32)
    return {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2]}


def _rgb(colour: np.ndarray) -> str:
    r, g, b = (int(round(255 * float(c))) for c in colour)
    return f"rgb({r},{g},{b})"


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
    return text


def registration_figure(
    reg: Any,
    *,
    ground_truth: ArrayLike | None = None,
    title: str = "",
    max_scan_points: int = MAX_SCAN_POINTS,
) -> Any:
    """The plotly figure of a :class:`pointclm.PointCloudRegistration` (see the module
    documentation); :func:`write_html` saves it as a page."""
    go = _plotly()
    if isinstance(max_scan_points, bool) or not isinstance(max_scan_points, int):
        raise ValueError(f"max_scan_points must be an int >= 1, got {max_scan_points!r}")
    if max_scan_points < 1:
        raise ValueError(f"max_scan_points must be an int >= 1, got {max_scan_points!r}")
    scan = np.asarray(reg.target_points, dtype=np.float64).reshape(-1, 3)
    model = np.asarray(reg.source_points, dtype=np.float64).reshape(-1, 3)
    poses = np.asarray(reg.transformations, dtype=np.float64).reshape(-1, 4, 4)
    shown = _decimated(scan, max_scan_points)
    traces = [
        go.Scatter3d(
            **_trace_points(shown),
            mode="markers",
            marker={"size": 1.5, "color": _SCAN_GREY},
            name=f"scan ({len(shown)} of {len(scan)} points)",
            hoverinfo="skip",
        )
    ]
    sub = _decimated(model, MAX_MODEL_POINTS)
    colours = palette(len(poses))
    for k, (inst, T, colour) in enumerate(zip(reg.instances, poses, colours, strict=True)):
        traces.append(
            go.Scatter3d(
                **_trace_points(_placed(sub, T)),
                mode="markers",
                marker={"size": 2.5, "color": _rgb(colour)},
                name=_copy_name(k, inst),
            )
        )
    missed = None if ground_truth is None else _missed(model, poses, ground_truth)
    for j in missed or []:
        box = _box_lines(model, np.asarray(ground_truth, dtype=np.float64)[j])
        traces.append(
            go.Scatter3d(
                **_trace_points(box),
                mode="lines",
                line={"color": _MISSED, "width": 4, "dash": "dash"},
                name=f"missed ground truth {j}",
            )
        )
    n_true = 0 if ground_truth is None else len(np.asarray(ground_truth).reshape(-1, 16))
    return _laid_out(go.Figure(traces), reg, title, _summary(reg, missed, n_true))


def _laid_out(fig: Any, reg: Any, title: str, summary: str) -> Any:
    heading = f"{html.escape(title)}<br><sub>{summary}</sub>" if title else summary
    fig.update_layout(
        title={"text": heading},
        scene={"aspectmode": "data", "xaxis_title": "x", "yaxis_title": "y", "zaxis_title": "z"},
        legend={"itemsizing": "constant"},
        margin={"l": 0, "r": 0, "t": 60, "b": 0},
        paper_bgcolor="white",
    )
    if not reg.instances:
        reason = _empty_reason(reg) or "nothing found"
        fig.add_annotation(
            text=html.escape(f"no copy found: {reason}"),
            xref="paper",
            yref="paper",
            x=0.5,
            y=0.98,
            showarrow=False,
        )
    return fig


def write_html(
    path: str | os.PathLike[str],
    reg: Any,
    *,
    ground_truth: ArrayLike | None = None,
    title: str = "",
    max_scan_points: int = MAX_SCAN_POINTS,
) -> Path:
    """Write the page of a :class:`pointclm.PointCloudRegistration` to `path` (one HTML
    file, plotly.js inline: it opens with no network) and return the path.

    `ground_truth` (G, 4, 4): the true ``T_target_source`` poses; those no found pose
    matches are outlined. `title` heads the page above the summary.

    Raises
    ------
    ValueError
        If `path` cannot be written (its folder is missing or not writable) or an argument
        is malformed.
    ImportError
        If plotly is not installed.
    """
    file = check_output_path(path, "HTML page")
    fig = registration_figure(
        reg, ground_truth=ground_truth, title=title, max_scan_points=max_scan_points
    )
    with atomic_path(file) as tmp:
        fig.write_html(
            str(tmp), include_plotlyjs=True, full_html=True, config={"displaylogo": False}
        )
    return file

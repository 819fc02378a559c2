"""The page :func:`pointclm.html_page.write_html` writes: a small point viewer in plain
JavaScript on a 2D canvas, with the points inline (base64 float32), so it needs no library
and no network.

A 3D plotly figure costs seconds before its first frame in a browser without a GPU
(plotly.js is 4.8 MB to parse and its WebGL shaders compile in software); this viewer draws
its points into a pixel buffer with a depth buffer and is on screen in a fraction of that
(BENCHMARKS.md). Drag turns the view about the scene's up axis, shift-drag or the right
button moves it, the wheel zooms, a double click resets; a legend entry hides or shows its
layer. After the first frame the body carries ``data-drawn="1"`` (what tests wait for).
"""

from __future__ import annotations

import html
import json
from typing import Any

__all__ = ["page"]

_STYLE = """
html,body{margin:0;height:100%;font:14px system-ui,sans-serif;background:#fff;color:#222}
body{display:flex;flex-direction:column}
#head{padding:6px 12px;border-bottom:1px solid #ddd}
#head h1{font-size:16px;margin:0 0 2px 0}
#head .sub{color:#444}
#head .help{color:#777;font-size:12px}
#wrap{flex:1;display:flex;min-height:0}
#view{flex:1;min-width:0;display:block;cursor:grab;touch-action:none}
#legend{width:290px;overflow:auto;margin:0;padding:8px;list-style:none;
  border-left:1px solid #ddd}
#legend li{cursor:pointer;padding:2px 0;user-select:none}
#legend li.off{opacity:.35}
#legend .swatch{display:inline-block;width:12px;height:12px;margin-right:6px;
  vertical-align:-1px;border-radius:2px}
#legend .swatch.dash{height:0;border-top:2px dashed;border-radius:0;vertical-align:3px}
"""

_SCRIPT = r"""
(function () {
"use strict";
const data = JSON.parse(document.getElementById("pointclm-data").textContent);
function decode(b64) {
  const s = atob(b64), u = new Uint8Array(s.length);
  for (let i = 0; i < s.length; i++) u[i] = s.charCodeAt(i);
  return new Float32Array(u.buffer);
}
const layers = data.layers.map(l => Object.assign({}, l, {xyz: decode(l.points), on: true}));
const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
for (const l of layers) for (let i = 0; i < l.xyz.length; i += 3)
  for (let a = 0; a < 3; a++) { const v = l.xyz[i + a];
    if (Number.isFinite(v)) { if (v < lo[a]) lo[a] = v; if (v > hi[a]) hi[a] = v; } }
const found = lo[0] <= hi[0];
const centre = found ? lo.map((v, a) => (v + hi[a]) / 2) : [0, 0, 0];
const radius = found ? Math.max(Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) / 2,
  1e-9) : 1;
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
  a[0] * b[1] - a[1] * b[0]];
const unit = a => { const n = Math.hypot(a[0], a[1], a[2]) || 1; return a.map(v => v / n); };
function rotate(v, k, t) {  // Rodrigues: v turned by t about the unit axis k
  const c = Math.cos(t), s = Math.sin(t), kv = cross(k, v), d = dot(k, v) * (1 - c);
  return [0, 1, 2].map(a => v[a] * c + kv[a] * s + k[a] * d);
}
const worldUp = unit(data.up);
let view;
function reset() {
  const back = unit(data.back);
  const right = unit(cross(worldUp, back));
  view = {right: right, up: cross(back, right), back: back, zoom: 1, pan: [0, 0]};
}
reset();
const canvas = document.getElementById("view"), ctx = canvas.getContext("2d");
let depth = null, image = null, pixels = null, pending = false;
function resize() {
  const r = window.devicePixelRatio || 1;
  canvas.width = Math.max(1, Math.round(canvas.clientWidth * r));
  canvas.height = Math.max(1, Math.round(canvas.clientHeight * r));
  image = ctx.createImageData(canvas.width, canvas.height);
  pixels = new Uint32Array(image.data.buffer);
  depth = new Float32Array(canvas.width * canvas.height);
  draw();
}
function draw() { if (!pending) { pending = true; requestAnimationFrame(frame); } }
function frame() {
  pending = false;
  const w = canvas.width, h = canvas.height, r = window.devicePixelRatio || 1;
  const s = view.zoom * Math.min(w, h) / (2.1 * radius);
  const cx = w / 2 + view.pan[0] * r, cy = h / 2 + view.pan[1] * r;
  const R = view.right, U = view.up, B = view.back;
  pixels.fill(0xffffffff);
  depth.fill(-Infinity);
  for (const l of layers) {
    if (!l.on || l.kind !== "points") continue;
    const shades = [];
    for (let k = 0; k < 8; k++) {  // nearer is brighter: depth reads at a glance
      const f = 0.55 + 0.45 * k / 7, c = l.colour.map(v => Math.round(v * f));
      shades.push((255 << 24 | c[2] << 16 | c[1] << 8 | c[0]) >>> 0);
    }
    // A copy lies on the scan's own surface: lifted a little toward the eye, it shows.
    const lift = l.front ? 0.01 * radius : 0;
    const half = Math.floor(l.size * r / 2), p = l.xyz;  // a square 2 half + 1 wide
    for (let i = 0; i < p.length; i += 3) {
      const x = p[i] - centre[0], y = p[i + 1] - centre[1], z = p[i + 2] - centre[2];
      const px = Math.round(cx + s * (x * R[0] + y * R[1] + z * R[2]));
      const py = Math.round(cy - s * (x * U[0] + y * U[1] + z * U[2]));
      const d = x * B[0] + y * B[1] + z * B[2] + lift;
      if (!(d === d)) continue;
      const colour = shades[Math.max(0, Math.min(7, Math.round((d / radius + 1) * 3.5)))];
      for (let v = py - half; v <= py + half; v++) {
        if (v < 0 || v >= h) continue;
        for (let u = px - half; u <= px + half; u++) {
          if (u < 0 || u >= w) continue;
          const q = v * w + u;
          if (d > depth[q]) { depth[q] = d; pixels[q] = colour; }
        }
      }
    }
  }
  ctx.putImageData(image, 0, 0);
  for (const l of layers) {
    if (!l.on || l.kind !== "lines") continue;
    ctx.save();
    ctx.strokeStyle = "rgb(" + l.colour.join(",") + ")";
    ctx.lineWidth = l.size * r;
    ctx.setLineDash(l.dash ? [6 * r, 4 * r] : []);
    ctx.beginPath();
    let open = false;
    for (let i = 0; i < l.xyz.length; i += 3) {
      const x = l.xyz[i] - centre[0], y = l.xyz[i + 1] - centre[1], z = l.xyz[i + 2] - centre[2];
      if (!Number.isFinite(x + y + z)) { open = false; continue; }
      const px = cx + s * (x * R[0] + y * R[1] + z * R[2]);
      const py = cy - s * (x * U[0] + y * U[1] + z * U[2]);
      if (open) ctx.lineTo(px, py); else { ctx.moveTo(px, py); open = true; }
    }
    ctx.stroke();
    ctx.restore();
  }
  axes(r, h);
  document.body.dataset.drawn = "1";
}
function axes(r, h) {  // the world's axes, bottom left, turned as the view is
  const o = [40 * r, h - 40 * r], n = 28 * r, names = ["x", "y", "z"];
  const colours = ["#d62728", "#2ca02c", "#1f77b4"];
  ctx.save();
  ctx.lineWidth = 2 * r;
  ctx.font = (12 * r) + "px sans-serif";
  for (let a = 0; a < 3; a++) {
    const e = [0, 0, 0]; e[a] = 1;
    const tip = [o[0] + n * dot(e, view.right), o[1] - n * dot(e, view.up)];
    ctx.strokeStyle = ctx.fillStyle = colours[a];
    ctx.beginPath(); ctx.moveTo(o[0], o[1]); ctx.lineTo(tip[0], tip[1]); ctx.stroke();
    ctx.fillText(names[a], tip[0] + 3 * r, tip[1] - 3 * r);
  }
  ctx.restore();
}
let drag = null;
canvas.addEventListener("pointerdown", e => {
  drag = {x: e.clientX, y: e.clientY, move: e.shiftKey || e.button === 2};
  canvas.setPointerCapture(e.pointerId);
});
canvas.addEventListener("pointermove", e => {
  if (!drag) return;
  const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
  drag.x = e.clientX; drag.y = e.clientY;
  if (drag.move) { view.pan[0] += dx; view.pan[1] += dy; draw(); return; }
  for (const k of ["right", "up", "back"]) view[k] = rotate(view[k], worldUp, -dx * 0.01);
  for (const k of ["up", "back"]) view[k] = rotate(view[k], view.right, -dy * 0.01);
  draw();
});
canvas.addEventListener("pointerup", () => { drag = null; });
canvas.addEventListener("contextmenu", e => e.preventDefault());
canvas.addEventListener("dblclick", () => { reset(); draw(); });
canvas.addEventListener("wheel", e => {
  e.preventDefault();
  view.zoom = Math.min(100, Math.max(0.05, view.zoom * Math.exp(-e.deltaY * 0.001)));
  draw();
}, {passive: false});
const legend = document.getElementById("legend");
for (const l of layers) {
  const li = document.createElement("li"), sw = document.createElement("span");
  const text = document.createElement("span");
  sw.className = l.kind === "lines" ? "swatch dash" : "swatch";
  sw.style[l.kind === "lines" ? "borderColor" : "background"] = "rgb(" + l.colour + ")";
  text.className = "legendtext";
  text.textContent = l.name;
  li.append(sw, text);
  li.addEventListener("click", () => { l.on = !l.on; li.classList.toggle("off", !l.on); draw(); });
  legend.append(li);
}
document.getElementById("title").textContent = data.title || data.summary;
document.getElementById("summary").textContent = data.title ? data.summary : "";
window.addEventListener("resize", resize);
resize();
})();
"""


def page(content: dict[str, Any]) -> str:
    """The HTML of the viewer showing `content` (``title``, ``summary``, ``up``, ``back``
    and ``layers``: each a ``name``, ``kind`` (``points`` or ``lines``), ``colour`` (0-255
    RGB), ``size`` (CSS pixels), ``front`` (drawn over coincident points), ``dash`` and
    ``points`` (base64 little-endian float32 x, y, z triples; NaN breaks a line))."""
    # "</" in the data would end its <script> element early; "<\/" is the same JSON string.
    blob = json.dumps(content, separators=(",", ":")).replace("</", "<\\/")
    title = html.escape(content["title"] or content["summary"])
    return (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        f"<title>{title}</title><style>{_STYLE}</style></head>\n<body>"
        "<div id='head'><h1 id='title'></h1><div class='sub' id='summary'></div>"
        "<div class='help'>drag: turn &middot; shift-drag or right-drag: move &middot; "
        "wheel: zoom &middot; double click: reset &middot; click a legend entry: hide or "
        "show it</div></div>\n<div id='wrap'><canvas id='view'></canvas>"
        "<ul id='legend'></ul></div>\n"
        f"<script id='pointclm-data' type='application/json'>{blob}</script>\n"
        f"<script>{_SCRIPT}</script>\n</body></html>\n"
    )

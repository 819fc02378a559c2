"""The HTML page of a result: its size, and how long headless Chromium takes to open it.

    python -m benchmarks.interop.html_page --copies 20 --opens 5

Builds a bin of ``--copies`` bunnies (``pointclm.datasets.bins.make_bin_scene``, its depth
camera as viewpoint), registers it with ``heap=True``, writes the page with
``PointCloudRegistration.to_html`` (its own viewer, the scan subsampled on a voxel grid to
``pointclm.html_page.MAX_SCAN_POINTS``), and opens it ``--opens`` times in the system's
Chromium driven by playwright (a fresh tab each time, one browser): the time from navigation
until the first frame is on screen. For comparison, and to show where a plotly page's time
goes, the same layers as a plotly page (``registration_figure``, plotly.js inline: what
``to_html`` wrote before), plotly.js with a 3D figure of two points, and plotly.js with an
empty figure. Prints a Markdown table (open time in seconds and as a multiple of the page's),
what the page holds (layers, points per layer, bytes of data), the date, the machine and its
load average (the machine may be shared: the times move with its load).

Needs playwright (``pip install playwright``), plotly for the comparison rows, and Chromium on
PATH (Debian: ``apt-get install chromium``); playwright's own browser download is never used.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import platform
import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

READY = (
    "() => { const g = document.querySelector('.js-plotly-plot');"
    " return g && g._fullLayout && document.querySelector('canvas'); }"
)
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


def _result(copies: int, seed: int):
    import pointclm
    from pointclm.datasets.bins import BinParams, make_bin_scene

    scene = make_bin_scene(seed, BinParams(model="bunny", copies=(copies, copies)))
    reg = pointclm.register_point_clouds(
        scene.model_points,
        scene.scan,
        voxel_size=scene.voxel_size,
        viewpoint=scene.sensor,
        heap=True,
    )
    return scene, reg


def _descendants_cpu_s() -> float:
    """CPU seconds (user + system) used so far by the running descendants of this process:
    the browser's processes (and playwright's driver, which idles meanwhile)."""
    parents: dict[int, int] = {}
    spent: dict[int, float] = {}
    tick = os.sysconf("SC_CLK_TCK")
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        parents[int(entry.name)] = int(fields[1])
        spent[int(entry.name)] = (int(fields[11]) + int(fields[12])) / tick
    ours = {os.getpid()}
    for _ in range(8):  # driver, browser, its zygotes, renderers and GPU process
        ours |= {pid for pid, parent in parents.items() if parent in ours}
    return sum(spent.get(pid, 0.0) for pid in ours - {os.getpid()})


def _open_times(
    pages: list[Path], opens: int, ready: list[str]
) -> tuple[list[list[float]], list[list[float]]]:
    """Seconds from navigation until `ready[i]` holds, `opens` times per page, and the CPU
    seconds the browser's processes spent meanwhile (what the wall time would be on an idle
    machine, were the work not spread over processes)."""
    from playwright.sync_api import sync_playwright

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        raise SystemExit("no chromium on PATH (Debian: apt-get install chromium)")
    wall: list[list[float]] = [[] for _ in pages]
    cpu: list[list[float]] = [[] for _ in pages]
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
        try:
            for _ in range(opens):
                for i, page_path in enumerate(pages):
                    tab = browser.new_page(viewport={"width": 1200, "height": 800})
                    c0, t0 = _descendants_cpu_s(), time.perf_counter()
                    tab.goto(page_path.as_uri(), wait_until="load")
                    tab.wait_for_function(ready[i], polling=20, timeout=120_000)
                    wall[i].append(time.perf_counter() - t0)
                    cpu[i].append(_descendants_cpu_s() - c0)
                    tab.close()
        finally:
            browser.close()
    return wall, cpu


DRAWN = "() => document.body.dataset.drawn === '1'"
PLOTLY_EMPTY = (
    "() => { const g = document.querySelector('.js-plotly-plot'); return g && g._fullLayout; }"
)


def _pages(folder: Path, scene, reg) -> list[tuple[str, Path, str]]:
    import plotly.graph_objects as go
    from pointclm.html_page import registration_figure

    page = reg.to_html(folder / "result.html", ground_truth=scene.poses, title="bin")
    rows = [(f"this page ({len(reg.instances)} copies)", page, DRAWN)]
    before = folder / "plotly.html"
    fig = registration_figure(reg, ground_truth=scene.poses, title="bin")
    fig.write_html(str(before), include_plotlyjs=True, full_html=True)
    rows.append(("the same layers in plotly (scatter3d)", before, READY))
    two = folder / "plotly-two.html"
    go.Figure([go.Scatter3d(x=[0, 1], y=[0, 1], z=[0, 1], mode="markers")]).write_html(
        str(two), include_plotlyjs=True, full_html=True
    )
    rows.append(("plotly.js, a 3D figure of 2 points", two, READY))
    floor = folder / "plotly-empty.html"
    go.Figure().write_html(str(floor), include_plotlyjs=True, full_html=True)
    rows.append(("plotly.js, an empty figure", floor, PLOTLY_EMPTY))
    return rows


def _held(page: Path) -> str:

    text = page.read_text()
    start = text.index("type='application/json'>") + len("type='application/json'>")
    content = json.loads(text[start : text.index("</script>", start)])
    sizes = [len(base64.b64decode(layer["points"])) // 12 for layer in content["layers"]]
    data = len(text[start : text.index("</script>", start)])
    return (
        f"{len(sizes)} layers, points per layer: scan {sizes[0]}, copies "
        f"{min(sizes[1:], default=0)}-{max(sizes[1:], default=0)}; float32 base64; "
        f"data {data / 1e6:.2f} MB of {page.stat().st_size / 1e6:.2f} MB"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--copies", type=int, default=20, help="bunnies in the bin (default 20)")
    parser.add_argument("--opens", type=int, default=5, help="times each page is opened")
    parser.add_argument("--seed", type=int, default=0, help="the bin scene's seed")
    args = parser.parse_args()
    t0 = time.perf_counter()
    scene, reg = _result(args.copies, args.seed)
    t_reg = time.perf_counter() - t0
    folder = Path(tempfile.mkdtemp(prefix="pointclm-html-"))
    t0 = time.perf_counter()
    reg.to_html(folder / "result.html", ground_truth=scene.poses, title="bin")
    t_write = time.perf_counter() - t0
    rows = _pages(folder, scene, reg)
    load_before = os.getloadavg()[0]
    wall, cpu = _open_times([r[1] for r in rows], args.opens, [r[2] for r in rows])
    print(
        f"# HTML page, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
        f"{platform.machine()}, {os.cpu_count()} CPUs, {_browser_version()}"
    )
    print(
        f"bin of {args.copies} bunnies: {len(reg.instances)} copies found "
        f"({t_reg:.1f} s), page written in {t_write:.2f} s; {_held(rows[0][1])}\n"
    )
    print(
        f"| page | size (MB) | open, median of {args.opens} (s) | fastest (s) "
        "| browser CPU, median (s) | open / this page's |"
    )
    print("|---|---|---|---|---|---|")
    ours = statistics.median(wall[0])
    for k, (name, path, _) in enumerate(rows):
        print(
            f"| {name} | {path.stat().st_size / 1e6:.2f} | {statistics.median(wall[k]):.2f} | "
            f"{min(wall[k]):.2f} | {statistics.median(cpu[k]):.2f} | "
            f"{statistics.median(wall[k]) / ours:.1f} |"
        )
    print(f"\nopen times of this page (s): {np.round(wall[0], 2).tolist()}")
    print(f"load average before / after: {load_before:.1f} / {os.getloadavg()[0]:.1f}")


def _browser_version() -> str:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        return "no chromium"
    out = subprocess.run([chromium, "--version"], capture_output=True, text=True, check=False)
    return out.stdout.strip() or "chromium"


if __name__ == "__main__":
    main()

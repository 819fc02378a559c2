"""The HTML page of a result: its size, and how long headless Chromium takes to open it.

    python benchmarks/html_page.py --copies 20 --opens 5

Builds a bin of ``--copies`` bunnies (``pointclm.datasets.bins.make_bin_scene``, its depth
camera as viewpoint), registers it with ``heap=True``, writes the page with
``PointCloudRegistration.to_html`` (plotly.js inline, the scan decimated to
``pointclm.html_page.MAX_SCAN_POINTS``), and opens it ``--opens`` times in the system's
Chromium driven by playwright (a fresh tab each time, one browser): the time from navigation
until plotly has laid out the figure and its WebGL canvas exists, which is when the page
shows the scan. Also timed: a page holding plotly.js and an empty figure, the floor of any
plotly page on the machine. Prints a Markdown table and the machine's load average (the
machine is shared: the times move with its load).

Needs plotly, playwright (``pip install playwright``) and Chromium on PATH (Debian:
``apt-get install chromium``); playwright's own browser download is never used.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--copies", type=int, default=20, help="bunnies in the bin (default 20)")
    parser.add_argument("--opens", type=int, default=5, help="times each page is opened")
    parser.add_argument("--seed", type=int, default=0, help="the bin scene's seed")
    args = parser.parse_args()
    import plotly.graph_objects as go
    from pointclm.html_page import MAX_SCAN_POINTS

    t0 = time.perf_counter()
    scene, reg = _result(args.copies, args.seed)
    t_reg = time.perf_counter() - t0
    folder = Path(tempfile.mkdtemp(prefix="pointclm-html-"))
    t0 = time.perf_counter()
    page = reg.to_html(folder / "result.html", ground_truth=scene.poses, title="bin")
    t_write = time.perf_counter() - t0
    floor = folder / "empty.html"
    go.Figure().write_html(str(floor), include_plotlyjs=True, full_html=True)
    floor_ready = "() => { const g = document.querySelector('.js-plotly-plot');"
    floor_ready += " return g && g._fullLayout; }"
    load_before = os.getloadavg()[0]
    wall, cpu = _open_times([page, floor], args.opens, [READY, floor_ready])
    n_scan = min(len(reg.target_points), MAX_SCAN_POINTS)
    print(
        f"# HTML page, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
        f"{platform.machine()}, {os.cpu_count()} CPUs"
    )
    print(
        f"bin of {args.copies} bunnies: {len(reg.instances)} copies found "
        f"({t_reg:.1f} s), page written in {t_write:.2f} s\n"
    )
    print(
        f"| page | size (MB) | open, median of {args.opens} (s) | fastest (s) "
        "| browser CPU, median (s) |"
    )
    print("|---|---|---|---|---|")
    rows = (f"{len(reg.instances)} copies, {n_scan} scan points", "plotly.js, empty figure")
    for k, (name, path) in enumerate(zip(rows, (page, floor), strict=True)):
        print(
            f"| {name} | {path.stat().st_size / 1e6:.2f} | {statistics.median(wall[k]):.2f} | "
            f"{min(wall[k]):.2f} | {statistics.median(cpu[k]):.2f} |"
        )
    print(f"\nopen times (s): {np.round(wall[0], 2).tolist()}")
    print(f"load average before / after: {load_before:.1f} / {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()

"""A result as one self-contained HTML page (plotly): what the page holds, the command's
--html, and the page opened in a real headless Chromium (skipped without one)."""

from __future__ import annotations

import io
import json
import re
import shutil
import sys

import numpy as np
import pointclm
import pytest
from pointclm.cli import main
from pointclm.datasets.scenes import SceneParams, make_realistic_scene
from pointclm.io import write_ply

pytest.importorskip("plotly")

#: plotly.js draws 3D traces with WebGL; headless Chromium without a GPU renders it in
#: software (SwiftShader), which recent versions enable only when asked.
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


@pytest.fixture(scope="module")
def scene_and_result():
    scene = make_realistic_scene(0, SceneParams(model="bunny"))
    reg = pointclm.register_point_clouds(
        scene.source_points, scene.target_points, viewpoint=scene.viewpoint
    )
    assert len(reg.instances) >= 3
    return scene, reg


def _figure_json(page: str) -> dict:
    """The figure plotly wrote into the page (the arguments of Plotly.newPlot)."""
    start = page.index("Plotly.newPlot(")
    args = page[start + len("Plotly.newPlot(") :]
    data_start = args.index("[")
    decoder = json.JSONDecoder()
    data, end = decoder.raw_decode(args[data_start:])
    rest = args[data_start + end :].lstrip(", ")
    layout, _ = decoder.raw_decode(rest)
    return {"data": data, "layout": layout}


def _names(reg) -> list[str]:
    return [f"copy {k}: confidence {i.confidence:.2f}" for k, i in enumerate(reg.instances)]


def test_the_page_is_self_contained_and_lists_every_copy(tmp_path, scene_and_result):
    _, reg = scene_and_result
    path = reg.to_html(tmp_path / "r.html", title="bunny <scan>")
    page = path.read_text()
    # plotly.js is inline: no script is fetched, so the page opens with no network.
    assert not re.search(r"<script[^>]*\bsrc=", page)
    assert "plotly.js v" in page or "plotly.js" in page
    fig = _figure_json(page)
    names = [t["name"] for t in fig["data"]]
    assert names[0].startswith(f"scan ({len(reg.target_points)} of {len(reg.target_points)}")
    assert names[1:] == _names(reg)
    assert fig["data"][0]["marker"]["color"] == "rgb(160,160,160)"
    colours = {t["marker"]["color"] for t in fig["data"][1:]}
    assert len(colours) == len(reg.instances)  # each copy its own colour
    assert "bunny &lt;scan&gt;" in fig["layout"]["title"]["text"]
    assert f"{len(reg.instances)} copies found" in fig["layout"]["title"]["text"]


def test_missed_true_copies_are_outlined(tmp_path, scene_and_result):
    scene, reg = scene_and_result
    far = scene.poses[0].copy()
    far[:3, 3] += 10.0  # a true copy where nothing was found
    truth = np.concatenate([scene.poses, far[None]])
    page = reg.to_html(tmp_path / "gt.html", ground_truth=truth).read_text()
    fig = _figure_json(page)
    missed = [t for t in fig["data"] if t["name"].startswith("missed ground truth")]
    assert [t["name"] for t in missed][-1] == f"missed ground truth {len(scene.poses)}"
    assert missed[-1]["mode"] == "lines" and missed[-1]["line"]["dash"] == "dash"
    assert f"of {len(truth)} true copies found" in fig["layout"]["title"]["text"]


def test_the_scan_is_decimated(tmp_path, scene_and_result):
    from pointclm.html_page import write_html

    _, reg = scene_and_result
    page = write_html(tmp_path / "small.html", reg, max_scan_points=1000).read_text()
    name = _figure_json(page)["data"][0]["name"]
    shown = int(re.match(r"scan \((\d+) of", name).group(1))
    assert 500 < shown <= 1000


def test_bad_arguments_are_value_errors(tmp_path, scene_and_result):
    _, reg = scene_and_result
    with pytest.raises(ValueError, match="the folder .* does not exist"):
        reg.to_html(tmp_path / "missing" / "r.html")
    with pytest.raises(ValueError, match=r"ground_truth must be finite \(G, 4, 4\)"):
        reg.to_html(tmp_path / "r.html", ground_truth=np.eye(3))
    with pytest.raises(ValueError, match="max_scan_points"):
        from pointclm.html_page import write_html

        write_html(tmp_path / "r.html", reg, max_scan_points=0)


def test_without_plotly_the_error_names_the_extra(tmp_path, monkeypatch, scene_and_result):
    _, reg = scene_and_result
    monkeypatch.setitem(sys.modules, "plotly.graph_objects", None)
    with pytest.raises(ImportError, match=r"pip install 'pointclm\[viz\]'"):
        reg.to_html(tmp_path / "r.html")


def test_register_command_writes_the_page(tmp_path, scene_and_result, capsys):
    scene, _ = scene_and_result
    model, scan, truth = tmp_path / "bunny.ply", tmp_path / "scan.ply", tmp_path / "gt.npy"
    write_ply(model, scene.source_points)
    write_ply(scan, scene.target_points)
    np.save(truth, scene.poses)
    out = tmp_path / "r.html"
    args = ["register", str(model), str(scan), "--html", str(out), "--quiet"]
    assert main([*args, "--ground-truth", str(truth)]) == 0
    fig = _figure_json(out.read_text())
    assert fig["data"][1]["name"].startswith("copy 0: confidence")
    assert "bunny.ply in scan.ply" in fig["layout"]["title"]["text"]


def test_register_refuses_an_unwritable_page_before_working(tmp_path, capsys):
    code = main(["register", "a.ply", "b.ply", "--html", str(tmp_path / "no" / "r.html")])
    assert code != 0
    assert "--html" in capsys.readouterr().err


# --- in a real browser --------------------------------------------------------------------


def _browser():
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("no chromium on PATH (Debian: apt-get install chromium)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="pip install playwright")
    return chromium, sync_api


def test_the_page_opens_in_headless_chromium_drawn_and_without_errors(tmp_path, scene_and_result):
    chromium, sync_api = _browser()
    _, reg = scene_and_result
    path = reg.to_html(tmp_path / "r.html")
    errors: list[str] = []
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 800})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(path.as_uri(), wait_until="load")
            page.wait_for_function(
                "() => { const g = document.querySelector('.js-plotly-plot');"
                " return g && g._fullLayout && document.querySelector('canvas'); }",
                timeout=60_000,
            )
            page.wait_for_timeout(300)
            legend = page.eval_on_selector_all(".legendtext", "els => els.map(e => e.textContent)")
            shot = page.locator("#scene canvas").first.screenshot()
        finally:
            browser.close()
    assert errors == []
    assert legend[1:] == _names(reg)
    import matplotlib.image

    pixels = matplotlib.image.imread(io.BytesIO(shot))[..., :3]
    assert pixels.std() > 0.02, "the plot area is blank"
    first = np.array([int(v) for v in re.findall(r"\d+", _first_colour(path))]) / 255
    assert (np.abs(pixels - first).max(axis=-1) < 0.06).sum() > 20, "copy 0 is not drawn"


def _first_colour(path) -> str:
    return _figure_json(path.read_text())["data"][1]["marker"]["color"]

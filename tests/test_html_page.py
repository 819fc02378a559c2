"""A result as one self-contained HTML page: what the page holds, the command's --html,
the plotly figure for notebooks, and the page opened, turned and clicked in a real headless
Chromium (skipped without one)."""

from __future__ import annotations

import base64
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
from pointclm.html_page import voxel_subsample, write_html
from pointclm.io import write_ply

#: Headless Chromium without a GPU draws canvases in software (SwiftShader), which recent
#: versions enable only when asked.
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


@pytest.fixture(scope="module")
def scene_and_result():
    scene = make_realistic_scene(0, SceneParams(model="bunny"))
    reg = pointclm.register_point_clouds(
        scene.source_points, scene.target_points, viewpoint=scene.viewpoint
    )
    assert len(reg.instances) >= 3
    return scene, reg


def _content(page: str) -> dict:
    """The data the page embeds (its JSON script element)."""
    start = page.index("<script id='pointclm-data' type='application/json'>")
    blob = page[page.index(">", start) + 1 : page.index("</script>", start)]
    return json.loads(blob)


def _points(layer: dict) -> np.ndarray:
    return np.frombuffer(base64.b64decode(layer["points"]), dtype="<f4").reshape(-1, 3)


def _names(reg) -> list[str]:
    return [f"copy {k}: confidence {i.confidence:.2f}" for k, i in enumerate(reg.instances)]


def test_the_page_is_self_contained_and_lists_every_copy(tmp_path, scene_and_result):
    _, reg = scene_and_result
    path = reg.to_html(tmp_path / "r.html", title="bunny <scan>")
    page = path.read_text()
    # Nothing is fetched: no script, style sheet or image comes from elsewhere.
    assert not re.search(r"<(script|img|iframe)[^>]*\bsrc=|<link|@import|https?://", page)
    assert "<title>bunny &lt;scan&gt;</title>" in page
    content = _content(page)
    layers = content["layers"]
    n = len(reg.target_points)
    assert layers[0]["name"] == f"scan ({n} of {n} points)"
    assert layers[0]["colour"] == [160, 160, 160]
    np.testing.assert_allclose(_points(layers[0]), reg.target_points, atol=1e-6, rtol=1e-6)
    assert [layer["name"] for layer in layers[1:]] == _names(reg)
    colours = {tuple(layer["colour"]) for layer in layers[1:]}
    assert len(colours) == len(reg.instances)  # each copy its own colour
    model = voxel_subsample(np.asarray(reg.source_points), 400)[0]
    T = reg.transformations[0]
    np.testing.assert_allclose(_points(layers[1]), model @ T[:3, :3].T + T[:3, 3], atol=1e-5)
    assert content["title"] == "bunny <scan>"
    assert content["summary"].startswith(f"{len(reg.instances)} copies found")


def test_missed_true_copies_are_outlined(tmp_path, scene_and_result):
    scene, reg = scene_and_result
    far = scene.poses[0].copy()
    far[:3, 3] += 10.0  # a true copy where nothing was found
    truth = np.concatenate([scene.poses, far[None]])
    content = _content(reg.to_html(tmp_path / "gt.html", ground_truth=truth).read_text())
    missed = [t for t in content["layers"] if t["name"].startswith("missed ground truth")]
    assert [t["name"] for t in missed][-1] == f"missed ground truth {len(scene.poses)}"
    assert missed[-1]["kind"] == "lines" and missed[-1]["dash"]
    box = _points(missed[-1])
    assert len(box) == 36 and np.isnan(box[2::3]).all()  # 12 edges, NaN between
    assert f"of {len(truth)} true copies found" in content["summary"]


def test_the_scan_is_subsampled_on_a_voxel_grid(tmp_path, scene_and_result):
    _, reg = scene_and_result
    page = write_html(tmp_path / "small.html", reg, max_scan_points=1000).read_text()
    name = _content(page)["layers"][0]["name"]
    shown = int(re.match(r"scan \((\d+) of \d+ points, one per [\d.e-]+ voxel\)", name).group(1))
    assert 900 < shown <= 1000


def test_voxel_subsample_keeps_at_most_the_budget_spread_over_the_cloud():
    rng = np.random.default_rng(0)
    dense = np.concatenate([rng.random((20_000, 3)) * 0.1, 1 + rng.random((2_000, 3)) * 0.1])
    kept, cell = voxel_subsample(dense, 1000)
    assert 900 < len(kept) <= 1000 and cell > 0
    # A stride keeps the dense blob's share (a tenth here for the small one); the grid keeps
    # the two blobs alike, they being the same size.
    assert 0.3 < (kept[:, 0] > 0.5).mean() < 0.7
    assert {tuple(p) for p in kept} <= {tuple(p) for p in dense}
    again, _ = voxel_subsample(dense, 1000)
    np.testing.assert_array_equal(kept, again)
    few, cell = voxel_subsample(dense[:10], 1000)
    assert len(few) == 10 and cell == 0.0
    assert len(voxel_subsample(dense, 1)[0]) == 1


def test_bad_arguments_are_value_errors(tmp_path, scene_and_result):
    _, reg = scene_and_result
    with pytest.raises(ValueError, match="the folder .* does not exist"):
        reg.to_html(tmp_path / "missing" / "r.html")
    with pytest.raises(ValueError, match=r"ground_truth must be finite \(G, 4, 4\)"):
        reg.to_html(tmp_path / "r.html", ground_truth=np.eye(3))
    with pytest.raises(ValueError, match="max_scan_points"):
        write_html(tmp_path / "r.html", reg, max_scan_points=0)


def test_the_page_needs_no_plotly_and_the_figure_names_the_extra(
    tmp_path, monkeypatch, scene_and_result
):
    from pointclm.html_page import registration_figure

    _, reg = scene_and_result
    monkeypatch.setitem(sys.modules, "plotly.graph_objects", None)
    assert reg.to_html(tmp_path / "r.html").stat().st_size > 0
    with pytest.raises(ImportError, match=r"pip install 'pointclm\[viz\]'"):
        registration_figure(reg)


def test_the_plotly_figure_draws_the_same_layers(scene_and_result):
    pytest.importorskip("plotly")
    from pointclm.html_page import registration_figure

    _, reg = scene_and_result
    fig = registration_figure(reg, title="bunny <scan>")
    assert [t.name for t in fig.data[1:]] == _names(reg)
    assert fig.data[0].marker.color == "rgb(160,160,160)"
    assert "bunny &lt;scan&gt;" in fig.layout.title.text


def test_register_command_writes_the_page(tmp_path, scene_and_result, capsys):
    scene, _ = scene_and_result
    model, scan, truth = tmp_path / "bunny.ply", tmp_path / "scan.ply", tmp_path / "gt.npy"
    write_ply(model, scene.source_points)
    write_ply(scan, scene.target_points)
    np.save(truth, scene.poses)
    out = tmp_path / "r.html"
    args = ["register", str(model), str(scan), "--html", str(out), "--quiet"]
    assert main([*args, "--ground-truth", str(truth)]) == 0
    content = _content(out.read_text())
    assert content["layers"][1]["name"].startswith("copy 0: confidence")
    assert "bunny.ply in scan.ply" in content["title"]


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
            page.wait_for_function("() => document.body.dataset.drawn === '1'", timeout=60_000)
            legend = page.eval_on_selector_all(".legendtext", "els => els.map(e => e.textContent)")
            canvas = page.locator("#view")
            shots = [canvas.screenshot()]
            page.locator("#legend li").nth(1).click()  # hides copy 0
            page.wait_for_timeout(200)
            shots.append(canvas.screenshot())
            box = canvas.bounding_box()
            page.mouse.move(box["x"] + 300, box["y"] + 300)
            page.mouse.down()
            page.mouse.move(box["x"] + 420, box["y"] + 360, steps=4)
            page.mouse.up()
            page.wait_for_timeout(200)
            shots.append(canvas.screenshot())
        finally:
            browser.close()
    assert errors == []
    assert legend[1:] == _names(reg)
    import matplotlib.image

    drawn, hidden, turned = (matplotlib.image.imread(io.BytesIO(s))[..., :3] for s in shots)
    assert drawn.std() > 0.02, "the plot area is blank"
    first = np.array(_content(path.read_text())["layers"][1]["colour"]) / 255
    assert _shaded_like(drawn, first) > 20, "copy 0 is not drawn"
    assert _shaded_like(hidden, first) < _shaded_like(drawn, first) / 10, "copy 0 not hidden"
    assert np.abs(turned - hidden).mean() > 0.005, "a drag does not turn the view"


def _shaded_like(pixels: np.ndarray, colour: np.ndarray) -> int:
    """Pixels of `colour` at some brightness (the page shades by depth)."""
    f = (pixels @ colour) / (colour @ colour)
    off = np.abs(pixels - f[..., None] * colour).max(axis=-1)
    return int(((off < 0.04) & (f > 0.45) & (f < 1.05)).sum())

"""report.html's 3D viewer (reports/viewer.py): the views it builds, the size budget it keeps, and
in headless Chromium, a small run's report opened from disk with no network: every mesh loads on a
WebGL canvas, moving one camera moves the others, and each toggle changes what is drawn.

The browser test needs Debian's ``chromium`` (scripts/setup.sh --test installs it) and is skipped
with that reason without it. SALSBENCH_WRITE_FIGURES=1 makes it write docs/figures/viewer.png.
"""

from __future__ import annotations

import io
import json
import os
import re
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

import reports.viewer as viewer
from tests.browser import Page, needs_chromium
from tests.test_reports_html import _Collect, write_fake_meshes

FIGURE = Path(__file__).resolve().parents[1] / "docs" / "figures" / "viewer.png"


def _data(page: str) -> dict:
    """The viewer's JSON data in a page."""
    text = re.search(r'<script type="application/json" id="viewer-data">(.*?)</script>', page, re.S).group(1)
    return json.loads(text)


def _viewer(meshes: Path, methods=("sals", "sdf"), **kw) -> str:
    options = dict(preset="default", up="", vmax=0.01, page_budget=viewer.DEFAULT_SIZE_BUDGET, page_bytes=0, limit=24)
    options.update(kw)
    shapes = sorted(p.name for p in meshes.iterdir())
    return viewer.viewer_html(shapes, list(methods), meshes, lambda s, m: f"metrics of {m} on {s}",
                              {"sals": "#ff0000", "sdf": "#0000ff"}, **options)


def test_size_budget_is_the_argument_else_the_environment_else_30_mb(monkeypatch):
    monkeypatch.delenv(viewer.SIZE_BUDGET_ENV, raising=False)
    assert viewer.size_budget() == 30_000_000 and viewer.size_budget(1234) == 1234
    monkeypatch.setenv(viewer.SIZE_BUDGET_ENV, "2.5")
    assert viewer.size_budget() == 2_500_000
    monkeypatch.setenv(viewer.SIZE_BUDGET_ENV, "lots")
    with pytest.raises(ValueError, match="expected a number of MB"):
        viewer.size_budget()


def test_scripts_are_inlined_only_when_they_cannot_end_early():
    assert viewer.inline_script("let a = 1;", "text/plain", "x") == '<script type="text/plain" id="x">let a = 1;</script>'
    for bad in ("a</script>b", "a</SCRIPT", "<!-- b"):
        with pytest.raises(ValueError, match="cannot be inlined"):
            viewer.inline_script(bad)
    data = viewer.json_script({"name": "</script><b>"}, "d")
    assert "</script><b>" not in data and json.loads(data[data.index(">") + 1:-len("</script>")]) == {"name": "</script><b>"}


def test_every_view_has_its_mesh_or_says_why_not(tmp_path):
    meshes = tmp_path / "meshes"
    write_fake_meshes(meshes)  # cube, sphere, cylinder; sdf has no cylinder mesh
    (meshes / "sphere" / "sals.ply").write_text("not a mesh")
    (meshes / "cylinder" / "gt.ply").unlink()
    data = _data(_viewer(meshes, up="z"))  # a scene's up axis
    by_shape = {s["name"]: {v["name"]: v for v in s["views"]} for s in data["shapes"]}
    assert list(by_shape) == ["cube", "cylinder", "sphere"]
    cube = by_shape["cube"]
    assert list(cube) == ["GT", "sals", "sdf"] and all(v["glb"] for v in cube.values())
    assert cube["GT"]["caption"] == "ground truth · 12 faces" and cube["sals"]["caption"] == "metrics of sals on cube"
    assert cube["sals"]["faces"] == cube["sals"]["fileFaces"] == 48  # the subdivided box, drawn in full
    assert by_shape["cylinder"]["sdf"]["message"] == "no mesh" and not by_shape["cylinder"]["sdf"]["glb"]
    assert by_shape["cylinder"]["GT"]["message"] == "no GT mesh" and by_shape["cylinder"]["sals"]["glb"]
    assert data["shapes"][1]["camera"]["target"] == pytest.approx([0, 0, 0], abs=0.01)  # framed by sals' mesh
    assert by_shape["sphere"]["sals"]["message"].startswith("unreadable")
    assert data["shapes"][0]["camera"]["up"] == [0.0, 0.0, 1.0]  # the views orbit about z, as the thumbnails stand


def test_the_viewer_fits_its_budget_by_decimating_the_largest_mesh_and_says_so(tmp_path):
    meshes = tmp_path / "meshes"
    (meshes / "ball").mkdir(parents=True)
    trimesh.creation.icosphere(subdivisions=3).export(meshes / "ball" / "gt.ply")  # 1,280 faces
    trimesh.creation.icosphere(subdivisions=5).export(meshes / "ball" / "sals.ply")  # 20,480 faces
    full = _viewer(meshes, ("sals",))
    assert "Every mesh is drawn in full" in full
    budget = len(full.encode()) - 20_000
    page = _viewer(meshes, ("sals",), page_budget=budget)
    assert len(page.encode()) <= budget
    views = {v["name"]: v for v in _data(page)["shapes"][0]["views"]}
    assert views["GT"]["faces"] == 1_280  # the smaller mesh is kept whole
    assert views["sals"]["fileFaces"] == 20_480 and 2_000 <= views["sals"]["faces"] < 20_480
    assert re.search(r"1 mesh\(es\) are drawn decimated .*ball / sals: [\d,]+ of 20,480 faces", page)
    assert "No 3D viewer" in _viewer(meshes, ("sals",), page_budget=budget, page_bytes=budget)


def test_shapes_beyond_the_budget_are_left_out_last_first():
    def build(i, caps):
        return viewer.ShapeViews(f"s{i}", [viewer.View("GT", "", glb="x" * 1000, faces=10, file_faces=10)])

    shapes, dropped = viewer.fit_views(build, 3, 2500)  # 10 faces are never decimated: two shapes fit
    assert [s.shape for s in shapes] == ["s0", "s1"] and dropped == 1


# ---------------------------------------------------------------------------------------------
# In headless Chromium
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_run(tmp_path_factory) -> Path:
    """An oracle run of sdf and bof on the first built-in shape at grid 32: its run directory."""
    from runner.cli import main

    out = tmp_path_factory.mktemp("viewer") / "run"
    code = main(["--mode", "oracle", "--methods", "sdf", "bof", "--grid", "32", "--eval-points", "20000",
                 "--limit", "1", "--out", str(out), "--cache-dir", str(out.parent / "cache"), "--quiet",
                 "--executor", "local"])
    assert code == 0
    return out


def _image(page: Page, view: int) -> np.ndarray:
    url = page.evaluate(f"salsbenchViewer.image({view})")
    return np.asarray(Image.open(io.BytesIO(__import__("base64").b64decode(url.split(",", 1)[1]))).convert("RGB"), int)


def _changed_pixels(a: np.ndarray, b: np.ndarray) -> int:
    return int((np.abs(a - b).sum(axis=2) > 30).sum())


@needs_chromium
@pytest.mark.slow
def test_a_small_run_report_shows_every_mesh_in_linked_views_in_a_real_browser(small_run, tmp_path):
    report = small_run / "report.html"
    assert report.stat().st_size <= viewer.DEFAULT_SIZE_BUDGET
    with Page(report.resolve().as_uri(), tmp_path / "profile") as page:
        page.wait_for("window.salsbenchViewer && salsbenchViewer.state.loaded")
        status = page.evaluate("salsbenchViewer.status()")
        assert status == [{"name": n, "status": "ok"} for n in ("GT", "sdf", "bof")]
        contexts = page.evaluate("[...document.querySelectorAll('#viewer-grid canvas')]"
                                 ".map(c => !!c.getContext('webgl2') && c.width > 0)")
        assert contexts == [True, True, True]  # a WebGL canvas per view, each drawn

        # drag the middle of view 1 with the mouse: every view's camera follows
        before = page.evaluate("salsbenchViewer.cameras()")
        x, y = page.evaluate("(() => { document.getElementById('viewer').scrollIntoView(); const r = document"
                             ".querySelectorAll('#viewer-grid canvas')[1].getBoundingClientRect();"
                             " return [r.x + r.width / 2, r.y + r.height / 2]; })()")
        page.mouse("mouseMoved", x, y)
        page.mouse("mousePressed", x, y, buttons=1)
        for step in range(1, 6):
            page.mouse("mouseMoved", x + 12 * step, y + 4 * step, buttons=1)
        page.mouse("mouseReleased", x + 60, y + 20)
        after = page.evaluate("salsbenchViewer.cameras()")
        assert not np.allclose(after[1]["position"], before[1]["position"])  # view 1 turned
        for camera in after:
            np.testing.assert_allclose(camera["position"], after[1]["position"])
            np.testing.assert_allclose(camera["quaternion"], after[1]["quaternion"])
            np.testing.assert_allclose(camera["target"], after[1]["target"])

        # each toggle changes what the prediction views draw; error colouring leaves the GT as it is
        shown = [_image(page, v) for v in range(3)]
        for toggle in ("error", "edges", "wire"):
            page.evaluate(f"document.getElementById('viewer-{toggle}').click()")
            changed = [_changed_pixels(a, _image(page, v)) for v, a in enumerate(shown)]
            assert min(changed[1:]) > 500, (toggle, changed)
            assert toggle != "error" or changed[0] == 0
            page.evaluate(f"document.getElementById('viewer-{toggle}').click()")

        if os.environ.get("SALSBENCH_WRITE_FIGURES") == "1":
            page.evaluate("document.querySelector('nav').style.display = 'none'; for (const id of ['viewer-error',"
                          " 'viewer-edges', 'viewer-reset']) document.getElementById(id).click();"
                          " salsbenchViewer.renderNow()")
            box = page.evaluate("(() => { const r = document.getElementById('viewer').getBoundingClientRect();"
                                " return [r.x, r.y + window.scrollY, r.width, r.height]; })()")
            shot = page.send("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True, "clip": dict(
                x=box[0], y=box[1], width=box[2], height=min(box[3], 640), scale=1)})["data"]
            FIGURE.write_bytes(__import__("base64").b64decode(shot))
        page.evaluate("1")  # read the events still in the pipe
        assert page.problems() == []
        assert all(url.split(":", 1)[0] in ("file", "data", "blob") for url in page.requests), page.requests

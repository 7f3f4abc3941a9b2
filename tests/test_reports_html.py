"""Headless rendering and the self-contained report.html, checked in a real headless browser.

The browser tests need Debian's ``chromium`` (``apt-get install chromium``; scripts/setup.sh --test
installs it) and are skipped with that reason when it is absent. Set SALSBENCH_KEEP_SCREENSHOT=DIR
to keep the browser's screenshot of the test report there.
"""

from __future__ import annotations

import io
import os
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

import reports
from reports.render import (BACKGROUND, ERROR_STOPS, camera_rotation, distances_to_mesh, error_colors, render_mesh,
                            render_mesh_and_error)
from tests.browser import CHROMIUM, FLAGS, needs_chromium
from tests.test_reports_tables import CONTEXT, make_results



def png_array(png: bytes) -> np.ndarray:
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def unit_cube():
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))  # [-1, 1]^3
    return np.asarray(box.vertices, float), np.asarray(box.faces, np.int64)


# ---------------------------------------------------------------------------------------------
# render_mesh
# ---------------------------------------------------------------------------------------------


def test_render_cube_has_right_size_and_content():
    V, F = unit_cube()
    img = png_array(render_mesh(V, F, size=(160, 120)))
    assert img.shape == (120, 160, 3)
    background = np.all(img == np.round(BACKGROUND * 255), axis=2)
    assert background[0, 0] and background[-1, -1]  # corners are background (5% margin)
    assert not background[60, 80]  # the cube covers the centre
    assert 0.3 < (~background).mean() < 0.95
    # three visible faces, flat shaded: at least three clearly different grey levels
    levels = np.unique((img[~background].mean(axis=1) // 8).astype(int))
    assert len(levels) >= 3


def test_render_is_two_sided_and_deterministic():
    V, F = unit_cube()
    a = render_mesh(V, F)
    flipped = render_mesh(V, F[:, ::-1])  # every face reversed (unoriented output): same picture
    assert np.array_equal(png_array(a), png_array(flipped))
    assert a == render_mesh(V, F)


def test_the_up_axis_points_up_in_the_image():
    for up, axis in (("x", 0), ("y", 1), ("z", 2)):
        R = camera_rotation(-35.0, 25.0, up)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose((R @ np.eye(3)[axis])[1], np.cos(np.radians(25.0)), atol=1e-12)  # image up
    np.testing.assert_array_equal(camera_rotation(-35.0, 25.0, "y"), camera_rotation(-35.0, 25.0))
    # a post 0.2 x 0.2 x 2 along z, seen level (elevation 0): standing with up='z', end-on (a square)
    # with the default y up, whose camera then looks along -z
    box = trimesh.creation.box(extents=(0.2, 0.2, 2.0))
    V, F = np.asarray(box.vertices, float), np.asarray(box.faces, np.int64)
    extents = {}
    for up in ("z", "y"):
        covered = ~np.all(png_array(render_mesh(V, F, size=(96, 96), view=(0.0, 0.0), up=up))
                          == np.round(BACKGROUND * 255), axis=2)
        extents[up] = np.ptp(np.flatnonzero(covered.any(1))), np.ptp(np.flatnonzero(covered.any(0)))  # rows, cols
    assert extents["z"][0] > 5 * extents["z"][1]
    assert abs(extents["y"][0] - extents["y"][1]) <= 2
    with pytest.raises(ValueError, match="up axis"):
        camera_rotation(0.0, 0.0, "w")


def test_render_empty_and_degenerate_meshes_are_blank():
    for V, F in [(np.zeros((0, 3)), np.zeros((0, 3), np.int64)),
                 (np.zeros((3, 3)), np.array([[0, 1, 2]])),
                 (np.full((3, 3), np.nan), np.array([[0, 1, 2]]))]:
        img = png_array(render_mesh(V, F, size=(64, 48)))
        assert img.shape == (48, 64, 3) and np.all(img == 255)


def test_render_fixed_bounds_frame_shapes_alike():
    V, F = unit_cube()
    bounds = (np.full(3, -1.0), np.full(3, 1.0))
    big = png_array(render_mesh(V, F, bounds=bounds, size=(128, 128)))
    small = png_array(render_mesh(V * 0.5, F, bounds=bounds, size=(128, 128)))  # same camera, half size
    cover_big = (big != 255).any(axis=2).mean()
    cover_small = (small != 255).any(axis=2).mean()
    assert cover_small == pytest.approx(cover_big / 4, rel=0.1)  # area scales with the square


def test_render_vertex_colors_and_bad_input():
    V, F = unit_cube()
    red = np.tile([1.0, 0.0, 0.0], (len(V), 1))
    img = png_array(render_mesh(V, F, colors=red, size=(64, 64)))
    fg = img[(img != 255).any(axis=2)].astype(int)
    assert (fg[:, 0] > fg[:, 1] + 40).mean() > 0.95  # reds everywhere on the cube
    with pytest.raises(ValueError, match="colors must be"):
        render_mesh(V, F, colors=np.ones((5, 3)))
    with pytest.raises(ValueError, match="faces index vertices"):
        render_mesh(V, F + 100)


def test_distance_and_error_colors_by_hand():
    V, F = unit_cube()
    d = distances_to_mesh(np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 1.0], [2.0, 2.0, 1.0], [np.nan, 0, 0]]), V, F)
    assert d[:3] == pytest.approx([1.0, 0.0, np.sqrt(2.0)]) and np.isnan(d[3])
    c = error_colors(np.array([0.0, 0.01, 0.5, np.nan]), vmax=0.01)
    first = [int(ERROR_STOPS[0][1][i:i + 2], 16) / 255 for i in (1, 3, 5)]
    last = [int(ERROR_STOPS[-1][1][i:i + 2], 16) / 255 for i in (1, 3, 5)]
    assert c[0] == pytest.approx(first) and c[1] == pytest.approx(last) and c[2] == pytest.approx(last)
    assert c[3] == pytest.approx([0.5, 0.5, 0.5])


def test_shaded_and_error_renders_from_one_rasterisation_are_the_separate_renders(monkeypatch):
    """Two spheres, the far one half hidden behind the near one, against a GT sphere: the pair
    equals the two separate renders byte for byte, although the distances are computed only for
    the vertices of faces that cover a pixel (fewer than all)."""
    near = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    far = trimesh.creation.icosphere(subdivisions=3, radius=0.6)
    far.apply_translation([0.2, 0.1, -0.9])
    both = trimesh.util.concatenate([near, far])
    V, F = np.asarray(both.vertices), np.asarray(both.faces)
    gt = trimesh.creation.icosphere(subdivisions=4, radius=0.55)
    gV, gF = np.asarray(gt.vertices), np.asarray(gt.faces)
    bounds = (V.min(0), V.max(0))
    import reports.render as render

    queried = []
    monkeypatch.setattr(render, "distances_to_mesh", lambda P, *gt: queried.append(len(P)) or distances_to_mesh(P, *gt))
    shaded, err = render_mesh_and_error(V, F, gV, gF, 0.1, size=(96, 96), bounds=bounds)
    assert 0 < queried[0] < 0.75 * len(V)
    assert shaded == render_mesh(V, F, size=(96, 96), bounds=bounds)
    colors = error_colors(distances_to_mesh(V, gV, gF), 0.1)
    assert err == render_mesh(V, F, colors=colors, size=(96, 96), bounds=bounds)
    assert shaded != err
    empty = render_mesh_and_error(V[:0], F[:0], gV, gF, 0.1, size=(8, 8))
    assert empty[0] == empty[1] == render_mesh(V[:0], F[:0], size=(8, 8))


# ---------------------------------------------------------------------------------------------
# report.html
# ---------------------------------------------------------------------------------------------


def write_fake_meshes(meshes: Path) -> None:
    """GT meshes of the fake run; predictions = subdivided GT pushed outwards by 0.002 (sals) and
    0.006 (sdf) along the vertex normals; sdf has no cylinder mesh (its jobs failed)."""
    gts = {"cube": trimesh.creation.box(extents=(1.9, 1.5, 1.2)),
           "sphere": trimesh.creation.icosphere(subdivisions=3, radius=0.99),
           "cylinder": trimesh.creation.cylinder(radius=0.6, height=1.98, sections=32)}
    for shape, mesh in gts.items():
        (meshes / shape).mkdir(parents=True)
        mesh.export(meshes / shape / "gt.ply")
        for method, offset in (("sals", 0.002), ("sdf", 0.006)):
            if shape == "cylinder" and method == "sdf":
                continue
            pred = mesh.subdivide()
            pred = trimesh.Trimesh(pred.vertices + offset * pred.vertex_normals, pred.faces, process=False)
            pred.export(meshes / shape / f"{method}.ply")


class _Collect(HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags, self.img_src, self.links = [], [], []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self.tags.append(tag)
        if tag == "img":
            self.img_src.append(a.get("src", ""))
        for key in ("src", "href"):
            if a.get(key) and tag != "img":
                self.links.append(a[key])


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    write_fake_meshes(out / "meshes")
    results, floor = make_results()
    paths = reports.write_reports(results, floor, CONTEXT, out, out / "meshes")
    return paths, out


def test_write_reports_contract_and_static_self_containment(report):
    paths, out = report
    assert sorted(paths) == ["report.html", "statistics.csv", "summary.md", "summary.tex", "timing.csv", "timing.md"]
    page = paths["report.html"].read_text()
    parsed = _Collect()
    parsed.feed(page)
    assert "link" not in parsed.tags  # no external CSS
    assert parsed.tags.count("script") == 4  # the 3D viewer's data, Draco decoder, three.js and viewer.js, inline
    assert parsed.img_src and all(s.startswith("data:image/") for s in parsed.img_src)
    # 3 GT + 5 predictions x (shaded + error-coloured) thumbnails + 2 plots
    assert sum(s.startswith("data:image/png") for s in parsed.img_src) == 3 + 2 * 5
    assert sum(s.startswith("data:image/svg+xml") for s in parsed.img_src) == 2
    assert all(link.startswith("#") for link in parsed.links)  # only in-page anchors
    assert paths["report.html"].stat().st_size <= 30_000_000  # the default size budget
    assert "Every mesh is drawn in full" in page and "three.js 0.187.0 (MIT)" in page  # the viewer's library, licence
    assert "MeshError: NaN loss at step 120" in page  # the failed jobs' error text
    assert re.search(r"clipped at\s+0\.01", page)  # error colour scale stated
    # the mean with its interval, sdf bold as a tie (3 shapes: no difference can be significant), said
    assert '<td class="r best">4.500 <span class="muted">[4.500, 4.500]</span></td>' in page
    assert '<td class="r best">8.500† <span class="muted">[8.500, 8.500]</span></td>' in page
    assert "tied with sdf" in page and "tied by construction: sdf" in page


def test_a_report_drawn_by_a_process_pool_is_the_report_drawn_in_one_process(report, tmp_path):
    """The gallery's cards and the viewer's meshes drawn shape by shape in two spawned processes
    (the run's workers draw them so) give the page of the one-process drawing, byte for byte."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    paths, out = report
    results, floor = make_results()
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
        pooled = reports.write_reports(results, floor, CONTEXT, tmp_path, out / "meshes", map_shapes=pool.map)
    assert pooled["report.html"].read_bytes() == paths["report.html"].read_bytes()


def test_missing_meshes_dir_and_unreadable_mesh(tmp_path):
    results, floor = make_results()
    paths = reports.write_reports(results, floor, CONTEXT, tmp_path / "a", None)
    assert "No meshes directory" in paths["report.html"].read_text()
    meshes = tmp_path / "meshes"
    write_fake_meshes(meshes)
    (meshes / "cube" / "sals.ply").write_text("not a mesh")
    (meshes / "sphere" / "gt.ply").unlink()
    page = reports.write_reports(results, floor, CONTEXT, tmp_path / "b", meshes, gallery_limit=2,
                                 max_bytes=1_000_000)["report.html"]
    assert page.stat().st_size <= 1_000_000
    page = page.read_text()
    assert "render failed" in page and "no GT mesh" in page and "Showing the first 2 of 3 shapes" in page
    assert "No 3D viewer: the page's size budget (1 MB" in page
    page = reports.write_reports(results, floor, CONTEXT, tmp_path / "c", meshes, gallery_limit=0)["report.html"].read_text()
    assert "image/png" not in page and "No thumbnails in this report (gallery limit 0)" in page  # plots stay


def test_compare_runs_writes_every_file(tmp_path):
    results, floor = make_results()
    runs = [{"name": name, "results": results, "floor": floor, "context": CONTEXT, "meshes_dir": None}
            for name in ("a", "b")]
    paths = reports.compare_runs(runs, tmp_path)
    assert sorted(paths) == ["report.html", "statistics.csv", "summary.md", "summary.tex", "timing.csv", "timing.md"]
    assert "Runs side by side" in paths["report.html"].read_text()


def _chromium(args: list[str], profile: Path) -> subprocess.CompletedProcess:
    cmd = [CHROMIUM, *FLAGS, f"--user-data-dir={profile}", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=90)


@needs_chromium
@pytest.mark.slow
def test_report_in_headless_browser(report, tmp_path):
    paths, out = report
    url = paths["report.html"].resolve().as_uri()
    dom = _chromium(["--dump-dom", url], tmp_path / "profile-dom")
    assert dom.returncode == 0, dom.stderr[-2000:]
    parsed = _Collect()
    parsed.feed(dom.stdout)
    assert parsed.tags.count("table") >= 5 and "CD ×1e3 ↓" in dom.stdout  # summary, per shape, validity, timing
    assert "floor (GT vs resample)" in dom.stdout and "sals" in dom.stdout
    assert "4.500" in dom.stdout  # the CD x1e3 mean, rendered in the page
    assert parsed.img_src and all(s.startswith("data:") for s in parsed.img_src)  # nothing from the network

    shot = tmp_path / "report.png"
    run = _chromium([f"--screenshot={shot}", "--window-size=1280,2000", "--hide-scrollbars", url],
                    tmp_path / "profile-shot")
    assert run.returncode == 0 and shot.is_file(), run.stderr[-2000:]
    img = np.asarray(Image.open(shot).convert("RGB"))
    assert img.shape[:2] == (2000, 1280)
    colours = np.unique(img.reshape(-1, 3)[:: 7], axis=0)
    assert len(colours) > 200  # text, table highlight, header gradient, plots: not a blank page
    assert img[:60].mean() < 100  # the dark header band is at the top
    keep = os.environ.get("SALSBENCH_KEEP_SCREENSHOT")
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        shutil.copy(shot, Path(keep) / "report.png")


def test_face_subset_keeps_a_seeded_subset_and_compacts_vertices():
    from reports.render import face_subset

    V = np.arange(30, dtype=float).reshape(10, 3)
    F = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8], [7, 8, 9]])
    V2, F2 = face_subset(V, F, 2)
    assert F2.shape == (2, 3) and len(V2) == len(np.unique(F2)) and F2.max() == len(V2) - 1
    # every kept triangle is one of the originals (same coordinates)
    originals = {tuple(map(tuple, V[f])) for f in F}
    assert all(tuple(map(tuple, V2[f])) in originals for f in F2)
    assert np.array_equal(face_subset(V, F, 2)[1], F2)  # seeded
    assert face_subset(V, F, 10)[1] is not None and len(face_subset(V, F, 10)[1]) == 4


# ---------------------------------------------------------------------------------------------
# Names from the wild: no warnings, escaped, shown in full
# ---------------------------------------------------------------------------------------------

NAMES = ("Ω-bracket", "部品", "emoji 🔧")


def _renamed_run():
    """The fake run with non-ASCII shape names and 'sdf' renamed to a method the registry does not
    know, whose name would be mathtext for matplotlib."""
    results, floor = make_results()
    rename = dict(zip(("cube", "sphere", "cylinder"), NAMES))
    results["shape"] = results["shape"].map(rename)
    floor["shape"] = floor["shape"].map(rename)
    results["method"] = results["method"].replace({"sdf": "old $x$"})
    return results, floor, dict(CONTEXT, shapes=list(NAMES), methods=["sals", "old $x$"])


def test_non_ascii_names_render_without_any_warning(tmp_path, recwarn):
    results, floor, context = _renamed_run()
    page = reports.write_reports(results, floor, context, tmp_path / "one")["report.html"].read_text()
    runs = [{"name": n, "results": results, "floor": floor, "context": context, "meshes_dir": None}
            for n in ("部品 run", "🔧")]
    reports.compare_runs(runs, tmp_path / "two")
    assert [str(w.message) for w in recwarn] == []  # no 'Glyph ... missing from font', no mathtext error
    assert all(name in page for name in NAMES) and "old $x$" in page  # the tables show the names in full


def test_plot_label_replaces_missing_glyphs_and_escapes_dollars():
    from reports.plots import plot_label

    assert plot_label("Ω-bracket") == "Ω-bracket"  # DejaVu Sans has Greek
    assert plot_label("部品") == "??" and plot_label("emoji 🔧") == "emoji ?"
    assert plot_label("a $x$") == r"a \$x\$"


def test_html_summary_counts_empty_predictions(tmp_path):
    results, floor = make_results()
    results.loc[(results["shape"] == "cube") & (results["method"] == "sals") & (results["seed"] == 1),
                ["cd", "nc", "ecd", "ef1", "f1_005", "f1_01", "empty_prediction"]] = [np.nan] * 3 + [0.0] * 3 + [1]
    page = reports.write_reports(results, floor, CONTEXT, tmp_path)["report.html"].read_text()
    summary = page[page.index('id="summary"'):page.index('id="gallery"')]
    headers = re.findall(r"<th[^>]*>([^<]*)</th>", summary.split("</thead>")[0])
    first_row = re.findall(r"<td[^>]*>([^<]*)(?:<span[^>]*>[^<]*</span>)?</td>",  # the value, not its interval
                           summary.split("<tbody>")[1].split("</tr>")[0])
    row = dict(zip(headers, (cell.strip() for cell in first_row)))
    # sals CD x1e3 over the 5 non-empty jobs: (4 + 5 + 4 + 5 + 4) / 5 = 4.400
    assert (row["method"], row["jobs"], row["empty"], row["CD ×1e3 ↓"]) == ("sals", "6", "1", "4.400")
    assert "CD, NC: over non-empty predictions" in summary


def test_gallery_captions_count_boundary_and_non_manifold_edges():
    """A box with one side's two triangles removed has a square hole: 4 boundary edges, no
    non-manifold edge; a third triangle on one of the box's edges makes that edge non-manifold."""
    from reports.html import _gt_caption, topology_text

    box = trimesh.creation.box()
    V, F = np.asarray(box.vertices), np.asarray(box.faces)
    side = np.flatnonzero(np.all(np.isclose(box.triangles_center[:, [0]], 0.5), axis=1))
    open_box = np.delete(F, side, axis=0)
    assert _gt_caption(V, open_box) == "10 faces · ∂ 4 · NM 0"
    fin = np.vstack([F, [[F[0, 0], F[0, 1], len(V)]]])
    assert _gt_caption(np.vstack([V, [[2.0, 2.0, 2.0]]]), fin).endswith("NM 1")
    assert topology_text(float("nan"), 0) == ""


def test_the_header_of_a_reconstruct_run_states_its_task_seed_and_workers_not_a_mode(tmp_path):
    """A reconstruct run by 2 process workers x 1 torch thread, one seed, no method under a budget."""
    context = dict(CONTEXT, task="reconstruct", seeds=[0], budget_values=None, device="cpu (2 threads)")
    page = reports.write_reports(*make_results(), context, tmp_path)["report.html"].read_text()
    header = page[page.index("<header>"):page.index("</header>")]
    chips = dict(re.findall(r'<span class="chip"><b>([^<]*)</b>([^<]*)</span>', header))
    assert chips["task"] == "reconstruct" and chips["seed"] == "0"
    assert "mode" not in chips and "seeds" not in chips and "budget" not in chips
    subtitle = re.search(r'<div class="sub">([^<]*)</div>', header).group(1)
    assert "cpu (Test CPU 3000) · executor process, 2 workers x 1 torch thread" in subtitle
    assert "2 threads" not in subtitle  # the driver's own threads are not the jobs'

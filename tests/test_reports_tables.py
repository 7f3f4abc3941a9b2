"""Tables contract of reports: summary.md / summary.tex / timing.csv / timing.md from hand-made frames.

The fake run (CONTEXT): 3 shapes x 2 methods x 2 seeds, no empty prediction. sals: cd = 0.004 (+0.001 for seed 1), ecd = 0.02,
ef1 = 0.6; sdf: cd = 0.008 (+0.001 for seed 1), ecd = 0.04, ef1 = 0.3, its 'cylinder' jobs fail and
its 'sphere' seed-0 prediction has no edge points (ecd NaN, flag set, ef1 = 0). So by hand, in table
units: sals CD mean = (4 + 5) / 2 = 4.500, sdf CD mean = 8.500, sals ECD 2.000, sdf ECD 4.000 over
3 jobs with 1 NaN, sdf EF1 = (0 + 0.3 * 3) / 4 = 0.225, floor CD 1.100. Intervals (mean over shapes of the
seed means): every shape of sals has CD 4.5, so [4.500, 4.500]; sdf EF1 per shape is 0.3 (cube) and 0.15
(sphere), so [0.150, 0.300]. Two or three shapes can never make a difference significant: sdf ties (bold, †).
"""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest

from reports.compare import build_comparison, write_comparison
from reports.summary import build_summary, write_summary
from reports.timing import timing_frame, write_timing

SHAPES = ("cube", "sphere", "cylinder")
METHODS = ("sals", "sdf")
CONTEXT = dict(dataset="builtin", task="encode", mode="neural", budget="quick",
               budget_values={"encode": {"steps": 2000, "lr": 0.001}}, grid=128, seeds=[0, 1], methods=list(METHODS),
               shapes=list(SHAPES), metric_preset="default", eval_points=1_000_000, device="cpu",
               cpu_model="Test CPU 3000", gpu=None, git_commit="0123456789abcdef",
               execution={"executor": "process", "workers": 2, "threads_per_job": 1})


def make_results() -> tuple[pd.DataFrame, pd.DataFrame]:
    rows = []
    for shape in SHAPES:
        for k, method in enumerate(METHODS):
            for seed in (0, 1):
                failed = shape == "cylinder" and method == "sdf"
                no_edges = shape == "sphere" and method == "sdf" and seed == 0
                row = dict(
                    shape=shape, method=method, mode="neural", seed=seed, status="failed" if failed else "ok",
                    error="MeshError: NaN loss at step 120" if failed else None,
                    cd=np.nan if failed else 0.004 * (k + 1) + 0.001 * seed, nc=0.98 - 0.01 * k,
                    f1_005=0.6 - 0.1 * k, f1_01=0.95 - 0.05 * k,
                    ecd=np.nan if (failed or no_edges) else 0.02 * (k + 1),
                    ef1=np.nan if failed else (0.0 if no_edges else 0.6 - 0.3 * k),
                    ecd_flag=no_edges, empty_prediction=0, n_vertices=100 * (k + 1), n_faces=200 * (k + 1),
                    boundary_edges=2 * k, nonmanifold_edges=k, components=1 + k, watertight=(k == 0),
                    sample_s=0.5, label_s=1.0, fit_s=30.0 + 10 * k + seed, query_s=2.0, extract_s=1.5,
                    metrics_s=3.0, total_s=40.0 + 10 * k + seed, device="cpu",
                )
                if method == "sals":
                    row.update(extract_edc_points_s=0.5, extract_qef_s=0.7, extract_faces_s=0.3)
                rows.append(row)
    floor = pd.DataFrame([dict(shape=s, cd=0.0011, nc=0.999, f1_005=0.9, f1_01=0.99, ecd=0.005, ef1=0.9,
                               ecd_flag=False, empty_prediction=0, n_vertices=8, n_faces=12, boundary_edges=0, nonmanifold_edges=0,
                               components=1, watertight=True) for s in SHAPES])
    return pd.DataFrame(rows), floor


def write_tables(results, floor, context, out) -> dict:
    """summary.md/.tex, statistics.csv and timing.csv/.md, as write_reports writes them (without report.html)."""
    summary = build_summary(results, floor, context)
    return {**write_summary(summary, context, out), **write_timing(summary.results, context, out)[0]}


def md_tables(text: str) -> dict[str, list[list[str]]]:
    """Markdown tables by their '## title': rows of stripped cells (header first, rule dropped);
    cells split at unescaped pipes, kept escaped."""
    out, title, rows = {}, None, []
    for line in text.splitlines() + [""]:
        if line.startswith("## "):
            title, rows = line[3:].strip(), []
        elif line.startswith("|") and title:
            cells = [c.strip() for c in re.split(r"(?<!\\)\|", line.strip()[1:-1])]
            if not all(re.fullmatch(r":?-+:?", c) for c in cells):
                rows.append(cells)
        elif rows and title:
            out.setdefault(title, rows)
            rows = []
    return out


def value(cell: str) -> str:
    """A mean cell without its interval: '**4.500** \\[4.1, 4.9\\]' -> '**4.500**'."""
    return cell.split(r" \[")[0]


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    results, floor = make_results()
    out = tmp_path_factory.mktemp("tables")
    return write_tables(results, floor, CONTEXT, out), results, floor


def test_files_written(written):
    paths, _, _ = written
    assert sorted(paths) == ["statistics.csv", "summary.md", "summary.tex", "timing.csv", "timing.md"]
    assert all(p.is_file() and p.stat().st_size > 0 for p in paths.values())


def test_mean_table_rows_units_bold_and_nan_count(written):
    paths, _, _ = written
    text = paths["summary.md"].read_text()
    table = md_tables(text)["Mean over shapes and seeds"]
    header, body = table[0], table[1:]
    assert [r[0] for r in body] == ["sals", "sdf", "floor (GT vs resample)"]  # one row per method + floor
    col = {h: i for i, h in enumerate(header)}
    # arrows: down for CD/ECD, up for NC/F1/EF1; multipliers in the header
    assert "CD ×1e3 ↓" in col and "ECD ×1e2 ↓" in col and "NC ↑" in col and "EF1 ↑" in col
    assert "F1@0.005 ↑" in col and "F1@0.01 ↑" in col
    sals, sdf, floor = body
    # cd 0.004 and 0.005 -> 4.5e-3 -> 4.500, best (bold), the same on every shape: interval [4.500, 4.500]
    assert sals[col["CD ×1e3 ↓"]] == r"**4.500** \[4.500, 4.500\]"
    assert sdf[col["CD ×1e3 ↓"]] == r"**8.500†** \[8.500, 8.500\]"  # 2 shapes in common: a tie, never a loss
    assert value(sals[col["ECD ×1e2 ↓"]]) == "**2.000**" and value(sdf[col["ECD ×1e2 ↓"]]) == "**4.000†**"
    assert sals[col["EF1 ↑"]] == r"**0.600** \[0.600, 0.600\]"
    assert sdf[col["EF1 ↑"]] == r"**0.225†** \[0.150, 0.300\]"  # shapes 0.3 and 0.15
    assert sdf[col["ECD NaN"]] == "1" and sals[col["ECD NaN"]] == "0"
    assert header.index("ECD NaN") == header.index("ECD ×1e2 ↓") + 1  # next to the ECD mean
    assert (sals[col["jobs"]], sals[col["failed"]], sdf[col["jobs"]], sdf[col["failed"]]) == ("6", "0", "6", "2")
    assert floor[col["CD ×1e3 ↓"]] == r"1.100 \[1.100, 1.100\]"
    assert "**" not in "".join(floor)  # reference, never bold
    assert "tied by construction: sdf (CD, NC, F1@0.005, F1@0.01, ECD, EF1)" in text  # why sdf ties, said
    assert "95% percentile-bootstrap confidence interval of the mean over shapes" in text
    assert "Protocol:" in text and "1,000,000" in text and "0.005, 0.01" in text and "128³" in text


def test_median_std_and_per_shape_tables(written):
    paths, _, _ = written
    tables = md_tables(paths["summary.md"].read_text())
    std = tables["Standard deviation over shapes and seeds"]
    col = {h: i for i, h in enumerate(std[0])}
    # sals CD x1e3 values 4,5,4,5,4,5: sample std = sqrt(6 * 0.25 / 5) = 0.5477
    assert std[1][col["CD ×1e3 ↓"]] == f"{np.sqrt(1.5 / 5):.3f}"
    assert "**" not in "".join(sum(std, [])) and "[" not in "".join(sum(std, []))  # no bold, no interval
    median = tables["Median over shapes and seeds"]
    assert [r[col["EF1 ↑"]] for r in median[1:]] == ["**0.600**", "**0.300†**", "0.900"]  # ties, no interval
    per_shape = tables["Per shape: CD ×1e3 ↓ (mean over seeds)"]
    assert per_shape[0] == ["shape", "sals", "sdf", "floor"]
    assert per_shape[1] == ["cube", "**4.500**", "8.500", "1.100"]
    assert per_shape[3] == ["cylinder", "**4.500**", "failed", "1.100"]
    ecd = tables["Per shape: ECD ×1e2 ↓ (mean over seeds)"]
    assert ecd[2] == ["sphere", "**2.000**", "4.000", "0.500"]  # seed 0 NaN skipped, seed 1 = 4.000
    validity = tables["Mesh validity of the predictions (mean over successful jobs)"]
    vcol = {h: i for i, h in enumerate(validity[0])}
    assert validity[1][vcol["watertight %"]] == "100" and validity[2][vcol["watertight %"]] == "0"
    assert validity[2][vcol["boundary edges"]] == "2.0"
    assert "cylinder / sdf / seed 0: MeshError: NaN loss at step 120" in paths["summary.md"].read_text()


def _strip_escaped(tex: str) -> str:
    return tex.replace(r"\{", "").replace(r"\}", "")


def test_latex_is_structurally_sound(written, tmp_path):
    paths, _, _ = written
    tex = paths["summary.tex"].read_text()
    body = _strip_escaped(tex)
    depth = 0
    for ch in body:  # balanced braces, never negative
        depth += {"{": 1, "}": -1}.get(ch, 0)
        assert depth >= 0
    assert depth == 0
    assert tex.count(r"\begin{tabular}") == tex.count(r"\end{tabular}") >= 5
    assert tex.count(r"\begin{table}") == tex.count(r"\end{table}") == tex.count(r"\begin{tabular}")
    assert r"\toprule" in tex and r"\midrule" in tex and r"\bottomrule" in tex
    assert r"\textbf{4.500}\,{\scriptsize [4.500, 4.500]}" in tex and r"\textbf{8.500$^{\dagger}$}" in tex
    assert r"$\downarrow$" in tex and r"$\uparrow$" in tex and "tied by construction" in tex  # caption says why
    assert r"$\times 10^{3}$" in tex
    # every row of every tabular has as many cells as the column spec has columns
    for spec, inner in re.findall(r"\\begin\{tabular\}\{([lrc]+)\}(.*?)\\end\{tabular\}", tex, flags=re.S):
        for line in inner.splitlines():
            if line.endswith(r"\\"):
                assert len(re.split(r"(?<!\\)&", line)) == len(spec), line
    assert "_" not in re.sub(r"\\_|\\label\{[^}]*\}", "", tex.split("\n", 1)[1])  # underscores escaped
    import shutil
    import subprocess

    if shutil.which("pdflatex"):
        doc = tmp_path / "doc.tex"
        doc.write_text("\\documentclass{article}\\usepackage{booktabs}\\begin{document}\n" + tex + "\\end{document}\n")
        run = subprocess.run(["pdflatex", "-interaction=nonstopmode", "-halt-on-error", doc.name], cwd=tmp_path,
                             capture_output=True, text=True, timeout=120)
        assert run.returncode == 0, run.stdout[-2000:]


def test_timing_csv_sums_and_means(written):
    paths, results, _ = written
    timing = pd.read_csv(paths["timing.csv"])
    assert list(timing.columns) == ["method", "stage", "label", "level", "n_jobs", "mean_s", "median_s", "std_s",
                                    "device", "execution"]
    for method in METHODS:
        t = timing[timing["method"] == method].set_index("stage")
        stages = t[t["level"] == "stage"]
        assert list(stages.index) == ["sample_s", "label_s", "fit_s", "query_s", "extract_s", "metrics_s"]
        assert t.at["sum_of_stages", "mean_s"] == pytest.approx(stages["mean_s"].sum())
        ok = results[(results["method"] == method) & (results["status"] == "ok")]
        assert t.at["fit_s", "mean_s"] == pytest.approx(ok["fit_s"].mean())
        assert t.at["total_s", "mean_s"] == pytest.approx(ok["total_s"].mean())
    sals = timing[timing["method"] == "sals"].set_index("stage")
    # extraction steps are listed but not added twice: 0.5 + 1 + 30.5 + 2 + 1.5 + 3 = 38.5
    assert sals.at["sum_of_stages", "mean_s"] == pytest.approx(38.5)
    assert sals.at["extract_qef_s", "level"] == "step" and sals.at["extract_qef_s", "mean_s"] == pytest.approx(0.7)
    assert timing[timing["method"] == "sdf"]["n_jobs"].max() == 4  # failed cylinder jobs excluded
    md = paths["timing.md"].read_text()
    assert "Test CPU 3000" in md and "Device: cpu" in md
    assert "executor process, 2 workers x 1 torch thread." in md and set(timing["execution"]) == {
        "executor process, 2 workers x 1 torch thread"}
    mean = md_tables(md)["Wall-clock seconds per job (mean)"]
    assert mean[0] == ["stage", "sals", "sdf"]
    rows = {r[0].strip("* "): r[1:] for r in mean[1:]}
    assert rows["sum of stages"] == ["38.50", "48.50"] and rows["fitting"] == ["30.50", "40.50"]
    assert rows["extraction: qef"] == ["0.70", "–"]


def test_ndc_preset_run_with_missing_columns(tmp_path):
    results, floor = make_results()
    results = results.drop(columns=["f1_005", "f1_01", "watertight", "components"]).assign(f1_003=0.5)
    cfg = dict(CONTEXT, metric_preset="ndc")
    paths = write_tables(results, floor.drop(columns=["f1_005", "f1_01"]), cfg, tmp_path)
    mean = md_tables(paths["summary.md"].read_text())["Mean over shapes and seeds"]
    col = {h: i for i, h in enumerate(mean[0])}
    assert "F1@0.003 ↑" in col and "F1@0.005 ↑" not in col
    assert mean[1][col["CD ×1e5 ↓"]] == r"**450.000** \[450.000, 450.000\]"  # 4.5e-3 x 1e5


def test_bad_frames_and_contexts_give_one_line_errors(tmp_path):
    results, floor = make_results()
    with pytest.raises(ValueError, match=r"^results frame lacks column\(s\) method$"):
        build_summary(results.drop(columns=["method"]), floor, CONTEXT)
    with pytest.raises(ValueError, match="must be a pandas DataFrame"):
        build_summary({"shape": []}, floor, CONTEXT)
    with pytest.raises(ValueError, match=r"^context lacks key\(s\) eval_points, gpu$"):
        build_summary(results, floor, {k: v for k, v in CONTEXT.items() if k not in ("eval_points", "gpu")})
    with pytest.raises(ValueError, match=r"^unknown metric preset 'nope'; known: default, ndc, scene$"):
        build_summary(results, floor, dict(CONTEXT, metric_preset="nope"))
    # no floor, no timing, no empty flag, everything failed: still writes every table
    dead = results.assign(status="failed", error="boom")[["shape", "method", "seed", "status", "error", "cd"]]
    paths = write_tables(dead, None, CONTEXT, tmp_path)
    mean = md_tables(paths["summary.md"].read_text())["Mean over shapes and seeds"]
    col = {h: i for i, h in enumerate(mean[0])}
    assert [r[0] for r in mean[1:]] == ["sals", "sdf"]
    assert [(r[col["failed"]], r[col["empty"]], r[col["CD ×1e3 ↓"]]) for r in mean[1:]] == [("6", "–", "–")] * 2
    assert pd.read_csv(paths["timing.csv"])["stage"].tolist() == ["sum_of_stages", "sum_of_stages"]


def test_timing_frame_orders_unknown_stages_before_metrics():
    results, _ = make_results()
    t = timing_frame(results.assign(load_s=0.25, mystery_s=1.0), CONTEXT)
    stages = t[t["method"] == "sdf"]["stage"].tolist()
    assert stages == ["load_s", "sample_s", "label_s", "fit_s", "query_s", "extract_s", "mystery_s", "metrics_s",
                      "sum_of_stages", "total_s"]


def test_timing_frame_reconstruct_steps_are_not_summed_twice():
    results, _ = make_results()
    results = results.drop(columns=["label_s", "fit_s", "query_s", "extract_s", "extract_edc_points_s",
                                    "extract_qef_s", "extract_faces_s"]).assign(
        network_s=0.5, sample_s=0.25, reconstruct_s=10.0, reconstruct_band_s=2.0, reconstruct_field_s=7.0,
        reconstruct_field_knn_s=1.0, metrics_s=3.0)
    t = timing_frame(results, CONTEXT)
    sals = t[t["method"] == "sals"].set_index("stage")
    assert sals.index.tolist() == ["network_s", "sample_s", "reconstruct_s", "reconstruct_band_s",
                                   "reconstruct_field_s", "reconstruct_field_knn_s", "metrics_s",
                                   "sum_of_stages", "total_s"]
    assert sals.loc[sals["level"] == "stage"].index.tolist() == ["network_s", "sample_s", "reconstruct_s",
                                                                  "metrics_s"]
    assert sals.at["sum_of_stages", "mean_s"] == pytest.approx(0.5 + 0.25 + 10.0 + 3.0)  # steps not added
    assert sals.at["reconstruct_field_knn_s", "label"] == "reconstruction: field knn"


def test_compare_runs_side_by_side(tmp_path):
    results, floor = make_results()
    better = results.assign(cd=results["cd"] / 2)
    comparison = build_comparison([
        {"name": "base", "results": results, "floor": floor, "context": CONTEXT, "meshes_dir": None},
        {"name": "half", "results": better, "floor": floor, "context": CONTEXT, "meshes_dir": None}])
    paths = write_comparison(comparison, tmp_path)
    table = md_tables(paths["summary.md"].read_text())["Runs side by side: mean over shapes and seeds"]
    col = {h: i for i, h in enumerate(table[0])}
    rows = [(r[0], r[1], value(r[col["CD ×1e3 ↓"]]), r[col["ECD NaN"]]) for r in table[1:]]
    # best over both runs: half/sals; 2 or 3 shapes in common cannot make anything significantly worse
    assert rows == [("base", "sals", "**4.500†**", "0"), ("base", "sdf", "**8.500†**", "1"),
                    ("base", "floor (GT vs resample)", "1.100", "0"),
                    ("half", "sals", "**2.250**", "0"), ("half", "sdf", "**4.250†**", "1"),
                    ("half", "floor (GT vs resample)", "1.100", "0")]
    stats = pd.read_csv(paths["statistics.csv"])
    cd = stats[stats["metric"] == "cd"].set_index(["run", "method"])
    assert cd.at[("half", "sals"), "mean"] == pytest.approx(2.25) and np.isnan(cd.at[("half", "sals"), "p_vs_best"])
    assert cd.at[("base", "sals"), "pairs"] == 3 and cd.at[("base", "sals"), "p_vs_best"] == pytest.approx(0.25)
    # the same builder as one run's mean table: the same columns after the 'run' column
    single = md_tables(write_tables(results, floor, CONTEXT, tmp_path / "one")["summary.md"].read_text())
    assert table[0][1:] == single["Mean over shapes and seeds"][0]
    timing = pd.read_csv(paths["timing.csv"])
    assert list(timing["run"].unique()) == ["base", "half"] and timing.columns[0] == "run"
    assert paths["timing.md"].is_file() and paths["summary.tex"].is_file()


def test_compare_runs_makes_repeated_names_unique():
    results, floor = make_results()
    run = {"name": "a", "results": results, "floor": floor, "context": CONTEXT, "meshes_dir": None}
    assert [r.label for r in build_comparison([run, run, run]).runs] == ["a", "a (2)", "a (3)"]
    with pytest.raises(ValueError, match=r"^run 1 lacks key\(s\) context$"):
        build_comparison([{k: v for k, v in run.items() if k != "context"}])


# ---------------------------------------------------------------------------------------------
# Empty predictions and hostile names in Markdown
# ---------------------------------------------------------------------------------------------


def one_method_run(cd, f1, empty, ecd, shapes=("cube", "sphere", "cylinder")) -> tuple[pd.DataFrame, dict]:
    """One method 'sals', one seed, a job per shape with the given raw values."""
    rows = [dict(shape=s, method="sals", seed=0, status="ok", error=None, cd=c, nc=np.nan if e else 0.9,
                 f1_005=f, f1_01=f, ecd=d, ef1=0.0 if e else 0.5, ecd_flag=bool(e), empty_prediction=e)
            for s, c, f, e, d in zip(shapes, cd, f1, empty, ecd)]
    return pd.DataFrame(rows), dict(CONTEXT, methods=["sals"], shapes=list(shapes), seeds=[0])


def test_empty_prediction_is_counted_and_cd_mean_is_over_the_others(tmp_path):
    # cube CD 0.002, sphere CD 0.004, cylinder empty (CD NaN, F1 0): mean CD x1e3 = (2 + 4) / 2 = 3.000,
    # mean F1@0.01 = (0.9 + 0.6 + 0) / 3 = 0.500, 1 empty, and its ECD is NaN too.
    results, context = one_method_run(cd=[0.002, 0.004, np.nan], f1=[0.9, 0.6, 0.0], empty=[0, 0, 1],
                                      ecd=[0.02, 0.04, np.nan])
    paths = write_tables(results, None, context, tmp_path)
    text = paths["summary.md"].read_text()
    mean = md_tables(text)["Mean over shapes and seeds"]
    col = {h: i for i, h in enumerate(mean[0])}
    row = mean[1]
    assert (row[col["jobs"]], row[col["failed"]], row[col["empty"]]) == ("3", "0", "1")
    assert row[col["CD ×1e3 ↓"]] == r"**3.000** \[2.000, 4.000\]"  # the interval over the 2 non-empty shapes
    assert value(row[col["F1@0.01 ↑"]]) == "**0.500**"
    assert value(row[col["ECD ×1e2 ↓"]]) == "**3.000**" and row[col["ECD NaN"]] == "1"
    assert "CD, NC: over non-empty predictions" in text and "an empty prediction scoring 0" in text
    per_shape = md_tables(text)["Per shape: CD ×1e3 ↓ (mean over seeds)"]
    assert per_shape[3] == ["cylinder", "empty"]
    tex = paths["summary.tex"].read_text()
    assert "CD, NC: over non-empty predictions" in tex  # in the LaTeX caption too


def test_hostile_shape_name_is_one_escaped_markdown_cell(tmp_path):
    name = "a|b<script>"
    results, context = one_method_run(cd=[0.002, 0.004], f1=[0.9, 0.6], empty=[0, 0], ecd=[0.02, 0.04],
                                      shapes=(name, "cube"))
    results.loc[1, ["status", "error"]] = ["failed", "ValueError: bad | <b>mesh</b> *x*"]
    text = write_tables(results, None, context, tmp_path)["summary.md"].read_text()
    assert "<script>" not in text and "<b>" not in text
    per_shape = md_tables(text)["Per shape: CD ×1e3 ↓ (mean over seeds)"]
    assert per_shape[1:] == [[r"a\|b\<script\>", "**2.000**"], ["cube", "failed"]]  # one row, two cells each
    assert r"- cube / sals / seed 0: ValueError: bad \| \<b\>mesh\</b\> \*x\*" in text


def test_caption_carries_the_notes_of_the_run_methods_only():
    from reports.protocol import protocol_caption
    from runner.export import method_notes

    notes = method_notes("reconstruct", ["sals-knn", "udf-knn", "occ-knn", "no-such-method"], {})
    assert set(notes) == {"udf-knn", "occ-knn"} and "controlled ablation" in notes["udf-knn"]
    scored = method_notes("score", ["mine"], {"mine": {"pred_dir": "/data/preds", "pred_frame": "canonical"}})
    assert scored == {"mine": "mine: meshes made outside this run from /data/preds (canonical frame), scored as given."}
    context = dict(CONTEXT, task="reconstruct", methods=["sals-knn", "udf-knn"], method_notes=notes)
    caption = protocol_caption(context)
    assert caption.startswith("Protocol: dataset: builtin (3 shapes); task: reconstruct")
    assert caption.endswith(notes["udf-knn"]) and notes["occ-knn"] not in caption
    assert protocol_caption(CONTEXT).endswith(".")  # no notes: the protocol sentence alone


def test_report_context_says_which_axis_is_up_for_scenes_only():
    from runner.export import report_context

    def up(dataset):
        return report_context({"config": {"dataset": dataset}})["up_axis"]

    assert up("rooms") == "z" and up("street") == "z"  # the generators build scenes with z up
    assert up("abc") == "" and up(None) == "" and up("no-such-dataset") == ""  # CAD parts state none


def test_complete_shapes_are_those_with_every_job_of_the_run():
    from runner.export import complete_shapes

    jobs = [(m, level) for m in ("sals-knn", "poisson") for level in ("scan", "noise-1")]
    rows = [{"shape": s, "method": m, "mode": "neural", "seed": 0, "sweep.pc_corruption": level, "status": "ok"}
            for s in ("a", "b", "c") for m, level in jobs]
    results = pd.DataFrame(rows)
    results.loc[(results["shape"] == "b") & (results["method"] == "poisson"), "status"] = "failed"
    stopped = results.drop(results.index[(results["shape"] == "c") & (results["sweep.pc_corruption"] == "noise-1")])
    assert complete_shapes(results) == ["a", "b", "c"]
    assert complete_shapes(stopped) == ["a", "b"]  # a failed job is finished; c lacks two of its four jobs
    assert complete_shapes(results.iloc[:0]) == []


def test_caption_says_when_a_report_covers_only_the_finished_shapes():
    from reports.protocol import protocol_caption

    assert "dataset: builtin (3 shapes);" in protocol_caption(dict(CONTEXT, planned_shapes=3))
    assert ("dataset: builtin (3 shapes of the run's 22: those whose every job finished);"
            in protocol_caption(dict(CONTEXT, planned_shapes=22)))

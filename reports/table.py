"""The table model of the reports and its Markdown and LaTeX writers.

Every table is built once as a :class:`Table` of plain-text :class:`Cell` s (unicode, never
escaped) plus bold flags and a kind per row, then written by each writer, which escapes every cell:

* Markdown: pandas ``DataFrame.to_markdown`` (tabulate) on cells escaped by :func:`md_escape`.
* LaTeX: :func:`table_latex`, a booktabs float. It stays hand-written rather than pandas'
  ``Styler.to_latex`` because the tables need what Styler does not give: a ``\\midrule`` before
  (and after) the floor row only, bold per cell (the best of a column and its ties) and
  an italic floor row in the same table, a caption that is the title plus the protocol, and the
  unicode of headers and names (×, ↓, ↑, –, ³, ...) mapped to LaTeX (:func:`tex_escape`), where
  Styler's ``escape='latex'`` only escapes the specials.
* HTML: ``reports.html.table_html`` (stdlib :func:`html.escape`).

Numbers are printed with :func:`fmt` (fixed point, NaN as an en dash); :func:`best_flags` marks the
best of a column compared at the printed precision, so ties are all bold (the statistics tables add
the ties within the noise, :mod:`reports.significance`). A cell's ``detail`` (a confidence interval)
follows its text, never bold: ``**4.500** [4.100, 4.930]`` in Markdown, ``\\,{\\scriptsize ...}`` in
LaTeX, a muted span in HTML.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

DASH = "–"
DIGITS = 3


@dataclass
class Cell:
    """One table cell: plain text, bold flag, optional hover text (HTML, e.g. an error message) and
    detail (plain text after the value, never bold, e.g. a confidence interval)."""

    text: str
    bold: bool = False
    title: str | None = None
    detail: str = ""


@dataclass
class Table:
    """A writer-agnostic table.

    Attributes
    ----------
    key : identifier (LaTeX label ``tab:salsbench-<key>``).
    title, caption : plain text; the caption states the protocol.
    headers : plain-text column headers; ``tex_headers`` the same in LaTeX source (math arrows).
    align : 'l' or 'r' per column.
    rows, row_kinds : cells per row and the row's kind ('method', 'floor', 'stage', 'step', 'sum',
        'total') for styling.
    notes : plain-text lines printed under the table.
    """

    key: str
    title: str
    caption: str
    headers: list[str]
    tex_headers: list[str]
    align: list[str]
    rows: list[list[Cell]] = field(default_factory=list)
    row_kinds: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def add(self, cells: list[Cell], kind: str = "method") -> None:
        if len(cells) != len(self.headers):
            raise ValueError(f"table {self.key}: row has {len(cells)} cells for {len(self.headers)} columns")
        self.rows.append(cells)
        self.row_kinds.append(kind)


def fmt(value, digits: int = DIGITS) -> str:
    """Fixed-point text with ``digits`` decimals; NaN, inf and None -> an en dash."""
    if value is None or not np.isfinite(value):
        return DASH
    return f"{value:.{digits}f}"


def best_flags(values: list[float], lower_is_better: bool, digits: int = DIGITS) -> list[bool]:
    """True where the value, rounded to the printed precision, is the best of the finite ones."""
    rounded = [round(v, digits) if v is not None and np.isfinite(v) else None for v in values]
    finite = [v for v in rounded if v is not None]
    if not finite:
        return [False] * len(values)
    best = min(finite) if lower_is_better else max(finite)
    return [v == best for v in rounded]


def _power_of_ten(scale: float) -> int | None:
    exponent = math.log10(scale)
    return round(exponent) if abs(exponent - round(exponent)) < 1e-9 else None


def metric_header(metric) -> str:
    """Plain header of a ``foundation.metrics.HeadlineMetric``: 'CD ×1e3 ↓', 'NC ↑', 'F1@0.005 ↑'."""
    scale = ""
    if metric.scale != 1:
        power = _power_of_ten(metric.scale)
        scale = f"×1e{power}" if power is not None else f"×{metric.scale:g}"
    arrow = "↓" if metric.lower_is_better else "↑"
    return " ".join(part for part in (metric.name, scale, arrow) if part)


def metric_tex_header(metric) -> str:
    """LaTeX header of a headline metric: 'CD ($\\times 10^{3}$) $\\downarrow$'."""
    scale = ""
    if metric.scale != 1:
        power = _power_of_ten(metric.scale)
        scale = rf" ($\times 10^{{{power}}}$)" if power is not None else rf" ($\times {metric.scale:g}$)"
    arrow = r"$\downarrow$" if metric.lower_is_better else r"$\uparrow$"
    return f"{tex_escape(metric.name)}{scale} {arrow}"


# ---------------------------------------------------------------------------------------------
# Markdown
# ---------------------------------------------------------------------------------------------

_MD_SPECIALS = re.compile(r"([\\`*_\[\]<>&|~])")
_NEWLINES = re.compile(r"\s*[\r\n]+\s*")


def md_escape(text) -> str:
    """Plain text -> Markdown that shows it literally, one line, safe inside a table cell.

    Backslash-escapes the characters Markdown (GitHub flavour) would interpret: ``\\ ` * _ [ ] < >
    & | ~`` (so 'a|b<i>' stays one cell and no HTML), and joins lines with a space.
    """
    return _MD_SPECIALS.sub(r"\\\1", _NEWLINES.sub(" ", str(text)))


def _md_cell(cell: Cell) -> str:
    text = f"**{md_escape(cell.text)}**" if cell.bold and cell.text != DASH else md_escape(cell.text)
    return f"{text} {md_escape(cell.detail)}" if cell.detail else text


def table_markdown(table: Table) -> str:
    """GitHub Markdown via pandas/tabulate; every cell escaped, bold cells as **x**, the detail after."""
    body = [[_md_cell(c) for c in row] for row in table.rows]
    headers = [md_escape(h) for h in table.headers]
    frame = pd.DataFrame(body, columns=headers)
    if frame.empty:
        return "| " + " | ".join(headers) + " |\n|" + "---|" * len(headers) + "\n"
    colalign = ["left" if a == "l" else "right" for a in table.align]
    return frame.to_markdown(index=False, disable_numparse=True, colalign=colalign) + "\n"


def table_markdown_section(table: Table, *, with_caption: bool = False) -> list[str]:
    """Lines of one Markdown section: '## title', the caption (when asked), the table, its notes
    (in italics)."""
    lines = [f"## {md_escape(table.title)}", ""] + ([md_escape(table.caption), ""] if with_caption else [])
    return lines + [table_markdown(table)] + [f"*{md_escape(n)}*\n" for n in table.notes]


# ---------------------------------------------------------------------------------------------
# LaTeX
# ---------------------------------------------------------------------------------------------

_TEX_REPLACE = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "×": r"$\times$",
    "↓": r"$\downarrow$",
    "↑": r"$\uparrow$",
    "–": "--",
    "—": "---",
    "±": r"$\pm$",
    "†": r"$^{\dagger}$",
    "≤": r"$\leq$",
    "≥": r"$\geq$",
    "·": r"$\cdot$",
    "→": r"$\rightarrow$",
    "−": r"$-$",
    "½": r"$\frac{1}{2}$",
    "³": r"$^3$",
    "²": r"$^2$",
    "|": r"$|$",
    "<": r"$<$",
    ">": r"$>$",
}
_TEX_PATTERN = re.compile("|".join(re.escape(k) for k in _TEX_REPLACE))


def tex_escape(text) -> str:
    """Plain (unicode) text -> LaTeX source, escaping the specials and mapping ×, ↓, ↑, – etc."""
    return _TEX_PATTERN.sub(lambda m: _TEX_REPLACE[m.group(0)], str(text))


def _tex_cell(cell: Cell) -> str:
    text = rf"\textbf{{{tex_escape(cell.text)}}}" if cell.bold and cell.text != DASH else tex_escape(cell.text)
    return rf"{text}\,{{\scriptsize {tex_escape(cell.detail)}}}" if cell.detail else text


def table_latex(table: Table) -> str:
    """A booktabs ``table`` float (needs ``\\usepackage{booktabs}``); bold as ``\\textbf``, the
    floor row in italics between midrules."""
    lines = [
        r"\begin{table}[t]",
        r"\centering",
        r"\small",
        rf"\caption{{{tex_escape(table.title)}. {tex_escape(table.caption)}}}",
        rf"\label{{tab:salsbench-{table.key}}}",
        rf"\begin{{tabular}}{{{''.join(table.align)}}}",
        r"\toprule",
        " & ".join(table.tex_headers) + r" \\",
        r"\midrule",
    ]
    previous = None
    for row, kind in zip(table.rows, table.row_kinds):
        if previous is not None and kind != previous and "floor" in (kind, previous):
            lines.append(r"\midrule")
        cells = [_tex_cell(c) for c in row]
        if kind == "floor":
            cells = [rf"\textit{{{c}}}" for c in cells]
        lines.append(" & ".join(cells) + r" \\")
        previous = kind
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}", ""]
    return "\n".join(lines)

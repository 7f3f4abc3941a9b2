"""The table model's writers: Markdown and LaTeX escaping, number formatting, bold at printed precision."""

from __future__ import annotations

import numpy as np

from reports.table import DASH, Cell, Table, best_flags, fmt, md_escape, table_latex, table_markdown, tex_escape


def test_md_escape_makes_user_text_literal_and_one_line():
    assert md_escape("a|b") == r"a\|b"
    assert md_escape("<script>&amp;") == r"\<script\>\&amp;"
    assert md_escape(r"x\y *b* _i_ `c` [l](u) ~~s~~") == r"x\\y \*b\* \_i\_ \`c\` \[l\](u) \~\~s\~\~"
    assert md_escape("two\n  lines") == "two lines"
    assert md_escape("Ω-bracket 部品 0.5 – #V") == "Ω-bracket 部品 0.5 – #V"  # nothing else touched


def test_tex_escape_specials_and_unicode():
    assert tex_escape("a_b & 50% $x$ #1 {y} ~^\\") == (r"a\_b \& 50\% \$x\$ \#1 \{y\} \textasciitilde{}"
                                                       r"\textasciicircum{}\textbackslash{}")
    assert tex_escape("CD ×1e3 ↓ |n·n| < ½ → −") == (r"CD $\times$1e3 $\downarrow$ $|$n$\cdot$n$|$ $<$ "
                                                     r"$\frac{1}{2}$ $\rightarrow$ $-$")


def test_fmt_and_best_flags_at_printed_precision():
    assert (fmt(4.5), fmt(np.nan), fmt(None), fmt(np.inf), fmt(2.0, 1)) == ("4.500", DASH, DASH, DASH, "2.0")
    # 1.0004 and 1.0001 both print as 1.000: a tie, both bold; NaN never bold
    assert best_flags([1.0004, 1.0001, 2.0, np.nan], lower_is_better=True) == [True, True, False, False]
    assert best_flags([0.5, 0.7, np.nan], lower_is_better=False) == [False, True, False]
    assert best_flags([np.nan, np.nan], lower_is_better=True) == [False, False]


def table() -> Table:
    t = Table("t", "Title", "Cap", ["name", "v"], ["name", "v"], ["l", "r"])
    t.add([Cell("a|b"), Cell("1.000", bold=True)])
    t.add([Cell("floor"), Cell(DASH, bold=True)], "floor")
    return t


def test_markdown_rows_bold_and_escaped():
    lines = table_markdown(table()).splitlines()
    assert len(lines) == 4  # header, rule, two rows: the pipe in 'a|b' did not add a column
    assert lines[2].startswith(r"| a\|b ") and "**1.000**" in lines[2]
    assert "**" not in lines[3]  # a dash is never bold


def test_latex_midrules_around_floor_and_italic_floor():
    tex = table_latex(table()).splitlines()
    rows = tex[tex.index(r"\midrule") + 1:tex.index(r"\bottomrule")]
    assert rows == [r"a$|$b & \textbf{1.000} \\", r"\midrule", r"\textit{floor} & \textit{--} \\"]

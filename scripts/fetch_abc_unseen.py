"""Check the ABC parts of ``lists/abc-unseen.txt`` against their pins, or copy them out of a ppsurf_modeling clone.

    .venv/bin/python scripts/fetch_abc_unseen.py --check                          # verify ../shared/data/abc-ppsurf
    .venv/bin/python scripts/fetch_abc_unseen.py --check DIR                      # verify another copy
    .venv/bin/python scripts/fetch_abc_unseen.py --repo ../ppsurf_modeling        # copy -> ../shared/data/abc-ppsurf
    .venv/bin/python scripts/fetch_abc_unseen.py --repo ../ppsurf_modeling --out DIR

The meshes are not in this repository: they come from github.com/cg-tuwien/ppsurf_modeling (MIT) at
the pinned commit ``COMMIT``, and ``abc-ppsurf`` in ../shared/data beside the checkout
(``$SALSBENCH_SHARED_DATA`` when set, as in tests/conftest.py) holds all 104 files of its
``datasets/abc_modeling/00_base_meshes/``, byte for byte: the default source, where ``--check``
looks and ``--repo`` copies to. When ``--repo`` does not exist the script prints the ``git clone``
and ``git checkout`` commands that make it. ``lists/abc-unseen.csv`` (committed) pins every file:
its source path in that repository and its SHA-256. Each problem (entry missing from the manifest,
source or copy missing, SHA-256 differs) is reported on one line (:func:`datasets.manifest.check_file`);
the exit status is 1 if there was any, 2 on usage errors (missing clone), 0 otherwise.
docs/ABC-UNSEEN.md states the selection rule.
"""

from __future__ import annotations

import argparse
import csv
import shutil
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from datasets.abc import default_ppsurf_dir, read_list_file  # noqa: E402
from datasets.manifest import check_file as check_pinned  # noqa: E402

LIST = REPO / "lists" / "abc-unseen.txt"
MANIFEST = REPO / "lists" / "abc-unseen.csv"
SOURCE_URL = "https://github.com/cg-tuwien/ppsurf_modeling"
COMMIT = "3dd947344aca3b1d206207c4cd3e5faaa9ae6b54"


def manifest_rows(list_file: Path = LIST, manifest: Path = MANIFEST) -> tuple[list[dict], list[str]]:
    """The manifest rows of the list's entries, in list order, and one problem line per entry with no
    row and per row with no entry."""
    with open(manifest, newline="") as f:
        rows = {Path(r["file"]).stem: r for r in csv.DictReader(f)}
    entries = read_list_file(list_file)
    problems = [f"{e}: listed in {list_file.name} but not in {manifest.name}" for e in entries if e not in rows]
    problems += [f"{s}: in {manifest.name} but not listed in {list_file.name}" for s in rows if s not in entries]
    return [rows[e] for e in entries if e in rows], problems


def check_file(path: Path, row: dict) -> str | None:
    """One problem line for ``path`` against its manifest row, or None when it matches."""
    return check_pinned(path, row["sha256"], MANIFEST.name)


def fetch(repo: Path, out: Path, rows: list[dict]) -> list[str]:
    """Copy each row's source file from ``repo`` into ``out`` (flat, same file name) after checking it."""
    out.mkdir(parents=True, exist_ok=True)
    problems = []
    for row in rows:
        source = repo / row["source_path"]
        problem = check_file(source, row)
        if problem:
            problems.append(problem)
            continue
        shutil.copyfile(source, out / row["file"])
        problem = check_file(out / row["file"], row)
        if problem:
            problems.append(problem)
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repo", type=Path, help=f"local clone of {SOURCE_URL} at {COMMIT[:12]}")
    parser.add_argument("--out", type=Path, default=None,
                        help=f"folder to copy into (default: {default_ppsurf_dir()})")
    parser.add_argument("--check", type=Path, metavar="DIR", nargs="?", const=default_ppsurf_dir(),
                        help=f"only verify the files in DIR (default: {default_ppsurf_dir()}), copy nothing")
    args = parser.parse_args(argv)
    args.out = default_ppsurf_dir() if args.out is None else args.out
    if (args.repo is None) == (args.check is None):
        parser.error("give either --repo PATH (fetch) or --check DIR (verify)")

    rows, problems = manifest_rows()
    if args.check is not None:
        problems += [p for row in rows if (p := check_file(args.check / row["file"], row))]
        where = args.check
    elif not args.repo.is_dir():
        print(f"{args.repo} does not exist; make it with:\n"
              f"  git clone {SOURCE_URL} {args.repo}\n"
              f"  git -C {args.repo} checkout {COMMIT}", file=sys.stderr)
        return 2
    else:
        problems += fetch(args.repo, args.out, rows)
        where = args.out
    for line in problems:
        print(line, file=sys.stderr)
    print(f"{len(problems)} problem(s) in {where}" if problems else f"{len(rows)} files ok in {where}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())

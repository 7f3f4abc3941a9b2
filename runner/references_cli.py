"""``run_benchmark.py references``: list the reference sets; ``references make RUN_DIR --name NAME``:
make one from a finished run (:mod:`runner.references`)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Sequence

from runner.parsing import EXIT_OK, EXIT_REFUSED, OneLineParser


def build_references_parser() -> OneLineParser:
    p = OneLineParser(prog="run_benchmark.py references",
                      description="List the reference sets (per-shape rows of finished runs with their protocol), "
                                  "or make one from a finished run: references make RUN_DIR --name NAME.")
    p.add_argument("action", nargs="?", choices=["list", "make"], default="list")
    p.add_argument("run", nargs="?", metavar="RUN_DIR", help="make: the finished run directory")
    p.add_argument("--name", help="make: the set's name (a folder name)")
    p.add_argument("--description", default="", help="make: one line saying what the set is")
    p.add_argument("--leave-out", nargs="+", default=[], metavar="JOB",
                   help="make: jobs left out of the set, METHOD or SHAPE/METHOD (a run's failed jobs must be named)")
    p.add_argument("--into", metavar="DIR", help="make: the folder of sets to write into (default: references/ of "
                                                 "the checkout); list: the folder to list")
    p.add_argument("--replace", action="store_true", help="make: replace a set of the same name")
    return p


def references_main(argv: Sequence[str]) -> int:
    from runner.config import ConfigError
    from runner.references import REFERENCES_DIR, listing, make_reference, stale_reason

    args = build_references_parser().parse_args(list(argv))
    folder = Path(args.into) if args.into else REFERENCES_DIR
    try:
        if args.action == "list":
            if args.run or args.name:
                raise ConfigError("references: RUN_DIR and --name go with 'make'")
            table = listing(folder)
            if table.empty:
                print(f"no reference sets in {folder}")
                return EXIT_OK
            print(table.to_markdown(index=False))
            print(f"\n{len(table)} sets in {folder}; a stale set (metric code other than this checkout's) is refused by "
                  "--reference with the command that re-makes it.")
            return EXIT_OK
        if not args.run or not args.name:
            raise ConfigError("references make needs RUN_DIR and --name NAME")
        ref = make_reference(Path(args.run), args.name, folder, args.description, tuple(args.leave_out), args.replace)
    except ConfigError as exc:
        print(f"run_benchmark.py references: error: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    print(f"wrote reference set {ref.name} in {ref.folder}: {len(ref.rows)} rows, {ref.rows['method'].nunique()} "
          f"methods, {len(ref.manifest['shapes'])} shapes, commit {ref.manifest['sources'][0]['commit']}")
    reason = stale_reason(ref)
    if reason:
        print(f"note: {reason}", file=sys.stderr)
    return EXIT_OK

#!/usr/bin/env python
"""salsbench command line: ``python run_benchmark.py --help``.

    python run_benchmark.py --methods sals sdf                       # default benchmark (builtin shapes)
    python run_benchmark.py --mode oracle --grid 64 --quiet          # exact fields, no fitting
    python run_benchmark.py report runs/A runs/B                     # tables/report from finished runs

Everything lives in :mod:`benchmark.runner`; this file only makes the checkout importable.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from benchmark.runner import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())

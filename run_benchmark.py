#!/usr/bin/env python
"""Run the salsbench benchmark: ``python run_benchmark.py --help`` (see benchmark/run/cli.py)."""

import sys

from benchmark.run.cli import main

if __name__ == "__main__":
    sys.exit(main())

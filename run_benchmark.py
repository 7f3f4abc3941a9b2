#!/usr/bin/env python
"""Run the salsbench benchmark: ``python run_benchmark.py --help`` (see runner/cli.py)."""

import sys

from runner.cli import main

if __name__ == "__main__":
    sys.exit(main())

"""The command line's exit statuses and its argument parser whose errors are one line."""

from __future__ import annotations

import argparse

#: 0: every task ok; 2: refused before any work (a bad flag, path or setting); 3: some tasks failed.
EXIT_OK, EXIT_REFUSED, EXIT_FAILED_TASKS = 0, 2, 3


class OneLineParser(argparse.ArgumentParser):
    """argparse whose errors are one line on stderr (exit status :data:`EXIT_REFUSED`)."""

    def error(self, message: str):  # noqa: D401
        self.exit(EXIT_REFUSED, f"{self.prog}: error: {message}\n")

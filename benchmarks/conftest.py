"""pytest-benchmark speed measurements: not part of the default test run (how to run them: docs/PERFORMANCE.md, section 14)."""

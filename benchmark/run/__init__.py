"""The run layer: configuration, tasks, the job function, caches, provenance, driver, executors,
records, regression and the command line. Imports the foundation (benchmark.grid, sampler, fields,
metrics, ...) and ``methods``; never imported by them. ``reports`` sits above it."""

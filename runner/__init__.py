"""The run layer: configuration, tasks, the job function, caches, provenance, driver, executors,
records, regression and the command line. Imports the foundation (``foundation``, ``datasets``),
``methods`` and ``reports``; none of them imports it."""

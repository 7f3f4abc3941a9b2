"""The tasks of a run, one module each: what a task is (:mod:`tasks.spec`), what its body
works with (:mod:`tasks.context`), how its shape is loaded (:mod:`tasks.load`), and
the bodies that compute a result, each a ``run(context)``: :mod:`tasks.encode`,
:mod:`tasks.reconstruct`, :mod:`tasks.score` and :mod:`tasks.floor`.

These modules, with what they import, are the code a task's result depends on: its code digest
(:func:`tasks.cache.task_code_digest`) covers them and the method's module, nothing of the
command line, executors, progress display or reports, which never enter them.
"""

from tasks.spec import (JOB_TYPES, EncodeJob, FloorSpec, JobSpec, ReconstructJob, ScoreJob, TaskSpec, digest,
                        identity_options)

__all__ = ["JOB_TYPES", "EncodeJob", "FloorSpec", "JobSpec", "ReconstructJob", "ScoreJob", "TaskSpec", "digest",
           "identity_options"]

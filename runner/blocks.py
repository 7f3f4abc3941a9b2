"""Block-wise jobs' blocks on the run's executor: the run layer's part of ``--pc-blocks B``.

What a block-wise job computes, its cloud, scene grid, blocks and merge, is :mod:`tasks.blocks`
(the job's body, inside its code digest). Here the driver only schedules it
(:func:`run_blocks`): it has each job's cloud prepared once, runs its missing blocks on the run's
executor (process pool or Ray: one block per task, in the task frame,
:func:`runner.job.run_block_task`), stores each block's result as it arrives (atomically: a run
killed between blocks keeps them, and the next run computes only the missing ones), and runs again,
with the halo it asked for, a block whose crop missed points its edges need. The blocks are kept in
``OUT/blocks/<job key>_<code digest>/`` (:func:`tasks.block_store.blocks_folder`): a job whose code
changed starts a new folder, and the folders of its other code are removed.

With Ray on several machines, ``OUT`` must be on a file system every node sees.
"""

from __future__ import annotations

import shutil
import sys
from dataclasses import replace
from pathlib import Path

from runner.job import run_block_task
from tasks.block_store import blocks_folder, other_code_folders, write_block
from tasks.blocks import block_tasks, prepare_cloud
from tasks.spec import JobSpec


def _say(text: str) -> None:
    print(f"salsbench: {text}", file=sys.stderr, flush=True)


def run_blocks(jobs: list[JobSpec], run_dir: Path, executor, codes: dict[str, str]) -> list[JobSpec]:
    """Run the missing blocks of the block-wise ``jobs`` on ``executor`` (module docstring); returns
    the jobs with their ``blocks_dir`` set. ``codes``: each job's code digest by its key. A job whose
    cloud cannot be made is returned as is: it fails in its own task with that reason."""
    ready, tasks = [], []
    for job in jobs:
        folder = blocks_folder(run_dir, job, codes[job.key])
        for stale in other_code_folders(run_dir, job, codes[job.key]):
            _say(f"{job.label}: removing the blocks of other code than today's ({stale.name})")
            shutil.rmtree(stale)
        try:
            prepare_cloud(job, folder)
            tasks += block_tasks(job, folder)
        except Exception as exc:  # noqa: BLE001 -- the job reports it when it runs
            _say(f"{job.label}: no blocks ({type(exc).__name__}: {exc})")
        ready.append(replace(job, blocks_dir=str(folder)))
    rounds = 0
    while tasks:
        rounds += 1
        _say(f"{len(tasks)} blocks to run (round {rounds})")
        again = []
        for task, outcome in executor.run(run_block_task, tasks):
            if isinstance(outcome, BaseException):
                _say(f"{task.label}: worker lost ({type(outcome).__name__}: {outcome})")
            elif outcome.status == "ok":
                write_block(outcome)
            elif outcome.status == "halo":
                again.append(replace(task, halo=max(outcome.needed_halo, 2.0 * task.halo)))
            else:
                _say(f"{task.label}: {outcome.error}")
        tasks = again
    return ready

"""What the reports state about a run (reports/protocol.py): the task, the mode where it applies,
the seeds as values, the budget where a method reads one, and the device with workers x threads."""

from __future__ import annotations

from reports.protocol import device_text, execution_text, protocol_items
from tests.test_reports_tables import CONTEXT

#: A reconstruct run of Poisson alone (no method fits under a budget) by 2 process workers x 1
#: thread, its context as runner.export.report_context makes it.
POISSON = dict(CONTEXT, task="reconstruct", mode="neural", budget="cpu", budget_values=None, seeds=[0],
               methods=["poisson"], device="cpu (2 threads)", cpu_model="Test CPU 3000",
               execution={"executor": "process", "workers": 2, "threads_per_job": 1})


def test_a_reconstruct_run_states_no_mode_and_no_budget_and_its_one_seed_as_a_value():
    items = dict(protocol_items(POISSON))
    assert items["task"] == "reconstruct" and "mode" not in items and "budget" not in items
    assert items["seed"] == "0" and "seeds" not in items
    learned = dict(protocol_items(dict(POISSON, budget_values={"knn": {"k": 20}})))
    assert learned["budget"] == "cpu (k 20)" and "mode" not in learned


def test_an_encode_run_states_its_mode_budget_and_seeds():
    items = dict(protocol_items(dict(CONTEXT, seeds=[0, 1, 2])))
    assert (items["task"], items["mode"], items["seeds"]) == ("encode", "neural", "0, 1, 2")
    assert items["budget"] == "quick (steps 2000, lr 0.001)"
    oracle = dict(protocol_items(dict(CONTEXT, mode="oracle", budget=None, budget_values=None)))
    assert oracle["mode"] == "oracle" and "budget" not in oracle


def test_the_device_leaves_out_the_driver_threads_where_the_jobs_own_are_recorded():
    assert device_text(POISSON) == "cpu (Test CPU 3000)"
    assert execution_text(POISSON) == "executor process, 2 workers x 1 torch thread"
    assert device_text(dict(POISSON, execution=None)) == "cpu (2 threads) (Test CPU 3000)"  # nothing better known
    gpu = dict(POISSON, device="cuda: NVIDIA H100", gpu="NVIDIA H100", cpu_model=None)
    assert device_text(gpu) == "cuda: NVIDIA H100"


def test_the_execution_names_each_way_the_tasks_of_one_directory_ran_with_their_counts():
    process = {"executor": "process", "workers": 2, "threads_per_job": 1}
    local = {"executor": "local", "workers": 1, "threads_per_job": 2}
    one_way = dict(POISSON, sessions=[{"execution": process, "tasks": 18}, {"execution": process, "tasks": 2}])
    assert execution_text(one_way) == "executor process, 2 workers x 1 torch thread"
    two_ways = dict(POISSON, execution=local, sessions=[{"execution": process, "tasks": 18},
                                                          {"execution": local, "tasks": 0},
                                                          {"execution": local, "tasks": 2}])
    assert execution_text(two_ways) == ("executor process, 2 workers x 1 torch thread (18 tasks); "
                                        "executor local, 1 worker x 2 torch threads (2 tasks)")
    older = dict(two_ways, sessions=[{"execution": process, "tasks": None}, {"execution": local, "tasks": 2}])
    assert execution_text(older).startswith("executor process, 2 workers x 1 torch thread (tasks of an earlier run)")

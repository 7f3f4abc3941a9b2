"""tasks.spec: one job type per task, each keyed by what defines its result. The keys below were
computed by the single job type of earlier versions: every run directory written before the split
keeps its keys (a changed key would re-run, or orphan, its finished rows)."""

from __future__ import annotations

import pickle

import pytest

from tasks.spec import JOB_TYPES, EncodeJob, FloorSpec, ReconstructJob, ScoreJob

COMMON = dict(dataset="builtin", dataset_options={"limit": 2}, shape="bracket", eval_points=100000,
              metric_preset="default", seed=0)

#: (job, its key under the earlier single job type)
EARLIER_KEYS = [
    (EncodeJob(**COMMON, method="sals", params={"o_threshold": 0.5}, mode="neural", budget="cpu", grid=128),
     "be4100503893c6d2"),
    (EncodeJob(**COMMON, method="sdf", mode="neural", budget="cpu", grid=64, checkpoints=(0.5, 1.0),
               budget_params={"steps": 100}, decompose=True), "a9e305c8743e5495"),
    (EncodeJob(**COMMON, method="udf-ndc", params={"a": 1}, mode="oracle", grid=128), "9d15ed6e9141cc52"),
    (ReconstructJob(**COMMON, method="poisson", grid=128, pc_points=40000, pc_noise=0.0), "204930c3d433e6fc"),
    (ReconstructJob(**COMMON, method="sals-knn", budget="cpu", grid=128, pc_points=40000, pc_noise=0.0,
                    pc_corruption="scan", train_dirs=("/x",), budget_params={"steps": 10}), "832fa66fd2f18c47"),
    (ReconstructJob(**COMMON, method="poisson", grid=128, pc_points=40000, pc_noise=0.0, pc_blocks=4),
     "23471526d59bd6fb"),
    (ScoreJob(**COMMON, method="mine", params={"pred_dir": "/p", "pred_frame": "original"}, grid=128),
     "bfc8505f97daceda"),
    (FloorSpec(**COMMON), "76717b0053e16eca"),
]


@pytest.mark.parametrize("job, key", EARLIER_KEYS, ids=lambda x: getattr(x, "label", ""))
def test_each_job_type_keeps_the_keys_of_earlier_run_directories(job, key):
    assert job.key == key
    assert pickle.loads(pickle.dumps(job)).key == key  # executors send jobs to other processes


def test_a_job_type_carries_only_its_tasks_settings_and_names_its_body():
    assert {t: j.task for t, j in JOB_TYPES.items()} == {"encode": "encode", "reconstruct": "reconstruct",
                                                          "score": "score"}
    assert {t: j(**COMMON).body for t, j in JOB_TYPES.items()} == {t: f"tasks.{t}" for t in JOB_TYPES}
    assert not hasattr(ScoreJob(**COMMON), "mode") and not hasattr(EncodeJob(**COMMON), "pc_points")
    assert not hasattr(ReconstructJob(**COMMON), "checkpoints")


def test_what_a_job_fits_and_shares():
    neural = EncodeJob(**COMMON, method="sdf", budget="cpu")
    assert neural.uses_fitting and neural.fit_identity() == EncodeJob(**COMMON, method="sdf-ndc", budget="cpu").fit_identity()
    assert EncodeJob(**COMMON, method="sdf", mode="oracle").fit_identity() is None
    learned = ReconstructJob(**COMMON, method="sals-knn", budget="cpu")
    assert learned.fit_identity() == ReconstructJob(**{**COMMON, "shape": "other"}, method="sals-knn",
                                                    budget="cpu").fit_identity()  # one network for every shape
    assert ReconstructJob(**COMMON, method="cap-udf", budget="cpu").fit_identity() is None  # optimises per cloud
    assert not ScoreJob(**COMMON).uses_fitting and ScoreJob(**COMMON).fit_identity() is None
    assert ReconstructJob(**COMMON, pc_blocks=4).block_wise and not ReconstructJob(**COMMON).block_wise
    assert not EncodeJob(**COMMON).block_wise
    assert EncodeJob(**COMMON, mode="oracle", grid=64).table_fields() == {"mode": "oracle", "budget": None, "grid": 64}

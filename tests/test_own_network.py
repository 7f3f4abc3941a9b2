"""The learned methods with their own network (POCO, GIFS, GeoUDF): each trains under a budget of its
own family, on the same training set as the K-NN networks at the same budget name, stores that
budget with its weights, and every table caption states each family's values."""

import dataclasses

import numpy as np
import pytest
import torch

from methods.base import METHODS, get_method
from methods.core.budgets import budget_values
from methods.core.weights import load_plain
from methods.pointcloud.knn.training import KNN_BUDGETS
from methods.pointcloud.training_set import TrainingSet, TrainResult
from reports.protocol import protocol_caption

OWN = ("poco", "gifs", "geoudf")


@pytest.mark.parametrize("name", OWN)
def test_each_reads_its_own_budget_family_with_the_knn_training_set(name):
    cls = METHODS.get(name)
    assert cls.budget_family == name
    training_set = [f.name for f in dataclasses.fields(TrainingSet)]
    for budget in ("paper", "cpu", "tiny"):
        mine, knn = cls.budget(budget), KNN_BUDGETS.get(budget)
        assert {f: getattr(mine, f) for f in training_set} == {f: getattr(knn, f) for f in training_set}
    assert set(training_set) <= cls.budget_fields() and "k" not in cls.budget_fields()


@pytest.mark.parametrize("name", OWN)
def test_the_stored_weights_carry_the_budget_values(name):
    method = get_method(name)
    budget = method.budget("tiny")
    net = torch.nn.Linear(2, 2)
    net.config = {}
    data = method.network_to_bytes(TrainResult(model=net, losses=np.zeros(1), seconds=1.0, steps=1,
                                               samples_per_s=1.0, final_loss=0.5), budget)
    blob = load_plain(data)  # plain data: it loads with weights_only=True
    assert blob["budget"] == budget_values(budget) and blob["method"] == name


def test_the_caption_states_the_values_of_each_budget_family_of_the_run():
    context = {"dataset": "abc", "task": "reconstruct", "mode": "neural", "budget": "cpu",
               "budget_values": {"knn": {"k": 20}, "poco": {"steps": 1200}}, "grid": 128, "seeds": [0],
               "methods": ["sals-knn", "poco"], "shapes": ["a"], "metric_preset": "default", "eval_points": 1000,
               "method_notes": {}}
    assert "budget: cpu (knn: k 20; poco: steps 1200)" in protocol_caption(context)
    one_family = dict(context, budget_values={"encode": {"steps": 3000}})
    assert "budget: cpu (steps 3000)" in protocol_caption(one_family)
    recorded_before_families = dict(context, budget_values={"steps": 3000})  # values not keyed by family
    assert "budget: cpu (steps 3000)" in protocol_caption(recorded_before_families)

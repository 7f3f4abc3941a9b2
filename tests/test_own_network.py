"""What the learned methods with their own network say about themselves in every table caption."""

import pytest

from methods.base import METHODS
from reports.protocol import protocol_caption
from runner.export import method_notes


@pytest.mark.parametrize("name, label", [("poco", "POCO"), ("gifs", "GIFS"), ("geoudf", "GeoUDF")])
def test_each_own_network_method_notes_that_the_budget_values_are_the_knn_networks(name, label):
    note = METHODS.get(name).table_note
    assert note.startswith(f"{name} trains {label}'s own network") and "K-NN network" in note


def test_the_caption_of_a_reconstruct_run_carries_the_notes_of_its_methods_only():
    notes = method_notes(["sals-knn", "poco", "cap-udf"])
    assert set(notes) == {"poco", "cap-udf"}  # sals-knn is the K-NN network the budget describes
    context = {"dataset": "abc", "task": "reconstruct", "mode": "neural", "budget": "cpu",
               "budget_values": {"k": 20}, "grid": 128, "seeds": [0], "methods": ["sals-knn", "poco"],
               "shapes": ["a"], "metric_preset": "default", "eval_points": 1000, "method_notes": notes}
    caption = protocol_caption(context)
    assert "budget: cpu (k 20)" in caption and notes["poco"] in caption and notes["cap-udf"] not in caption

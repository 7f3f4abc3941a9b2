"""A network as bytes and back (methods.core.weights): a round trip gives the same network, and bytes
that would run code when unpickled are refused unread, in one line, whoever wrote them."""

import io
import pathlib

import pytest
import torch

from methods.core.network import make_network
from methods.core.weights import WeightsError, weights_from_bytes, weights_to_bytes


class TouchOnLoad:
    """Unpickling this object calls ``pathlib.Path.touch(marker)``: a stand-in for any code a crafted
    weights file could run."""

    def __init__(self, marker: pathlib.Path):
        self.marker = marker

    def __reduce__(self):
        return pathlib.Path.touch, (self.marker,)


def crafted_weights(marker: pathlib.Path) -> bytes:
    """``torch.save`` bytes shaped like a weights record whose ``config`` runs code when unpickled."""
    buf = io.BytesIO()
    torch.save({"state_dict": {}, "config": TouchOnLoad(marker), "budget": {}, "method": "sdf", "final_loss": 0.0},
               buf)
    return buf.getvalue()


def test_round_trip_gives_the_same_network():
    net = make_network(3, 1, depth=3, width=16)
    model, blob = weights_from_bytes(weights_to_bytes(net, {"steps": 3}, "sdf", 0.25), make_network, "cpu", "sdf")
    assert blob["budget"] == {"steps": 3} and blob["final_loss"] == 0.25 and not model.training
    for key, value in net.state_dict().items():
        torch.testing.assert_close(model.state_dict()[key], value, rtol=0, atol=0)


def test_a_file_that_would_run_code_is_refused_unread_in_one_line(tmp_path):
    data = crafted_weights(tmp_path / "ran")
    torch.load(io.BytesIO(data), weights_only=False)  # the payload is live: a plain unpickle runs it
    assert (tmp_path / "ran").exists()
    (tmp_path / "ran").unlink()
    with pytest.raises(WeightsError, match="weights refused unread: not a plain weights file") as info:
        weights_from_bytes(data, make_network, "cpu")
    assert "\n" not in str(info.value) and not (tmp_path / "ran").exists()


@pytest.mark.parametrize("data", [b"", b"not torch at all", b"PK\x03\x04truncated zip"])
def test_foreign_or_truncated_bytes_are_a_weights_error(data):
    with pytest.raises(WeightsError, match="refused unread") as info:
        weights_from_bytes(data, make_network, "cpu")
    assert "\n" not in str(info.value)


def test_plain_data_that_is_not_a_weights_record_is_refused():
    buf = io.BytesIO()
    torch.save([1, 2, 3], buf)
    with pytest.raises(WeightsError, match="not a weights record"):
        weights_from_bytes(buf.getvalue(), make_network, "cpu")

"""The learned intersection flags of sals-ndc (methods.extractors.learned_flags, methods.training.learned_flags):
the input grid's layout, a hand-set network that flags o > 1/2 exactly, the network's shapes, the
refusal of weights trained on an evaluation shape, and a deterministic training."""

import numpy as np
import pytest
import torch

from foundation.grid import ijk_axis_to_edge_index, num_edges
from methods.core.weights import WeightsError
from methods.extractors import learned_flags
from methods.extractors.rec7 import RECEPTIVE_PADDING, Rec7Network


def _threshold_network(channels: int = 4) -> Rec7Network:
    """A network whose logit of edge (p, a) is o(p, a) - 1/2: each layer passes the centre value of
    channel a on (the inputs are >= 0 where it matters, so leaky ReLU passes them)."""
    network = Rec7Network(channels, in_channels=learned_flags.IN_CHANNELS, out_channels=3)
    with torch.no_grad():
        for layer in (network.conv_0, network.conv_1, network.conv_2, network.conv_3, network.conv_4,
                      network.conv_out):
            layer.weight.zero_()
            layer.bias.zero_()
            centre = tuple(k // 2 for k in layer.weight.shape[2:])
            for a in range(3):
                layer.weight[(a, a) + centre] = 1.0
        network.conv_out.bias[:] = -0.5
    return network.eval()


def test_the_input_grid_holds_each_edges_o_and_centred_s_at_its_start_point():
    N = 10
    ids = ijk_axis_to_edge_index(N, np.array([[2, 3, 4], [0, 0, 0], [9, 9, 8]]), np.array([0, 1, 2]))
    grid = learned_flags.network_input(N, ids, np.array([0.9, 0.2, 0.6]), np.array([0.25, 0.5, 1.0]))
    assert grid.shape == (6, N + 6, N + 6, N + 6) and grid.dtype == np.float32
    p = RECEPTIVE_PADDING
    assert grid[0, 2 + p, 3 + p, 4 + p] == np.float32(0.9) and grid[3, 2 + p, 3 + p, 4 + p] == -0.25
    assert grid[1, p, p, p] == np.float32(0.2) and grid[4, p, p, p] == 0.0
    assert grid[2, 9 + p, 9 + p, 8 + p] == np.float32(0.6) and grid[5, 9 + p, 9 + p, 8 + p] == 0.5
    assert np.count_nonzero(grid) == 5  # every other edge and the padding read o = 0, s - 1/2 = 0


def test_a_network_that_thresholds_o_flags_exactly_the_candidates_above_one_half():
    N = 12
    rng = np.random.default_rng(0)
    ids = np.sort(rng.choice(num_edges(N), 400, replace=False))
    o = rng.random(400).astype(np.float32)
    s = rng.random(400).astype(np.float32)
    flagged = learned_flags.predict_flags(_threshold_network(), N, ids, o, s, o_low=0.3)
    np.testing.assert_array_equal(flagged, ids[o > 0.5])
    assert learned_flags.candidate_edges(ids, o, 0.3).tolist() == ids[o > 0.3].tolist()
    assert len(learned_flags.predict_flags(_threshold_network(), N, ids, o, s, o_low=float(o.max()))) == 0


def test_the_network_reads_six_channels_and_gives_three_logits_per_point():
    network = Rec7Network(8, in_channels=learned_flags.IN_CHANNELS, out_channels=3)
    out = network(torch.zeros(1, 6, 20, 21, 22))
    assert out.shape == (1, 3, 14, 15, 16)


def test_edge_labels_mark_the_crossing_edges_from_their_start_points():
    N = 6
    ids = ijk_axis_to_edge_index(N, np.array([[1, 2, 3], [4, 4, 4]]), np.array([2, 0]))
    labels = learned_flags.edge_labels(N, ids)
    assert labels.shape == (3, N, N, N) and labels.sum() == 2 and labels[2, 1, 2, 3] and labels[0, 4, 4, 4]
    assert learned_flags.edges_of_points(N, np.array([[5, 0, 0], [1, 2, 3]]), np.array([0, 2])).tolist() == [-1, ids[0]]


def test_weights_trained_on_an_evaluation_shape_are_refused_in_one_line(tmp_path):
    network = Rec7Network(4, in_channels=6, out_channels=3)
    good = tmp_path / "good.pt"
    learned_flags.save_weights(good, network, {"training_names": ["train1_builtin_000_bracket", "44234"],
                                               "training_hashes": ["a", "b"]})
    loaded, info = learned_flags.load_weights(good)
    assert info["training_names"] == ["train1_builtin_000_bracket", "44234"] and len(info["sha256"]) == 64
    for name in ("00000005_d4fe04f0f5f84b52bd4f10e4_trimesh_000", "builtin_001_flange"):
        bad = tmp_path / f"{name}.pt"
        learned_flags.save_weights(bad, network, {"training_names": ["44234", name], "training_hashes": []})
        with pytest.raises(WeightsError, match=rf"trained on evaluation shape\(s\) {name}: refused") as exc:
            learned_flags.load_weights(bad)
        assert "\n" not in str(exc.value)
    with pytest.raises(WeightsError, match="sals-ndc weights not found at .*absent.pt .*python -m methods.training"):
        learned_flags.load_weights(tmp_path / "absent.pt")


@pytest.mark.slow
def test_the_tiny_training_is_deterministic_and_learns():
    """Two trainings with the same seed give the same weights and losses bit for bit (the fits, the
    crops and the initialisation are seeded), they are trained on no evaluation shape, and the loss
    falls from its first steps to its last (the margins over seeds and float paths: docs/TESTING.md)."""
    from methods.training.learned_flags import learned_flags_training_shapes, train

    shapes = learned_flags_training_shapes("tiny")
    assert not any(learned_flags.EVALUATION_NAME.match(s.name) for s in shapes)
    a, b = train(shapes, "tiny", seed=0), train(shapes, "tiny", seed=0)
    for (name, x), (_, y) in zip(a.network.state_dict().items(), b.network.state_dict().items()):
        assert torch.equal(x, y), name
    assert np.array_equal(a.losses, b.losses) and np.isfinite(a.losses).all()
    assert a.losses[-10:].mean() < a.losses[:10].mean()

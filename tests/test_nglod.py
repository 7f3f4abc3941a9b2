"""``nglod``: NGLOD's network (summed multi-LOD feature volumes, one decoder per LOD) on the SDF.
The network by hand on constant volumes, each LOD blind to the finer ones, its weights round trip,
and a tiny fit of a sphere."""

import numpy as np
import pytest
import torch
import trimesh

from foundation.fields import ExactFields
from foundation.metrics import evaluate
from foundation.sampler import sample_training_data
from methods.base import get_method
from methods.core.fitting import BUDGETS, fit, model_from_bytes, model_to_bytes, parameter_groups
from methods.core.network import LODNetwork, make_network
from methods.fields.nglod import lod_resolutions


def test_the_authors_five_lods_are_volumes_of_4_to_64_cells():
    assert lod_resolutions(5) == (5, 9, 17, 33, 65)
    method = get_method("nglod")
    assert method.output_dim == 5
    config = method.network_config(BUDGETS["cpu"])
    assert config == {"backbone": "nglod", "width": 128, "grid_resolutions": (5, 9, 17, 33, 65), "grid_channels": 32}


def test_each_lod_decodes_the_features_summed_up_to_it():
    """Constant volumes: level l holds the feature vector c_l everywhere, so z_l = c_0 + ... + c_l at
    any point, and output l = w2_l . relu(W1_l [x, z_l] + b1_l) + b2_l."""
    torch.manual_seed(0)
    net = LODNetwork(3, 3, width=4, grid_resolutions=(3, 5, 9), grid_channels=2)
    constants = torch.tensor([[1.0, -2.0], [0.5, 0.25], [-1.0, 3.0]])
    with torch.no_grad():
        for level, c in zip(net.encoder.levels, constants):
            level.copy_(c.expand_as(level))
    x = torch.tensor([[0.1, -0.3, 0.7], [-0.9, 0.2, 0.0]])
    out = net(x)
    for l in range(3):
        z = constants[: l + 1].sum(dim=0).expand(2, 2)
        hidden = torch.relu(torch.cat([x, z], dim=1) @ net.hidden_weight[l] + net.hidden_bias[l])
        expected = hidden @ net.output_weight[l] + net.output_bias[l]
        torch.testing.assert_close(out[:, l], expected[:, 0])


def test_a_coarse_lod_does_not_see_the_finer_volumes():
    torch.manual_seed(0)
    net = LODNetwork(3, 3, width=8, grid_resolutions=(3, 5, 9), grid_channels=2)
    x = torch.rand(16, 3) * 2 - 1
    net(x)[:, 0].sum().backward()
    levels = list(net.encoder.levels)
    assert levels[0].grad.abs().sum() > 0
    assert levels[1].grad.abs().sum() == 0 and levels[2].grad.abs().sum() == 0
    assert net.hidden_weight.grad[1:].abs().sum() == 0  # the other LODs' decoders neither


def test_weights_round_trip_and_the_volumes_train_at_the_grid_rate():
    torch.manual_seed(0)
    net = make_network(3, 2, width=8, backbone="nglod", grid_resolutions=(3, 5), grid_channels=4)
    assert isinstance(net, LODNetwork) and make_network(**net.config).config == net.config
    loaded, loss = model_from_bytes(model_to_bytes(net, "cpu", "nglod", 0.5), device="cpu", method_name="nglod")
    x = torch.rand(10, 3) * 2 - 1
    torch.testing.assert_close(loaded(x), net(x), rtol=0, atol=0)
    grid_group = parameter_groups(net, BUDGETS["cpu"])[1]
    assert grid_group["lr_start"] == BUDGETS["cpu"].lr_grid and len(grid_group["params"]) == 2
    mlp_budget_group = parameter_groups(net, BUDGETS["tiny"])[1]  # no grid rates: the MLP's
    assert mlp_budget_group["lr_start"] == BUDGETS["tiny"].lr and mlp_budget_group["lr_end"] == BUDGETS["tiny"].lr_final
    with pytest.raises(ValueError, match="one output per level"):
        LODNetwork(3, 1, width=8, grid_resolutions=(3, 5), grid_channels=4)


@pytest.mark.learned
def test_tiny_fit_of_a_sphere_gets_finer_with_each_lod(fit_seed, torch_threads, measured):
    """Measured over seeds 0-4 on the AVX512 and scalar float paths: CD 0.0124-0.0125; the mean
    |f - d| of the finest LOD 0.0010-0.0013, 0.10-0.15 of the coarsest's (0.007-0.010)."""
    V, F = (np.asarray(a) for a in (lambda m: (m.vertices, m.faces))(trimesh.creation.icosphere(3, radius=0.7)))
    fields = ExactFields(V, F)
    samples = sample_training_data(V, F, BUDGETS["tiny"].num_samples, np.random.default_rng(0))
    method = get_method("nglod", lods=3, feature_dim=8, hidden=32)
    res = fit(method, samples, method.training_targets(fields, samples), "tiny", seed=fit_seed, device="cpu")
    points = samples.points[:4000]
    with torch.no_grad():
        errors = (res.model(torch.as_tensor(points)).numpy() - fields.sdf(points)[:, None]).__abs__().mean(axis=0)
    grid, info = method.neural_grid(res.model, 32, "cpu")
    ex = method.extract(grid, 32)
    r = evaluate(V, F, ex.vertices, ex.faces, n_points=10_000)
    measured(cd=r["cd"], coarsest_error=float(errors[0]), finest_error=float(errors[-1]))
    assert errors[-1] < 0.5 * errors[0]  # the finest LOD fits better than the coarsest
    assert info["query_fraction"] > 0
    assert r["cd"] < 0.03

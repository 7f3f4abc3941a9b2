"""The MLP of SPEC section 5 and the clamped Softplus(beta) (same values and derivatives as torch's)."""

import pytest
import torch
import torch.nn.functional as F

from methods.network import ACTIVATIONS, fast_softplus, make_network

BETA = 100.0


def _points(dtype):
    g = torch.Generator().manual_seed(0)
    x = torch.cat([torch.randn(20000, generator=g, dtype=dtype) * s for s in (0.003, 0.03, 0.3, 3.0)])
    return torch.cat([x, torch.tensor([0.0, -50.0, 50.0, -0.2, 0.2, -1.0, 1.0], dtype=dtype)])


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_clamped_softplus_matches_torch_values_and_gradients(dtype):
    x = _points(dtype).requires_grad_(True)
    y_ref = F.softplus(x, beta=BETA)
    (g_ref,) = torch.autograd.grad(y_ref.sum(), x)
    y = fast_softplus(x, BETA)
    (g,) = torch.autograd.grad(y.sum(), x)
    assert (y - y_ref).abs().max().item() < 1e-6
    assert (g - g_ref).abs().max().item() < 1e-6
    # hand values: softplus_100(0) = log(2)/100, slope 1/2; far right = x, far left = 0
    assert fast_softplus(torch.tensor([0.0], dtype=dtype)).item() == pytest.approx(0.006931471805599453, rel=1e-6)
    assert fast_softplus(torch.tensor([50.0, -50.0], dtype=dtype)).tolist() == pytest.approx([50.0, 0.0], abs=1e-12)


def test_clamped_softplus_second_derivative_matches_torch():
    """create_graph double backward (the UDF loss differentiates through input gradients)."""
    x = _points(torch.float64).requires_grad_(True)
    second = []
    for f in (lambda t: F.softplus(t, beta=BETA), lambda t: fast_softplus(t, BETA)):
        (g,) = torch.autograd.grad(f(x).sum(), x, create_graph=True)
        (gg,) = torch.autograd.grad(g.sum(), x)
        second.append(gg)
    # beta sigmoid'(beta x) peaks at beta / 4 = 25: compare relative to that scale
    assert (second[0] - second[1]).abs().max().item() < 1e-6 * BETA


def test_paper_network_shape_and_parameter_count():
    net = make_network(3, 1)  # paper defaults: 9 linear layers, width 512, Softplus(100)
    linears = [m for m in net.modules() if isinstance(m, torch.nn.Linear)]
    assert len(linears) == 9
    assert [(l.in_features, l.out_features) for l in linears] == [(3, 512)] + [(512, 512)] * 7 + [(512, 1)]
    n = sum(p.numel() for p in net.parameters())
    assert n == (3 * 512 + 512) + 7 * (512 * 512 + 512) + (512 + 1)
    acts = [m for m in net.modules() if isinstance(m, torch.nn.Softplus)]
    assert len(acts) == 8 and acts[0].beta == 100
    assert net(torch.zeros(5, 3)).shape == (5, 1)
    assert net.config == dict(in_dim=3, out_dim=1, depth=9, width=512, beta=100.0, activation="softplus")


def test_all_activations_agree_on_softplus_family_and_bad_config_errors():
    x = torch.linspace(-1, 1, 101)[:, None].repeat(1, 3)
    torch.manual_seed(0)
    a = make_network(3, 2, depth=3, width=16, activation="softplus")
    b = make_network(3, 2, depth=3, width=16, activation="softplus-clamped")
    b.load_state_dict(a.state_dict())
    assert torch.allclose(a(x), b(x), atol=1e-6)
    assert set(ACTIVATIONS) >= {"softplus", "softplus-clamped", "relu"}
    with pytest.raises(ValueError, match="depth"):
        make_network(3, 1, depth=1)
    with pytest.raises(ValueError, match="known: softplus"):
        make_network(3, 1, activation="tanh")

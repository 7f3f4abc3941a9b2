"""The paper's MLP, the clamped Softplus(beta) (same values and derivatives as torch's) and the
grid backbone (trilinear feature grid shared by a segment's endpoints, derivatives to second order)."""

import pytest
import torch
import torch.nn.functional as F

from methods.core.network import (ACTIVATIONS, MLP, GRID_INIT_SCALE, SEGMENT_SCALE, FeatureGrid, GridNetwork, endpoint_split,
                             StackedNetworks, fast_softplus, make_network, trilinear, value_and_input_gradient,
                             value_and_input_gradients)

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


# ---------------------------------------------------------------------------------------------
# grid backbone
# ---------------------------------------------------------------------------------------------
GRID = dict(depth=3, width=16, backbone="grid", grid_resolutions=(3, 5), grid_channels=2)


def _random_volume(R, C, seed=0, dtype=torch.float64):
    return torch.randn(R, R, R, C, generator=torch.Generator().manual_seed(seed), dtype=dtype)


def test_trilinear_hand_values_linear_fields_and_border():
    """Grid points return their own value; a linear field is reproduced exactly anywhere in the cube
    (trilinear interpolation is exact on linear functions); outside, the nearest point of the cube."""
    R = 5
    axis = torch.linspace(-1, 1, R, dtype=torch.float64)
    X, Y, Z = torch.meshgrid(axis, axis, axis, indexing="ij")
    linear = torch.stack([0.3 * X - 2.0 * Y + 0.5 * Z + 0.25, X + Y + Z], dim=-1)  # (R, R, R, 2)
    p = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [0.5, -0.5, 0.0], [0.123, -0.777, 0.951]],
                     dtype=torch.float64)
    expected = torch.stack([0.3 * p[:, 0] - 2.0 * p[:, 1] + 0.5 * p[:, 2] + 0.25, p.sum(dim=1)], dim=1)
    assert torch.allclose(trilinear(linear, p), expected, atol=1e-14)
    vol = _random_volume(R, 3)
    assert torch.equal(trilinear(vol, torch.tensor([[-0.5, 0.0, 1.0]], dtype=torch.float64))[0], vol[1, 2, 4])
    outside = torch.tensor([[1.7, -0.2, -3.0]], dtype=torch.float64)
    assert torch.equal(trilinear(vol, outside), trilinear(vol, outside.clamp(-1, 1)))


def test_trilinear_matches_grid_sample():
    """The same values as torch's grid_sample(align_corners=True, padding_mode='border'), whose x indexes
    the last volume axis: volume[i, j, k] <-> input[0, :, k, j, i]."""
    vol = _random_volume(6, 4)
    p = torch.rand(500, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 2.4 - 1.2
    ref = F.grid_sample(vol.permute(3, 2, 1, 0)[None], p.view(1, -1, 1, 1, 3), mode="bilinear",
                        padding_mode="border", align_corners=True).view(4, -1).t()
    assert torch.allclose(trilinear(vol, p), ref, atol=1e-13)


def test_trilinear_gradcheck_and_gradgradcheck():
    """First and second derivatives in the points and the grid values (float64, a 3^3 grid with 2 cells
    per axis); the points lie away from cell faces, one is outside the cube (clamped axis)."""
    vol = _random_volume(3, 2).requires_grad_(True)
    p = torch.tensor([[0.31, -0.42, 0.77], [-0.83, 0.12, -0.27], [0.55, 0.64, -0.91], [1.3, -0.36, 0.48]],
                     dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(trilinear, (vol, p))
    assert torch.autograd.gradgradcheck(trilinear, (vol, p))


def test_trilinear_volume_gradient_without_point_gradients():
    """Points that carry no gradient take the hand-written backward: the gradient in the grid values
    passes gradcheck and equals, bit for bit, the autograd path's (the points requiring grad), in
    float32 as a fit uses it; one point lies outside the cube, several share cells."""
    vol = _random_volume(3, 2).requires_grad_(True)
    p = torch.tensor([[0.31, -0.42, 0.77], [-0.83, 0.12, -0.27], [1.3, -0.36, 0.48]], dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda v: trilinear(v, p), (vol,))
    g = torch.Generator().manual_seed(2)
    vol32 = torch.randn(9, 9, 9, 4, generator=g).requires_grad_(True)
    points = torch.rand(3000, 3, generator=g) * 2.2 - 1.1
    upstream = torch.randn(3000, 4, generator=g)
    (hand,) = torch.autograd.grad(trilinear(vol32, points), vol32, upstream)
    moving = points.clone().requires_grad_(True)
    (auto,) = torch.autograd.grad(trilinear(vol32, moving), vol32, upstream)
    assert torch.equal(hand, auto)
    assert torch.equal(trilinear(vol32, points), trilinear(vol32, moving))


def test_grid_network_input_gradcheck_second_order():
    """The whole grid network (grid + Softplus head, float64): d out/d input and its derivative, as the
    SALS normals (first order) and the UDF gradient loss (second order, create_graph) use them."""
    torch.manual_seed(0)
    net = make_network(6, 2, **GRID).double()
    with torch.no_grad():  # values of order 1, so the grid's part of the derivative is not negligible
        for level in net.encoder.levels:
            level.normal_()
    x = torch.tensor([[0.31, -0.42, 0.77, 0.35, -0.40, 0.71], [-0.83, 0.12, -0.27, -0.78, 0.18, -0.33]],
                     dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(net, (x,))
    assert torch.autograd.gradgradcheck(net, (x,))


def test_grid_network_shapes_parameters_and_config():
    torch.manual_seed(0)
    points = make_network(3, 1, depth=3, width=64, backbone="grid", grid_resolutions=(16, 32, 64), grid_channels=4)
    segments = make_network(6, 2, depth=3, width=64, backbone="grid", grid_resolutions=(16, 32, 64), grid_channels=4)
    assert points(torch.zeros(7, 3)).shape == (7, 1) and segments(torch.zeros(7, 6)).shape == (7, 2)
    grid_values = (16 ** 3 + 32 ** 3 + 64 ** 3) * 4
    head = lambda n_in, n_out: (n_in * 64 + 64) + (64 * 64 + 64) + (64 * n_out + n_out)  # noqa: E731
    assert sum(p.numel() for p in points.parameters()) == grid_values + head(3 * 4 + 3, 1)
    assert sum(p.numel() for p in segments.parameters()) == grid_values + head(2 * (3 * 4 + 3) + 3, 2)  # + offset
    assert all(level.abs().max() <= GRID_INIT_SCALE for level in points.encoder.levels)
    assert segments.config == dict(backbone="grid", in_dim=6, out_dim=2, depth=3, width=64, beta=100.0,
                                   activation="softplus", grid_resolutions=(16, 32, 64), grid_channels=4)
    rebuilt = make_network(**segments.config)
    rebuilt.load_state_dict(segments.state_dict())
    x = torch.rand(50, 6) * 2 - 1
    assert torch.equal(rebuilt(x), segments(x))


def test_segments_share_one_encoder_and_swapping_u_v_swaps_the_code_blocks():
    """One FeatureGrid serves u and v: the head reads [enc(u), u, enc(v), v, (v - u) / SEGMENT_SCALE], so
    (v, u) gives the same two blocks swapped and the offset negated; the network's parameters are
    exactly that grid's and the head's."""
    torch.manual_seed(0)
    net = make_network(6, 2, **GRID)
    assert [type(m) for m in net.modules()].count(FeatureGrid) == 1
    ids = lambda module: {id(p) for p in module.parameters()}  # noqa: E731
    assert ids(net) == ids(net.encoder) | ids(net.head)
    with torch.no_grad():
        for level in net.encoder.levels:
            level.normal_()
    codes = []
    net.head.register_forward_pre_hook(lambda module, args: codes.append(args[0]))
    g = torch.Generator().manual_seed(2)
    u, v = torch.rand(10, 3, generator=g) * 2 - 1, torch.rand(10, 3, generator=g) * 2 - 1
    net(torch.cat([u, v], dim=1))
    net(torch.cat([v, u], dim=1))
    n = net.encoder.out_dim + 3
    assert codes[0].shape == (10, 2 * n + 3)
    assert torch.equal(codes[0][:, :n], torch.cat([net.encoder(u), u], dim=1))
    assert torch.equal(codes[0][:, n:2 * n], torch.cat([net.encoder(v), v], dim=1))
    assert torch.equal(codes[0][:, 2 * n:], (v - u) / SEGMENT_SCALE)
    assert torch.equal(codes[1][:, :2 * n], torch.cat([codes[0][:, n:2 * n], codes[0][:, :n]], dim=1))
    assert torch.equal(codes[1][:, 2 * n:], (u - v) / SEGMENT_SCALE)


@pytest.mark.parametrize("backbone", ["mlp", "grid"])
def test_endpoint_split_recomposes_the_segment_network(backbone):
    """tail(A(u) + B(v)) is the network's output for (u, v), in float64 to 1e-12, for both backbones
    (random grid values, so the encoder matters); points networks and foreign modules are not split."""
    torch.manual_seed(0)
    config = GRID if backbone == "grid" else dict(depth=4, width=32)
    net = make_network(6, 2, **config).double()
    with torch.no_grad():
        for level in getattr(getattr(net, "encoder", None), "levels", []):
            level.normal_()
    split = endpoint_split(net)
    g = torch.Generator().manual_seed(1)
    u, v = (torch.rand(500, 3, generator=g, dtype=torch.float64) * 2.2 - 1.1 for _ in range(2))
    A, _ = split.terms(u)
    _, B = split.terms(v)
    with torch.no_grad():
        torch.testing.assert_close(split.tail(A + B), net(torch.cat([u, v], dim=1)), rtol=0, atol=1e-12)
    assert endpoint_split(make_network(3, 1, **config)) is None
    assert endpoint_split(torch.nn.Linear(6, 2)) is None


def test_backbone_errors():
    with pytest.raises(ValueError, match="unknown backbone 'hash'; known: mlp, grid"):
        make_network(3, 1, backbone="hash")
    with pytest.raises(ValueError, match="not of 'mlp'"):
        make_network(3, 1, grid_channels=4)
    with pytest.raises(ValueError, match="needs grid_resolutions and grid_channels"):
        make_network(3, 1, backbone="grid", grid_channels=4)
    with pytest.raises(ValueError, match="in_dim 3, 6"):
        make_network(4, 1, **GRID)
    with pytest.raises(ValueError, match=">= 2 points per axis"):
        FeatureGrid((1, 4), 2)
    with pytest.raises(ValueError, match="channels must be >= 1"):
        FeatureGrid((4,), 0)
    assert isinstance(make_network(3, 1, **GRID), GridNetwork)


def test_stacked_networks_are_independent_members_on_their_inputs():
    """A stack's outputs are its members' side by side, each on the input with its zeroed columns
    set to 0 (so constant along them); the members share no parameter, a member's loss moves only
    its own weights; the config rebuilds the stack, and the stack's errors are one line each."""
    torch.manual_seed(0)
    members = [dict(GRID, out_dim=1), dict(depth=2, width=8, out_dim=2), dict(GRID, out_dim=1)]
    net = make_network(3, 4, backbone="stack", members=members, zeroed=[[], [1], [0, 2]])
    assert isinstance(net, StackedNetworks) and len(net.nets) == 3
    x = torch.rand(40, 3) * 2 - 1
    out = net(x)
    assert out.shape == (40, 4)
    assert torch.equal(out[:, 0:1], net.nets[0](x))
    assert torch.equal(out[:, 1:3], net.nets[1](x * torch.tensor([1.0, 0.0, 1.0])))
    moved = x + torch.tensor([0.3, -0.2, 0.5])  # member 2 sees y only: moving x and z changes nothing
    assert torch.equal(net(x * torch.tensor([0.0, 1.0, 0.0]) + moved * torch.tensor([1.0, 0.0, 1.0]))[:, 3], out[:, 3])
    ids = [{id(p) for p in m.parameters()} for m in net.nets]
    assert not (ids[0] & ids[1]) and not (ids[0] & ids[2]) and not (ids[1] & ids[2])
    net.member(1, x).sum().backward()
    assert all(p.grad is None for k in (0, 2) for p in net.nets[k].parameters())
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in net.nets[1].parameters())
    assert [type(m) for m in net.modules()].count(FeatureGrid) == 2
    rebuilt = make_network(**net.config)
    rebuilt.load_state_dict(net.state_dict())
    assert torch.equal(rebuilt(x), out) and net.config["members"][1] == dict(depth=2, width=8, beta=100.0,
                                                                             activation="softplus", out_dim=2)
    with pytest.raises(ValueError, match="sum to 4, not 3"):
        make_network(3, 3, backbone="stack", members=members)
    with pytest.raises(ValueError, match="zeroed columns must lie in"):
        make_network(3, 4, backbone="stack", members=members, zeroed=[[], [3], []])
    with pytest.raises(ValueError, match="needs members"):
        make_network(3, 4, backbone="stack")
    with pytest.raises(ValueError, match="not of 'grid'"):
        make_network(3, 1, members=members, **GRID)


def _input_gradient_loss(out, grad):
    weights = torch.tensor([0.3, -1.0, 0.5, 0.7, 0.2, -0.4], dtype=grad.dtype)[:grad.shape[1]]
    return (out ** 2).sum() + (grad * weights).sum() + (grad ** 2).sum()


@pytest.mark.parametrize("in_dim", [3, 6])
def test_value_and_input_gradient_of_a_grid_network_matches_autograd(in_dim):
    """The grid network's analytic path (grid Jacobian x head's autograd gradient) gives the outputs,
    the input gradient and the weights' gradient of a loss on that gradient as float64 autograd
    does, to float32 rounding, for points and for segments (whose offset enters the head too);
    points on every side of the cube, grid values of size 0.3."""
    torch.manual_seed(0)
    config = dict(depth=3, width=64, beta=BETA, backbone="grid", grid_resolutions=(4, 16), grid_channels=4)
    model = make_network(in_dim, 2, **config)
    with torch.no_grad():
        for level in model.encoder.levels:
            level.uniform_(-0.3, 0.3)
    x = torch.rand(3000, 3, generator=torch.Generator().manual_seed(1)) * 2.4 - 1.2
    if in_dim == 6:  # segments of length ~0.02 around those points
        x = torch.cat([x, x + 0.02 * torch.randn(3000, 3, generator=torch.Generator().manual_seed(2))], dim=1)
    assert not value_and_input_gradient(model, x, output_index=1, create_graph=False)[1].requires_grad
    out, grad = value_and_input_gradient(model, x, output_index=1)
    _input_gradient_loss(out, grad).backward()
    ours = [p.grad.clone() for p in model.parameters()]

    reference = make_network(in_dim, 2, **config).double()
    reference.load_state_dict({k: v.double() for k, v in model.state_dict().items()})
    x64 = x.double().requires_grad_(True)
    out64 = reference(x64)
    (grad64,) = torch.autograd.grad(out64[:, 1].sum(), x64, create_graph=True)
    _input_gradient_loss(out64, grad64).backward()
    assert torch.allclose(out.double(), out64, atol=1e-6)
    assert torch.allclose(grad.double(), grad64, atol=1e-5 * grad64.abs().max().item())
    for mine, p in zip(ours, reference.parameters()):
        assert torch.allclose(mine.double(), p.grad, atol=1e-5 * p.grad.abs().max().item())


@pytest.mark.parametrize("backbone", ["grid", "mlp"])
def test_value_and_input_gradients_of_several_outputs_equal_one_at_a_time(backbone):
    """The gradients of outputs 2, 0 (in that order) from one evaluation are, bit for bit, those
    of each output asked alone, and a loss on the outputs and both gradients back-propagates into
    the weights as the sum of the separate losses."""
    torch.manual_seed(0)
    grid = dict(grid_resolutions=(4, 8), grid_channels=2) if backbone == "grid" else {}
    model = make_network(3, 3, depth=3, width=32, beta=BETA, backbone=backbone, **grid)
    x = torch.rand(500, 3, generator=torch.Generator().manual_seed(3)) * 2 - 1
    out, (g2, g0) = value_and_input_gradients(model, x, (2, 0))
    for index, grad in ((2, g2), (0, g0)):
        alone_out, alone = value_and_input_gradient(model, x, index)
        assert torch.equal(out, alone_out) and torch.equal(grad, alone)
    (out.square().sum() + g2.square().sum() + g0.square().sum()).backward()
    together = [p.grad.clone() for p in model.parameters()]
    model.zero_grad()
    model(x).square().sum().backward()
    for index in (2, 0):
        value_and_input_gradient(model, x, index)[1].square().sum().backward()
    for mine, p in zip(together, model.parameters()):
        assert torch.allclose(mine, p.grad, atol=1e-6 * p.grad.abs().max().item())


def test_value_and_input_gradient_of_a_plain_mlp_is_the_closed_form_and_of_other_networks_autograd():
    """A Softplus MLP is differentiated by the closed form (autograd's numbers to float32 rounding,
    without a graph unless asked); a grid network on float64 by autograd (the same numbers)."""
    torch.manual_seed(0)
    mlp = make_network(3, 1, depth=3, width=32, beta=BETA)
    x = torch.rand(100, 3, generator=torch.Generator().manual_seed(2)) * 2 - 1
    out, grad = value_and_input_gradient(mlp, x, create_graph=False)
    xr = x.clone().requires_grad_(True)
    (ref,) = torch.autograd.grad(mlp(xr)[:, 0].sum(), xr)
    assert torch.equal(out, mlp(x)) and not grad.requires_grad
    torch.testing.assert_close(grad, ref, rtol=1e-5, atol=1e-6 * ref.abs().max().item())
    grid64 = make_network(3, 1, depth=3, width=32, beta=BETA, backbone="grid", grid_resolutions=(4,),
                          grid_channels=2).double()
    x64 = x.double().requires_grad_(True)
    (ref64,) = torch.autograd.grad(grid64(x64)[:, 0].sum(), x64)
    assert torch.equal(value_and_input_gradient(grid64, x.double(), create_graph=False)[1], ref64)


def test_under_bfloat16_autocast_the_input_layer_keeps_float32_and_the_rest_runs_in_bfloat16():
    torch.manual_seed(0)
    net = MLP(3, 1, depth=3, width=16)
    x = torch.tensor([[0.5009, -0.2503, 0.9994]])  # coordinates bfloat16 would round by up to 0.004
    seen = []
    net.layers[1].register_forward_hook(lambda module, inputs, output: seen.append(inputs[0]))
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = net(x)
    assert seen[0].dtype == torch.float32 and out.dtype == torch.bfloat16
    torch.testing.assert_close(seen[0], net.layers[0](x), rtol=0, atol=0)  # the float32 input layer, bit for bit
    with torch.autocast("cpu", dtype=torch.bfloat16):
        rounded = net.layers[0](x)  # what autocast alone would give: bfloat16
    assert rounded.dtype == torch.bfloat16 and not torch.equal(rounded.float(), seen[0])
    seen.clear()
    net(x)  # outside autocast: plain float32 all through
    assert net(x).dtype == torch.float32

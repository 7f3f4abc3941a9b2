"""The compiled feature-grid lookup: torch's numbers (values bit for bit where torch's kernels have FMA,
gradients bit for bit everywhere), and its Jacobian and adjoint against autograd in float64."""

import pytest
import torch

from methods.core import grid_lookup
from methods.core.network import trilinear

#: torch's lerp uses a fused multiply-add on these CPU kernels; on the scalar kernels it need not.
TORCH_LERP_FUSED = torch.backends.cpu.get_cpu_capability() != "DEFAULT"


def _levels(resolutions, channels=4, seed=0, scale=1.0):
    g = torch.Generator().manual_seed(seed)
    return [((torch.rand(R, R, R, channels, generator=g) * 2 - 1) * scale).requires_grad_(True) for R in resolutions]


def _points(n=3000, seed=1):
    """Random points in [-1.1, 1.1]^3 (some outside the cube on some axis), plus the cube's corners,
    faces and cell boundaries of every level used here."""
    g = torch.Generator().manual_seed(seed)
    special = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [1.0, -0.5, 0.0], [0.0, 0.0, 0.0],
                            [-1.3, 0.2, 1.7], [2.0 / 15.0 - 1.0, 1.0 / 3.0, -1.0 / 3.0]])
    return torch.cat([torch.rand(n, 3, generator=g) * 2.2 - 1.1, special])


def test_lookup_equals_torch_trilinear():
    levels, points = _levels((2, 5, 16, 31)), _points()
    with torch.no_grad():
        ours = grid_lookup.lookup(levels, points)
        ref = torch.cat([trilinear(level, points) for level in levels], dim=1)
        ref64 = torch.cat([trilinear(level.double(), points.double()) for level in levels], dim=1)
    assert ours.shape == (len(points), 16)
    # float32 rounding of the cell coordinate (up to 15 cells x 1.2e-7) times feature slopes up to 2 a cell
    assert torch.allclose(ours.double(), ref64, rtol=0, atol=1e-5)
    if TORCH_LERP_FUSED:
        assert torch.equal(ours, ref)
    else:
        assert torch.allclose(ours, ref, rtol=0, atol=4e-7)


def test_lookup_gradient_equals_torch_bit_for_bit():
    """The adjoint adds the same products in the same order as the torch path's ``index_add_``; many
    points share cells, and some lie outside the cube."""
    levels, points = _levels((3, 8, 16)), _points(5000)
    upstream = torch.randn(len(points), 12, generator=torch.Generator().manual_seed(3))
    grid_lookup.lookup(levels, points).backward(upstream)
    ours = [level.grad.clone() for level in levels]
    for level in levels:
        level.grad = None
    torch.cat([trilinear(level, points) for level in levels], dim=1).backward(upstream)
    for mine, theirs in zip(ours, (level.grad for level in levels)):
        assert torch.equal(mine, theirs)


def test_lookup_hand_values():
    """A grid point returns its own feature; the centre of a 2^3 grid the mean of its 8 corners;
    outside the cube the value at the nearest point of the cube."""
    level = torch.arange(8 * 2, dtype=torch.float32).reshape(2, 2, 2, 2)
    values = grid_lookup.lookup([level], torch.tensor([[-1.0, 1.0, -1.0], [0.0, 0.0, 0.0], [3.0, 1.0, -7.0]]))
    assert values[0].tolist() == level[0, 1, 0].tolist()
    assert values[1].tolist() == level.reshape(8, 2).mean(dim=0).tolist()
    assert values[2].tolist() == level[1, 1, 0].tolist()


def test_jacobian_of_a_linear_field_and_outside_the_cube():
    """Trilinear interpolation reproduces a linear field, so its Jacobian is the field's matrix inside
    the cube; along an axis on which a point lies outside, the coordinate is clamped: derivative 0."""
    R = 9
    axis = torch.linspace(-1, 1, R)
    X, Y, Z = torch.meshgrid(axis, axis, axis, indexing="ij")
    A = torch.tensor([[0.3, -2.0, 0.5], [1.0, 1.0, 1.0]])
    level = torch.stack([A[0, 0] * X + A[0, 1] * Y + A[0, 2] * Z + 0.25, X + Y + Z], dim=-1)
    inside = torch.rand(200, 3, generator=torch.Generator().manual_seed(4)) * 1.98 - 0.99
    values, jac = grid_lookup.lookup_with_jacobian([level], inside)
    assert torch.allclose(values, inside @ A.T + torch.tensor([0.25, 0.0]), atol=1e-6)
    assert torch.allclose(jac, A.expand(200, 2, 3), atol=1e-5)
    assert torch.equal(values, grid_lookup.lookup([level], inside))
    outside = torch.tensor([[1.5, 0.2, -0.3], [0.1, -1.2, 0.4], [-2.0, 3.0, 0.5]])
    jac_out = grid_lookup.lookup_with_jacobian([level], outside)[1]
    expected = A.expand(3, 2, 3).clone()
    expected[0, :, 0] = expected[1, :, 1] = 0.0
    expected[2, :, :2] = 0.0
    assert torch.allclose(jac_out, expected, atol=1e-5)


def test_jacobian_and_its_adjoint_match_autograd():
    """Values, Jacobian, and the gradient in the levels of a loss on both, against autograd of the
    float64 torch lookup (points away from cell faces: the Jacobian jumps there)."""
    levels = _levels((4, 7), channels=3, seed=5)
    g = torch.Generator().manual_seed(6)
    points = torch.rand(400, 3, generator=g) * 2.4 - 1.2
    values, jac = grid_lookup.lookup_with_jacobian(levels, points)
    up_values, up_jac = torch.randn(400, 6, generator=g), torch.randn(400, 6, 3, generator=g)
    ((values * up_values).sum() + (jac * up_jac).sum()).backward()
    ours = [level.grad.clone() for level in levels]

    levels64 = [level.detach().double().requires_grad_(True) for level in levels]
    p64 = points.double().requires_grad_(True)
    ref_values = torch.cat([trilinear(level, p64) for level in levels64], dim=1)
    ref_jac = torch.stack([torch.autograd.grad(ref_values[:, j].sum(), p64, create_graph=True)[0]
                           for j in range(6)], dim=1)
    assert torch.allclose(values.double(), ref_values, atol=1e-6)
    assert torch.allclose(jac.double(), ref_jac, atol=2e-5)
    ((ref_values * up_values.double()).sum() + (ref_jac * up_jac.double()).sum()).backward()
    for mine, level in zip(ours, levels64):
        assert torch.allclose(mine.double(), level.grad, atol=1e-4, rtol=1e-5)


def test_lookup_refuses_what_it_does_not_serve():
    levels = _levels((4,))
    with pytest.raises(ValueError, match="float32 CPU"):
        grid_lookup.lookup(levels, _points(10).double())
    with pytest.raises(ValueError, match="without a gradient"):
        grid_lookup.lookup(levels, _points(10).requires_grad_(True))
    assert not grid_lookup.applies([level.double() for level in levels], _points(10))

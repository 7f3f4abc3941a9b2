"""The closed-form input gradient of a Softplus MLP (methods.core.head_gradient) against autograd:
values, the gradient, and the derivatives of a loss on both in every weight and in the input."""

import pytest
import torch

from methods.core.head_gradient import value_and_input_gradients


def _mlp(widths, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    weights = [(torch.randn(o, i, generator=g, dtype=dtype) / i ** 0.5).requires_grad_(True)
               for i, o in zip(widths[:-1], widths[1:])]
    biases = [(0.1 * torch.randn(o, generator=g, dtype=dtype)).requires_grad_(True) for o in widths[1:]]
    return weights, biases


def _autograd(weights, biases, beta, x, indices):
    """The same MLP through torch's layers, its input gradients by autograd with create_graph."""
    x = x.detach().requires_grad_(True)
    a = x
    for W, b in zip(weights[:-1], biases[:-1]):
        a = torch.nn.functional.softplus(torch.nn.functional.linear(a, W, b), beta)
    out = torch.nn.functional.linear(a, weights[-1], biases[-1])
    grads = [torch.autograd.grad(out[:, k].sum(), x, create_graph=True)[0] for k in indices]
    return out, grads, x


@pytest.mark.parametrize("widths,indices", [((3, 16, 1), (0,)), ((15, 32, 32, 1), (0,)),
                                            ((6, 24, 24, 24, 3), (2, 0))])
def test_values_gradients_and_second_derivatives_equal_autograds(widths, indices):
    """Depths 2-4, one or two outputs, beta 100 on inputs that put units on both sides of the
    Softplus knee: the outputs, the input gradients, and the gradients of a loss on all of them
    in every weight, bias and the input, equal float64 autograd's to 1e-12."""
    weights, biases = _mlp(widths)
    x = 0.05 * torch.randn(64, widths[0], generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    x.requires_grad_(True)
    out, grads = value_and_input_gradients(weights, biases, 100.0, x, indices)
    loss = out.square().sum() + sum((g * torch.linspace(-1, 1, g.shape[1], dtype=g.dtype)).sin().sum() for g in grads)
    mine = torch.autograd.grad(loss, [x, *weights, *biases])
    ref_out, ref_grads, xr = _autograd(weights, biases, 100.0, x, indices)
    ref_loss = ref_out.square().sum() + sum((g * torch.linspace(-1, 1, g.shape[1], dtype=g.dtype)).sin().sum()
                                            for g in ref_grads)
    ref = torch.autograd.grad(ref_loss, [xr, *weights, *biases])
    torch.testing.assert_close(out, ref_out, rtol=1e-12, atol=1e-12)
    for g, r in zip(grads, ref_grads):
        torch.testing.assert_close(g, r, rtol=1e-12, atol=1e-12)
    for m, r in zip(mine, ref):
        torch.testing.assert_close(m, r, rtol=1e-10, atol=1e-12)


def test_gradcheck_of_the_written_backward():
    """torch.autograd.gradcheck: the written backward is the Jacobian of the forward (finite
    differences in float64), for the input and every parameter, through both outputs."""
    weights, biases = _mlp((4, 8, 8, 2), seed=3)
    x = 0.02 * torch.randn(5, 4, generator=torch.Generator().manual_seed(4), dtype=torch.float64)

    def f(x, *params):
        out, grads = value_and_input_gradients(params[0::2], params[1::2], 50.0, x, (1, 0))
        return (out, *grads)

    params = [p for pair in zip(weights, biases) for p in pair]
    assert torch.autograd.gradcheck(f, (x.requires_grad_(True), *params), eps=1e-6, atol=1e-6)


def test_an_outputs_gradient_is_the_same_bits_alone_or_with_others():
    weights, biases = _mlp((5, 16, 16, 3), dtype=torch.float32)
    x = torch.randn(50, 5, generator=torch.Generator().manual_seed(2))
    out, (g2, g0) = value_and_input_gradients(weights, biases, 100.0, x, (2, 0))
    out0, (alone,) = value_and_input_gradients(weights, biases, 100.0, x, (0,))
    assert torch.equal(out, out0) and torch.equal(g0, alone)


def test_one_bias_per_weight_is_required():
    weights, biases = _mlp((3, 4, 1))
    with pytest.raises(ValueError, match="one bias per weight"):
        value_and_input_gradients(weights, biases[:1], 100.0, torch.zeros(2, 3, dtype=torch.float64), (0,))

"""A Softplus MLP's output and its input gradient, with the derivative of both in the weights
written out (no double backward through autograd).

For an :class:`methods.core.network.MLP` with Softplus(beta) activations,

    z_i = a_{i-1} W_i^T + b_i,   a_i = sp(z_i)  (i < L),   f = z_L,   a_0 = x,

the gradient of an output k in the input is a backward chain of the same products,

    c_L = W_L[k],   q_i = c_{i+1} * s_i,   c_i = q_i W_i  (i = L-1, ..., 1),   df_k/dx = c_1,

with ``s_i = sp'(z_i) = sigmoid(beta z_i)`` (1 where torch's Softplus turns linear, beta z_i >
20). :func:`value_and_input_gradients` returns ``(f, c_1)`` (a c_1 per output asked) and its
backward, given the adjoints of f and of c_1, returns those of x, every W_i and every b_i:
the adjoint r_i of c_i runs forward through the chain (``dW_i += q_i^T r_i``, ``r_{i+1} = (r_i
W_i^T) s_i``), each ``s_i`` passes ``(r_i W_i^T) c_{i+1} beta s_i (1 - s_i)`` on to z_i, and the
usual backward of the forward pass carries it down with f's adjoint. This is what autograd computes
from ``torch.autograd.grad(f, x, create_graph=True)``, in fewer and larger operations: two
products per layer forward (the value and the chain) and four backward, with no graph of the
Softplus derivative's own derivative. The same function to float rounding (tests/test_head_gradient.py).
"""

from __future__ import annotations

from typing import Sequence

import torch

#: torch's Softplus threshold: sp(z) = z where beta z exceeds it (the networks' Softplus).
SOFTPLUS_THRESHOLD = 20.0


class _ValueAndInputGradients(torch.autograd.Function):

    @staticmethod
    def forward(ctx, x, beta: float, indices: tuple[int, ...], *parameters):
        weights, biases = parameters[0::2], parameters[1::2]
        activations, slopes, curvatures = [x], [], []
        a = x
        for W, b in zip(weights[:-1], biases[:-1]):
            z = torch.addmm(b, a, W.t())
            s = torch.sigmoid(z * beta)
            if s.dtype != torch.float32:  # float32's sigmoid is 1 there already
                s.masked_fill_(z * beta > SOFTPLUS_THRESHOLD, 1.0)
            slopes.append(s)
            curvatures.append(torch.addcmul(s, s, s, value=-1.0).mul_(beta))  # d s / d z = beta s (1 - s)
            a = torch.nn.functional.softplus(z, beta, SOFTPLUS_THRESHOLD)
            activations.append(a)
        out = torch.addmm(biases[-1], a, weights[-1].t())
        chains, products = [], []
        for index in indices:
            chain, product = [weights[-1][index:index + 1]], []  # the gradient in the last hidden layer, every row
            for W, s in zip(reversed(weights[:-1]), reversed(slopes)):
                product.append(chain[-1] * s)
                chain.append(torch.mm(product[-1], W))
            chains.append(chain[::-1])  # chain[i]: the gradient of the output in the input of layer i
            products.append(product[::-1])  # product[i] = chain[i + 1] s_i
        ctx.beta, ctx.indices, ctx.layers = beta, indices, len(weights)
        ctx.save_for_backward(*weights, *activations, *slopes, *curvatures,
                              *(c for chain in chains for c in chain), *(q for product in products for q in product))
        return (out, *(chain[0] for chain in chains))

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_out, *grad_gradients):
        L, n = ctx.layers, len(ctx.indices)
        saved = list(ctx.saved_tensors)
        weights, activations = saved[:L], saved[L:2 * L]
        slopes, curvatures = saved[2 * L:3 * L - 1], saved[3 * L - 1:4 * L - 2]
        rest = saved[4 * L - 2:]
        chains = [rest[j * L:(j + 1) * L] for j in range(n)]
        products = [rest[n * L + j * (L - 1):n * L + (j + 1) * (L - 1)] for j in range(n)]
        grad_w: list = [None] * L
        extra_z: list = [None] * (L - 1)  # what each slope s_i passes on to z_i
        top = torch.zeros_like(weights[-1])
        for index, chain, product, r in zip(ctx.indices, chains, products, grad_gradients):
            if r is None:
                continue
            for i in range(L - 1):  # the chain, input side first: r is the adjoint of chain[i]
                grad_w[i] = _add(grad_w[i], torch.mm(product[i].t(), r))
                dq = torch.mm(r, weights[i].t())
                extra_z[i] = _add(extra_z[i], torch.mul(dq, chain[i + 1]).mul_(curvatures[i]))
                r = dq.mul_(slopes[i])
            top[index] += r.sum(dim=0)
        grad_w[-1] = top
        dz = grad_out if grad_out is not None else top.new_zeros(activations[-1].shape[0], weights[-1].shape[0])
        grad_b: list = [None] * L
        grad_x = None
        for i in reversed(range(L)):  # the forward pass's backward, output side first
            grad_w[i] = torch.mm(dz.t(), activations[i]) if grad_w[i] is None \
                else torch.addmm(grad_w[i], dz.t(), activations[i])
            grad_b[i] = dz.sum(dim=0)
            da = torch.mm(dz, weights[i])
            if i == 0:
                grad_x = da
            elif extra_z[i - 1] is None:
                dz = da.mul_(slopes[i - 1])
            else:
                dz = torch.addcmul(extra_z[i - 1], da, slopes[i - 1])
        return (grad_x, None, None, *[g for pair in zip(grad_w, grad_b) for g in pair])


def _add(a: torch.Tensor | None, b: torch.Tensor | None) -> torch.Tensor | None:
    return b if a is None else a if b is None else a + b


def value_and_input_gradients(weights: Sequence[torch.Tensor], biases: Sequence[torch.Tensor], beta: float,
                              x: torch.Tensor, indices: Sequence[int]) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """A Softplus MLP's outputs and the gradients of some outputs in its input.

    Parameters
    ----------
    weights, biases : the linear layers' ``weight`` (out, in) and ``bias`` (out,), input side first;
        a Softplus(``beta``, threshold :data:`SOFTPLUS_THRESHOLD`) follows every layer but the last.
    x : (B, in) inputs.
    indices : the outputs whose gradients are returned, in this order.

    Returns
    -------
    ``(f (B, out), [df[:, i]/dx (B, in) for i in indices])``, all differentiable (once) in ``x``
    and every weight and bias, by the backward written out in the module docstring; float32 also
    under a bfloat16 autocast (a fit's ``precision``: this network is then fitted in float32). An output's
    gradient is the same, bit for bit, whichever other outputs are asked with it.
    """
    if len(weights) != len(biases) or not weights:
        raise ValueError(f"one bias per weight, at least one layer: got {len(weights)} weights, {len(biases)} biases")
    parameters = [p for pair in zip(weights, biases) for p in pair]
    with torch.autocast(device_type=x.device.type, enabled=False):  # its backward is float32: so is its forward
        out, *grads = _ValueAndInputGradients.apply(x, float(beta), tuple(int(i) for i in indices),
                                                    *parameters)
    return out, grads

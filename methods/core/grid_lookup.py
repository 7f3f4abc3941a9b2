"""Trilinear lookup of dense feature grids on the CPU, and its adjoint, as compiled loops (numba).

One pass over the points reads each point's 8 corner rows of a level and interpolates them; the
adjoint adds each point's 8 weighted gradient rows into a zeroed gradient of the level. These are
the operations of :func:`methods.core.network.trilinear` (a gather, a lerp along x, y and z; an
``index_add_`` of the weighted rows), without the dozens of tensor operations, temporaries and
autograd nodes a lookup costs in torch.

The same numbers as torch, bit for bit, on every CPU whose torch kernels have FMA (AVX2 and up):

* a lerp is ``fma(w, b - a, a)`` for ``|w| < 1/2`` and ``fma(w - 1, b - a, b)`` otherwise, the
  formula of ATen's CPU lerp (its ``is_lerp_weight_small`` branch), with a fused multiply-add;
* a corner's weight multiplies the gradient in autograd's order, ``((g w_z) w_y) w_x``, and the
  products are added in point order, corner order (x, y, z bits), as ``index_add_`` adds them.

On a CPU without FMA the fused multiply-add is computed exactly in software (slower, same numbers).

Frames and units: a level is a (R, R, R, C) volume of points on the cube [-1, 1]^3, corners on its
faces (``level[i, j, k]`` at ``-1 + 2 (i, j, k) / (R - 1)``); points outside the cube take the
value at the nearest point of the cube, as ``grid_sample(..., align_corners=True,
padding_mode='border')``.
"""

from __future__ import annotations

from typing import Sequence

import numba
import numpy as np
import torch
from numba.extending import intrinsic

_ONE = np.float32(1.0)
_HALF = np.float32(0.5)
_ZERO = np.float32(0.0)


@intrinsic
def _fma(typingctx, a, b, c):
    """``a * b + c`` with one rounding (LLVM's ``llvm.fma``)."""
    def codegen(context, builder, signature, args):
        return builder.fma(*args)
    return a(a, b, c), codegen


@numba.njit(inline="always")
def _lerp(a, b, w):
    if abs(w) < _HALF:
        return _fma(w, b - a, a)
    return _fma(w - _ONE, b - a, b)


@numba.njit(inline="always")
def _cell(x, y, z, R):
    """The cell of a point (its lowest corner's row in the flattened level) and its fractional
    coordinates in that cell, in float32 as :func:`methods.core.network.trilinear` computes them."""
    scale, top, last = np.float32(0.5 * (R - 1)), np.float32(R - 1), np.float32(R - 2)
    tx = min(max((x + _ONE) * scale, _ZERO), top)
    ty = min(max((y + _ONE) * scale, _ZERO), top)
    tz = min(max((z + _ONE) * scale, _ZERO), top)
    cx, cy, cz = min(np.floor(tx), last), min(np.floor(ty), last), min(np.floor(tz), last)
    row = (np.int64(cx) * R + np.int64(cy)) * R + np.int64(cz)
    return row, tx - cx, ty - cy, tz - cz


@numba.njit(cache=True, boundscheck=False)
def _lookup(points, level, R, out, column):
    """out[:, column:column + C] = trilinear lookup of ``level`` ((R^3, C) rows) at ``points`` (P, 3)."""
    C, plane = level.shape[1], R * R
    for p in range(points.shape[0]):
        row, fx, fy, fz = _cell(points[p, 0], points[p, 1], points[p, 2], R)
        for c in range(C):
            x00 = _lerp(level[row, c], level[row + plane, c], fx)
            x01 = _lerp(level[row + 1, c], level[row + plane + 1, c], fx)
            x10 = _lerp(level[row + R, c], level[row + plane + R, c], fx)
            x11 = _lerp(level[row + R + 1, c], level[row + plane + R + 1, c], fx)
            out[p, column + c] = _lerp(_lerp(x00, x10, fy), _lerp(x01, x11, fy), fz)


@numba.njit(cache=True, boundscheck=False)
def _lookup_adjoint(points, grad, R, column, level_grad):
    """level_grad ((R^3, C) rows, zeroed) += the adjoint of :func:`_lookup` applied to
    grad[:, column:column + C]."""
    C = level_grad.shape[1]
    for p in range(points.shape[0]):
        row, fx, fy, fz = _cell(points[p, 0], points[p, 1], points[p, 2], R)
        for a in range(2):
            wx = fx if a else _ONE - fx
            for b in range(2):
                wy = fy if b else _ONE - fy
                for d in range(2):
                    wz = fz if d else _ONE - fz
                    corner = row + (a * R + b) * R + d
                    for c in range(C):
                        level_grad[corner, c] += ((grad[p, column + c] * wz) * wy) * wx


@numba.njit(cache=True, boundscheck=False)
def _lookup_with_jacobian(points, level, R, out, jac, column):
    """:func:`_lookup` into ``out`` and the derivative of each feature along x, y, z into
    ``jac[:, column:column + C, :]`` (per unit of the cube's coordinates; 0 along an axis where the
    point lies outside the cube, whose coordinate is clamped)."""
    C, plane = level.shape[1], R * R
    scale, top = np.float32(0.5 * (R - 1)), np.float32(R - 1)
    for p in range(points.shape[0]):
        x, y, z = points[p, 0], points[p, 1], points[p, 2]
        row, fx, fy, fz = _cell(x, y, z, R)
        sx, sy, sz = _inside(x, scale, top), _inside(y, scale, top), _inside(z, scale, top)
        for c in range(C):
            v000, v100 = level[row, c], level[row + plane, c]
            v001, v101 = level[row + 1, c], level[row + plane + 1, c]
            v010, v110 = level[row + R, c], level[row + plane + R, c]
            v011, v111 = level[row + R + 1, c], level[row + plane + R + 1, c]
            x00, x01 = _lerp(v000, v100, fx), _lerp(v001, v101, fx)
            x10, x11 = _lerp(v010, v110, fx), _lerp(v011, v111, fx)
            y0, y1 = _lerp(x00, x10, fy), _lerp(x01, x11, fy)
            out[p, column + c] = _lerp(y0, y1, fz)
            dx0 = _lerp(v100 - v000, v110 - v010, fy)
            dx1 = _lerp(v101 - v001, v111 - v011, fy)
            jac[p, column + c, 0] = sx * _lerp(dx0, dx1, fz)
            jac[p, column + c, 1] = sy * _lerp(x10 - x00, x11 - x01, fz)
            jac[p, column + c, 2] = sz * (y1 - y0)


@numba.njit(inline="always")
def _inside(x, scale, top):
    """d(cell coordinate)/dx: ``scale`` inside the cube (faces included), 0 where it is clamped."""
    t = (x + _ONE) * scale
    return scale if (t >= _ZERO and t <= top) else _ZERO


@numba.njit(cache=True, boundscheck=False)
def _lookup_with_jacobian_adjoint(points, grad, grad_jac, R, column, level_grad):
    """level_grad ((R^3, C) rows, zeroed) += the adjoint of :func:`_lookup_with_jacobian` applied to
    ``grad[:, column:column + C]`` and ``grad_jac[:, column:column + C, :]``."""
    C = level_grad.shape[1]
    scale, top = np.float32(0.5 * (R - 1)), np.float32(R - 1)
    for p in range(points.shape[0]):
        x, y, z = points[p, 0], points[p, 1], points[p, 2]
        row, fx, fy, fz = _cell(x, y, z, R)
        sx, sy, sz = _inside(x, scale, top), _inside(y, scale, top), _inside(z, scale, top)
        for a in range(2):
            wx, dwx = (fx, _ONE) if a else (_ONE - fx, -_ONE)
            for b in range(2):
                wy, dwy = (fy, _ONE) if b else (_ONE - fy, -_ONE)
                for d in range(2):
                    wz, dwz = (fz, _ONE) if d else (_ONE - fz, -_ONE)
                    corner = row + (a * R + b) * R + d
                    w, wdx, wdy, wdz = wx * wy * wz, sx * dwx * wy * wz, sy * wx * dwy * wz, sz * wx * wy * dwz
                    for c in range(C):
                        level_grad[corner, c] += (grad[p, column + c] * w + grad_jac[p, column + c, 0] * wdx
                                                  + grad_jac[p, column + c, 1] * wdy + grad_jac[p, column + c, 2] * wdz)


def applies(levels: Sequence[torch.Tensor], points: torch.Tensor) -> bool:
    """Whether :func:`lookup` serves these tensors: float32 on the CPU, points without a gradient
    (a loss that differentiates the points takes torch's path, differentiable to any order)."""
    return (points.device.type == "cpu" and points.dtype == torch.float32 and not points.requires_grad
            and all(level.device.type == "cpu" and level.dtype == torch.float32 for level in levels))


def _rows(level: torch.Tensor) -> np.ndarray:
    """A (R, R, R, C) level as its (R^3, C) float32 rows (a view where the level is contiguous)."""
    R, C = level.shape[0], level.shape[-1]
    return level.detach().contiguous().reshape(R * R * R, C).numpy()


def _level_gradients(ctx, adjoint) -> tuple:
    """The backward's gradients of ``(points, *levels)``: None for the points and for each level
    autograd does not need; for the others a zeroed level filled by ``adjoint(R, column, rows)``
    (``column`` is the level's first feature in the concatenated output)."""
    grads, column = [None], 0
    for shape, wanted in zip(ctx.shapes, ctx.needs_input_grad[1:]):
        level_grad = None
        if wanted:
            level_grad = torch.zeros(shape, dtype=torch.float32)
            adjoint(shape[0], column, _rows(level_grad))
        grads.append(level_grad)
        column += shape[-1]
    return tuple(grads)


class _Lookup(torch.autograd.Function):

    @staticmethod
    def forward(ctx, points, *levels):
        P, C = points.shape[0], levels[0].shape[-1]
        out = torch.empty(P, len(levels) * C, dtype=torch.float32)
        xyz = points.detach().contiguous()
        for i, level in enumerate(levels):
            _lookup(xyz.numpy(), _rows(level), level.shape[0], out.numpy(), i * C)
        ctx.save_for_backward(xyz)
        ctx.shapes = [level.shape for level in levels]
        return out

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad):
        (xyz,) = ctx.saved_tensors
        xyz, grad = xyz.numpy(), grad.detach().numpy()
        return _level_gradients(ctx, lambda R, column, rows: _lookup_adjoint(xyz, grad, R, column, rows))


def lookup(levels: Sequence[torch.Tensor], points: torch.Tensor) -> torch.Tensor:
    """The trilinear features of every level at ``points``, concatenated: (P, 3) -> (P, L C).

    Parameters
    ----------
    levels : (R_l, R_l, R_l, C) float32 CPU tensors (any R_l >= 2, one C), differentiable.
    points : (P, 3) float32 CPU tensor of (x, y, z) in the cube's frame, without a gradient.

    The same values as ``torch.cat([methods.core.network.trilinear(level, points) for level in levels], 1)``
    and the same gradient in every level (see the module docstring); the points get no gradient.
    """
    if not applies(levels, points):
        raise ValueError("grid_lookup.lookup takes float32 CPU tensors and points without a gradient")
    return _Lookup.apply(points, *levels)


class _LookupWithJacobian(torch.autograd.Function):

    @staticmethod
    def forward(ctx, points, *levels):
        P, C = points.shape[0], levels[0].shape[-1]
        out = torch.empty(P, len(levels) * C, dtype=torch.float32)
        jac = torch.empty(P, len(levels) * C, 3, dtype=torch.float32)
        xyz = points.detach().contiguous()
        for i, level in enumerate(levels):
            _lookup_with_jacobian(xyz.numpy(), _rows(level), level.shape[0], out.numpy(), jac.numpy(), i * C)
        ctx.save_for_backward(xyz)
        ctx.shapes = [level.shape for level in levels]
        return out, jac

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad, grad_jac):
        (xyz,) = ctx.saved_tensors
        P, LC = xyz.shape[0], sum(shape[-1] for shape in ctx.shapes)
        xyz = xyz.numpy()
        grad = (torch.zeros(P, LC) if grad is None else grad.detach()).numpy()
        grad_jac = (torch.zeros(P, LC, 3) if grad_jac is None else grad_jac.detach()).numpy()
        return _level_gradients(ctx, lambda R, column, rows: _lookup_with_jacobian_adjoint(xyz, grad, grad_jac, R,
                                                                                             column, rows))


def lookup_with_jacobian(levels: Sequence[torch.Tensor], points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`lookup` and the derivative of every feature with respect to the point: (P, L C) and
    (P, L C, 3), ``jac[p, j, a] = d feature_j / d x_a`` in the cube's units (0 along an axis on which
    the point lies outside the cube). Both are linear in the levels and differentiable in them (the
    points are constants), so a loss on a network's input gradient needs no second derivative here.
    Same arguments as :func:`lookup`.
    """
    if not applies(levels, points):
        raise ValueError("grid_lookup.lookup_with_jacobian takes float32 CPU tensors and points without a gradient")
    return _LookupWithJacobian.apply(points, *levels)


@numba.njit(cache=True, boundscheck=False)
def _jacobian_transpose_product(jac, d, out):
    """out[p, a] = sum_j d[p, j] jac[p, j, a]."""
    for p in range(jac.shape[0]):
        x = y = z = _ZERO
        for j in range(jac.shape[1]):
            x += d[p, j] * jac[p, j, 0]
            y += d[p, j] * jac[p, j, 1]
            z += d[p, j] * jac[p, j, 2]
        out[p, 0], out[p, 1], out[p, 2] = x, y, z


@numba.njit(cache=True, boundscheck=False)
def _jacobian_transpose_product_adjoint(jac, d, grad, grad_jac, grad_d):
    """The adjoints of :func:`_jacobian_transpose_product`: grad_jac[p, j, a] = d[p, j] grad[p, a],
    grad_d[p, j] = sum_a grad[p, a] jac[p, j, a]."""
    for p in range(jac.shape[0]):
        gx, gy, gz = grad[p, 0], grad[p, 1], grad[p, 2]
        for j in range(jac.shape[1]):
            grad_jac[p, j, 0], grad_jac[p, j, 1], grad_jac[p, j, 2] = d[p, j] * gx, d[p, j] * gy, d[p, j] * gz
            grad_d[p, j] = gx * jac[p, j, 0] + gy * jac[p, j, 1] + gz * jac[p, j, 2]


class _JacobianTransposeProduct(torch.autograd.Function):

    @staticmethod
    def forward(ctx, jac, d):
        jac, d = jac.detach().contiguous(), d.detach().contiguous()
        out = torch.empty(jac.shape[0], 3, dtype=torch.float32)
        _jacobian_transpose_product(jac.numpy(), d.numpy(), out.numpy())
        ctx.save_for_backward(jac, d)
        return out

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad):
        jac, d = ctx.saved_tensors
        grad_jac, grad_d = torch.empty_like(jac), torch.empty_like(d)
        _jacobian_transpose_product_adjoint(jac.numpy(), d.numpy(), grad.detach().contiguous().numpy(),
                                            grad_jac.numpy(), grad_d.numpy())
        return grad_jac, grad_d


def jacobian_transpose_product(jac: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """``(d[:, None, :] @ jac)[:, 0]``: per point, the features' derivatives ``jac`` (P, J, 3) of
    :func:`lookup_with_jacobian` contracted with a gradient ``d`` (P, J) in those features, the
    gradient in the point (P, 3); float32 CPU tensors, differentiable once in both. One compiled
    pass each way instead of a batched product of 1 x J x 3 matrices."""
    return _JacobianTransposeProduct.apply(jac, d)

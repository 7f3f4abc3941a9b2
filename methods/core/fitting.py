"""One fitting loop for every method, with budgets as data.

The loop: network ``methods.core.network.make_network(method.input_dim, method.output_dim,
**method.network_config(budget))`` (the budget's backbone, ``'mlp'`` or ``'grid'``, unless the method
has its own network); AdamW with one
parameter group per kind of weight (:func:`parameter_groups`): the MLP's weights (lr, weight
decay) and, for the grid backbone, the feature grid (lr_grid, no weight decay); cosine decay of
each group's learning rate from its start to its end value over the budget's ``steps`` (MLP:
``lr_t = lr_final + (lr - lr_final) (1 + cos(pi t / T)) / 2``; grid: the same from ``lr_grid`` to
``lr_grid_final``), so both reach their end value at the budget's last step; with
``warmup_fraction`` > 0 the first ``W = round(warmup_fraction T)`` steps scale that schedule by
``(t + 1) / W`` (a linear warm-up; from step W on the schedule is the cosine above) (torch's fused AdamW
kernel where the budget asks for it, :func:`make_optimizer`); each step draws ``batch_size``
samples *with replacement* from the M samples with a ``torch.Generator`` seeded by ``seed``; the
loss is ``method.loss(method.predict(model, batch_inputs), batch_targets)``; the steps themselves (schedule,
NaN checks, checkpoints, timing) are :func:`methods.core.training_loop.run_steps`, shared with the K-NN
training. Everything about a fit is
decided by (method, samples, targets, budget, seed): on the CPU the same seed gives the same
weights bit for bit (same thread count). The seed is the job's fitting stream
(``foundation.seeding.JobStreams.fitting_seed``); it seeds the network initialisation and the
batch-order generator. A non-finite loss raises :class:`FittingError` (the runner records the job
as failed and goes on), and so does a fit that ends with a constant network (every output the same
on the training inputs: its Softplus units died, :func:`check_not_constant`), which would otherwise
read as an empty mesh.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable, Sequence

import numpy as np
import torch

from foundation.params import Param, check_fields, setting
from methods.core.budgets import register_budget_family
from methods.core.weights import weights_from_bytes, weights_to_bytes
from methods.core.device import PRECISIONS, autocast, get_device, precision_unavailable, seeded_generator
from methods.core.network import BACKBONES, FeatureGrid, make_network
from methods.core.schedules import warmup_cosine_lr
from methods.core.training_loop import FittingError, run_steps


@dataclass(frozen=True)
class Budget:
    """A fitting budget. ``depth`` counts linear layers; ``num_samples`` is M.

    ``backbone``: ``'mlp'`` (the MLP is ``depth`` x ``width``) or ``'grid'`` (a feature grid of
    ``grid_resolutions`` points per axis per level and ``grid_channels`` features, then a
    ``depth`` x ``width`` MLP head; :class:`methods.core.network.GridNetwork`). The grid's values train
    at ``lr_grid`` decaying to ``lr_grid_final``, without weight decay (a decay would pull every
    cell no sample visits to 0, and cells the samples rarely reach toward it); the grid settings
    are empty for ``'mlp'`` budgets and required for ``'grid'`` ones.
    ``fused_adam``: torch's fused AdamW kernel (the same update to float rounding; much faster than
    the default per-tensor loop on a feature grid's values: docs/PERFORMANCE.md, section 2). Off for
    the MLP budgets, whose numbers stay those of the default kernel.
    ``log_every``: the loss is checked for NaN/inf and reported to ``progress`` every so many steps.
    ``warmup_fraction``: the first ``round(warmup_fraction * steps)`` steps ramp both learning
    rates linearly up to their schedule (:func:`methods.core.schedules.warmup_cosine_lr`); 0 = none.
    ``precision``: ``'float32'`` (the numbers any CPU reproduces on its float path) or ``'bfloat16'``
    (the forward pass under :func:`methods.core.device.autocast`; refused where the device lacks
    bfloat16 arithmetic, :func:`methods.core.device.precision_unavailable`). A loss that needs the
    MLP's input gradient (UDF's, :mod:`methods.core.head_gradient`) is computed in float32 either way.
    """

    name: str = setting(Param(kind=str, help="budget name"))
    depth: int = setting(Param(kind=int, help="linear layers of the MLP (the grid backbone's head)", ge=2),
                         override=True)
    width: int = setting(Param(kind=int, help="hidden width of the MLP", ge=1), override=True)
    steps: int = setting(Param(kind=int, help="optimizer steps", ge=1), override=True)
    batch_size: int = setting(Param(kind=int, help="samples per step", ge=1), override=True)
    num_samples: int = setting(Param(kind=int, help="training samples M drawn by the shared sampler", ge=100),
                               override=True)
    beta: float = setting(Param(100.0, "Softplus sharpness", gt=0))
    lr: float = setting(Param(1e-3, "MLP learning rate at the first step", gt=0), override=True)
    lr_final: float = setting(Param(1e-5, "MLP learning rate at the last step", ge=0), override=True)
    weight_decay: float = setting(Param(0.01, "AdamW weight decay of the MLP (torch's default)", ge=0), override=True)
    activation: str = setting(Param("softplus", "hidden activation of the MLP"))
    log_every: int = setting(Param(50, "steps between loss checks and progress reports", ge=1))
    backbone: str = setting(Param("mlp", "network backbone", choices=BACKBONES))
    grid_resolutions: tuple[int, ...] = setting(Param((), "grid points per axis of each feature-grid level",
                                                      kind=tuple, item=int, ge=2))
    grid_channels: int = setting(Param(0, "features per grid level", ge=0), override=True)
    lr_grid: float = setting(Param(0.0, "feature-grid learning rate at the first step", ge=0), override=True)
    lr_grid_final: float = setting(Param(0.0, "feature-grid learning rate at the last step", ge=0), override=True)
    fused_adam: bool = setting(Param(False, "torch's fused AdamW kernel"))
    warmup_fraction: float = setting(Param(0.0, "fraction of the steps that ramp the learning rates up linearly",
                                           ge=0, lt=1), override=True)
    precision: str = setting(Param("float32", "arithmetic of the forward and backward passes (bfloat16: autocast of "
                                   "the hidden and output layers; the input layer, weights, optimizer and loss in "
                                   "float32; only where the device has bfloat16 arithmetic)",
                                   choices=PRECISIONS), override=True)

    def __post_init__(self):
        check_fields(self, f"budget '{self.name}'")
        grid = (self.grid_resolutions, self.grid_channels, self.lr_grid, self.lr_grid_final)
        if self.backbone == "mlp" and any(grid):
            raise ValueError(f"budget '{self.name}': grid settings given for the 'mlp' backbone")
        if self.backbone == "grid" and not (self.grid_resolutions and self.grid_channels >= 1 and self.lr_grid > 0
                                            and self.lr_grid_final >= 0):
            raise ValueError(f"budget '{self.name}': the 'grid' backbone needs grid_resolutions, grid_channels >= 1, "
                             f"lr_grid > 0 and lr_grid_final >= 0")

    def network_config(self) -> dict:
        """Keyword arguments of :func:`methods.core.network.make_network` (the grid settings only for 'grid')."""
        config = {"depth": self.depth, "width": self.width, "beta": self.beta, "activation": self.activation}
        if self.backbone == "grid":
            config.update(backbone="grid", grid_resolutions=self.grid_resolutions, grid_channels=self.grid_channels)
        return config


#: The budgets (why these values, with the measurements: docs/PERFORMANCE.md, "The cpu budget"):
#: *paper*: the paper's network and schedule (a GPU budget). *quick*: a 5 x 128 MLP without a grid,
#: the CPU reference of a plain MLP, at the paper's lr 1e-3. *tiny*: tests (200 steps of 1,024 samples).
#: *cpu*: the default of run_benchmark.py, the same for every method: the grid backbone at CPU size
#: (levels 16/32/64 x 4 channels, raw xyz concatenated, a 3 x 64 Softplus head), AdamW at 1e-2 for grid
#: and head after a 5 % linear warm-up, cosine-decayed to 1e-4 at the last of 3,000 steps of 4,096
#: samples drawn from 1M. *tiny-grid*: the grid backbone at test/CI size (the neural regression tier).
#: *cpu-mlp*: the cpu budget's fit seconds spent on a plain Softplus MLP (5 x 128, no grid; 1,200 steps
#: of 4,096 from 1M at the paper's lr 1e-3, cosine-decayed): the backbone comparison (``--recipe backbone``).
ENCODE_FAMILY = register_budget_family("encode", (
    Budget("paper", depth=9, width=512, steps=100_000, batch_size=10_000, num_samples=10_000_000,
           log_every=500),
    Budget("quick", depth=5, width=128, steps=1_000, batch_size=2_048, num_samples=200_000,
           lr=1e-3, log_every=50),
    Budget("tiny", depth=4, width=64, steps=200, batch_size=1_024, num_samples=20_000,
           lr=3e-3, log_every=20),
    Budget("cpu", depth=3, width=64, steps=3_000, batch_size=4_096, num_samples=1_000_000,
           lr=1e-2, lr_final=1e-4, log_every=50, backbone="grid", grid_resolutions=(16, 32, 64),
           grid_channels=4, lr_grid=1e-2, lr_grid_final=1e-4, fused_adam=True, warmup_fraction=0.05),
    Budget("cpu-mlp", depth=5, width=128, steps=1_200, batch_size=4_096, num_samples=1_000_000,
           lr=1e-3, log_every=50),
    Budget("mlp", depth=5, width=256, steps=16_000, batch_size=4_096, num_samples=1_000_000,
           lr=1e-3, lr_final=1e-5, log_every=100, warmup_fraction=0.05),
    Budget("tiny-grid", depth=3, width=32, steps=250, batch_size=2_048, num_samples=100_000,
           lr=1e-2, lr_final=1e-4, log_every=25, backbone="grid", grid_resolutions=(16, 32, 64),
           grid_channels=4, lr_grid=1e-2, lr_grid_final=1e-4, fused_adam=True, warmup_fraction=0.05),
))
#: The encode budgets by name.
BUDGETS = ENCODE_FAMILY.budgets


def get_budget(budget: str | Budget, overrides: dict | None = None) -> Budget:
    """An encode budget by name (or the budget itself), with ``overrides`` of the fields marked
    ``override=True`` applied (typed, range-checked); unknown names list the known ones."""
    return ENCODE_FAMILY.get(budget, overrides)


@dataclass
class FitResult:
    """model (eval mode), per-step losses (float32, length ``steps``), wall seconds, steps, final
    loss (mean of the last ``log_every`` steps)."""

    model: torch.nn.Module
    losses: np.ndarray
    seconds: float
    steps: int
    final_loss: float
    samples_per_s: float


#: A fit whose outputs on (up to this many) training inputs all lie within :data:`CONSTANT_PTP` of
#: each other, in every channel, is a collapsed network (:func:`check_not_constant`).
CONSTANT_PROBE = 4096
CONSTANT_PTP = 1e-6


def check_not_constant(model: torch.nn.Module, inputs: torch.Tensor, where: str) -> None:
    """Raise :class:`FittingError` if ``model`` gives the same output on all of ``inputs`` (its
    hidden units died: every Softplus is ~0 on every input, so only the last bias learns and the
    field has no level set at all)."""
    with torch.no_grad():
        out = model(inputs[:CONSTANT_PROBE])
    spread = (out.max(dim=0).values - out.min(dim=0).values).max().item() if len(out) > 1 else 1.0
    if spread < CONSTANT_PTP:
        raise FittingError(f"the network collapsed to a constant output (spread {spread:.2g} over "
                           f"{len(out)} training inputs) in {where}: its hidden units died; a longer warm-up "
                           f"(--budget-param warmup_fraction=0.1) or a lower lr (--budget-param lr=...) may fit it")


def parameter_groups(model: torch.nn.Module, budget: Budget) -> list[dict]:
    """AdamW parameter groups of ``model`` under ``budget``, each with its schedule's end points.

    The MLP weights (all of an MLP; the head of a :class:`methods.core.network.GridNetwork`, the decoders
    of a :class:`methods.core.network.LODNetwork`): ``lr`` -> ``lr_final``, the optimizer's weight decay.
    The feature grids (every :class:`methods.core.network.FeatureGrid` of the network: its ``encoder``,
    or each member's in a :class:`methods.core.network.StackedNetworks`), if any: ``lr_grid`` ->
    ``lr_grid_final`` (``lr`` -> ``lr_final`` under a budget without a grid), weight decay 0. ``lr_start``/``lr_end`` are read by :func:`fit` each step.
    """
    grid = [p for module in model.modules() if isinstance(module, FeatureGrid) for p in module.parameters()]
    in_grid = {id(p) for p in grid}
    groups = [{"params": [p for p in model.parameters() if id(p) not in in_grid],
               "lr_start": budget.lr, "lr_end": budget.lr_final}]
    if grid:  # a method's own grid under an MLP budget (no grid rates) trains at the MLP's rates
        start, end = (budget.lr_grid, budget.lr_grid_final) if budget.backbone == "grid" else (budget.lr, budget.lr_final)
        groups.append({"params": grid, "lr": start, "weight_decay": 0.0, "lr_start": start, "lr_end": end})
    return groups


def make_optimizer(model: torch.nn.Module, budget: Budget) -> torch.optim.AdamW:
    """AdamW over :func:`parameter_groups` (initial lr ``budget.lr``, weight decay ``budget.weight_decay``
    where the group sets none; torch's fused kernel if ``budget.fused_adam``, else its default)."""
    return torch.optim.AdamW(parameter_groups(model, budget), lr=budget.lr, weight_decay=budget.weight_decay,
                             fused=True if budget.fused_adam else None)


def _to_tensors(inputs: np.ndarray, targets: dict, device) -> tuple[torch.Tensor, dict]:
    M = len(inputs)
    x = torch.as_tensor(np.ascontiguousarray(inputs, dtype=np.float32), device=device)
    t = {}
    for key, value in targets.items():
        value = np.asarray(value)
        if len(value) != M:
            raise FittingError(f"target '{key}' has {len(value)} rows for {M} samples")
        if value.dtype.kind == "f" and not np.all(np.isfinite(value)):
            raise FittingError(f"target '{key}' contains NaN or infinite values")
        t[key] = torch.as_tensor(np.ascontiguousarray(value, dtype=np.float32), device=device)
    return x, t


def gather_rows(inputs: torch.Tensor, targets: dict[str, torch.Tensor], rows: torch.Tensor
                ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """``inputs[rows]`` and every ``targets[key][rows]``, each by one ``index_select`` along the first
    axis (the same values as advanced indexing; on the CPU the random-row gather of a step costs
    several times less this way: ``benchmarks/bench_fit_profile.py``)."""
    return inputs.index_select(0, rows), {key: value.index_select(0, rows) for key, value in targets.items()}


def as_float32(prediction):
    """``prediction`` (a tensor, or a tuple/list/dict of them, as ``method.predict`` returns) with every
    floating tensor in float32: a bfloat16 forward pass's outputs, so the loss is computed in float32."""
    if isinstance(prediction, torch.Tensor):
        return prediction.float() if prediction.is_floating_point() else prediction
    if isinstance(prediction, dict):
        return {key: as_float32(value) for key, value in prediction.items()}
    if isinstance(prediction, (tuple, list)):
        return type(prediction)(as_float32(value) for value in prediction)
    return prediction


def fit(method, samples, targets: dict, budget: str | Budget, seed: int = 0, device=None,
        progress: Callable[..., None] | None = None, checkpoints: Sequence[int] = (),
        on_checkpoint: Callable[[int, float, torch.nn.Module], None] | None = None) -> FitResult:
    """Fit ``method``'s network to ``targets`` on ``samples`` under ``budget`` (see module docstring).

    Parameters
    ----------
    method : a :class:`methods.base.FieldMethod` (gives input/output sizes and the loss).
    samples : :class:`foundation.sampler.Samples` (or anything ``method.network_inputs`` accepts).
    targets : dict of (M, ...) arrays from ``method.training_targets``.
    budget : a :class:`Budget` or its name in :data:`BUDGETS`.
    seed : initialisation and batch-order seed.
    device : torch device (default: :func:`methods.core.device.get_device`).
    progress : optional ``progress(step=int, loss=float)`` called every ``budget.log_every`` steps.
    checkpoints, on_checkpoint : after each step number in ``checkpoints`` (1-based, <= steps)
        the fit pauses and calls ``on_checkpoint(step, fit_seconds_so_far, model)`` with the model in
        eval mode (anytime curves). The pause is not counted in the fit's seconds and changes nothing
        about the fit: the weights and losses are those of a fit without checkpoints.
    """
    budget = get_budget(budget)
    device = get_device(device)
    unavailable = precision_unavailable(budget.precision, device)
    if unavailable:
        raise FittingError(f"budget '{budget.name}' asks for precision={budget.precision}: {unavailable}")
    inputs = method.network_inputs(samples)
    x_all, t_all = _to_tensors(inputs, targets, device)
    M = len(x_all)
    if M == 0:
        raise FittingError("no training samples")
    generator = seeded_generator(seed, device)
    model = make_network(method.input_dim, method.output_dim, **method.network_config(budget)).to(device)
    optimizer = make_optimizer(model, budget)
    T, B = int(budget.steps), int(budget.batch_size)
    warmup = round(budget.warmup_fraction * T)

    def step_loss(step: int) -> torch.Tensor:
        idx = torch.randint(0, M, (B,), generator=generator, device=device)
        xb, tb = gather_rows(x_all, t_all, idx)
        with autocast(budget.precision, device):
            prediction = method.predict(model, xb)
        return method.loss(as_float32(prediction), tb)

    where = f"(method '{method.name}', budget '{budget.name}', seed {seed})"
    result = run_steps(model, optimizer, T, step_loss, log_every=budget.log_every,
                       where=lambda i: f"iteration {i} of {T} {where}",
                       learning_rate=lambda group, step: warmup_cosine_lr(step, T, group["lr_start"], group["lr_end"], warmup),
                       progress=progress, checkpoints=checkpoints, on_checkpoint=on_checkpoint, device=device)
    check_not_constant(model, x_all, f"method '{method.name}', budget '{budget.name}', seed {seed}")
    return FitResult(model=model, losses=result.losses, seconds=result.seconds, steps=T,
                     final_loss=result.final_loss, samples_per_s=T * B / max(result.seconds, 1e-9))


# ---------------------------------------------------------------------------------------------
# weights as bytes (the run layer's cache stores them checksummed, foundation.storage)
# ---------------------------------------------------------------------------------------------


def model_to_bytes(model, budget: Budget, method_name: str, final_loss: float) -> bytes:
    """``torch.save`` bytes of ``{'state_dict', 'config' (network), 'budget', 'method', 'final_loss'}``."""
    return weights_to_bytes(model, asdict(get_budget(budget)), method_name, final_loss)


def model_from_bytes(data: bytes, device=None, method_name: str | None = None):
    """(model in eval mode on ``device``, final loss) from :func:`model_to_bytes`' bytes.

    The network is rebuilt from the stored ``model.config`` (any backbone; a config without
    ``backbone``, as every MLP's, is an MLP). ``method_name``, when given, must match the stored one
    (a clear ValueError otherwise)."""
    model, blob = weights_from_bytes(data, make_network, device, method_name)
    return model, float(blob["final_loss"])

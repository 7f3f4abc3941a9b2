"""Training the K-NN local network of ``sals-knn``, ``udf-knn`` and ``occ-knn`` once across many
shapes, and its budget.

The training set and its pools are the learned point-cloud methods' shared ones
(:mod:`methods.pointcloud.training_set`); this module draws the K-NN batches and runs the steps.

Batches and steps (:func:`train`)
---------------------------------
Network ``make_knn_network(method.network_kind, out_dim=method.output_dim, **budget.network_config())``,
AdamW (``budget.lr``, ``budget.weight_decay``), constant learning rate (the paper). Each of the
``budget.steps`` steps picks ``shapes_per_batch`` distinct training shapes (with repeats only when
there are fewer shapes); each such item draws ``points_per_item`` input points of its point pool
without replacement (its cloud) and ``samples_per_item`` labelled samples with replacement; one
KD-tree per item (``knn_neighbourhoods``, or ``segment_neighbourhoods`` at the midpoints)
gives every sample its K neighbours in that item's cloud, gathered to (S, K, 3) at once
(:func:`knn_batch`). The items are concatenated into one batch (batch norm sees all of it), the
network runs in train mode and the loss is ``method.loss(prediction, targets)``. The loss is
checked for NaN/inf and reported to ``progress(step=..., loss=...)`` every ``budget.log_every``
steps (a non-finite loss raises :class:`methods.core.training_loop.FittingError`); the model comes
back in eval mode with ``knn_k`` set (the K the grid queries need, :mod:`methods.pointcloud.knn.query`).

Seeding: ``seed`` seeds torch's generator before the network is built (its initialisation,
:func:`methods.core.device.seeded_generator`, which also turns on deterministic algorithms on the CPU)
and the batch Generator of :func:`foundation.seeding.training_streams` (shapes, clouds, samples of
every step); pools built inside :func:`train` use the same ``seed``. On the CPU the same seed gives
the same weights bit for bit (same thread count; the KD-tree is exact and deterministic).

Weights: :func:`knn_model_to_bytes` / :func:`knn_model_from_bytes` (the network rebuilt by
``make_knn_network(**config)``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import torch

from foundation.params import Param, check_fields, setting
from foundation.seeding import training_streams
from datasets import Shape
from methods.core.budgets import budget_values, register_budget_family
from methods.core.device import get_device, seeded_generator
from methods.core.weights import weights_from_bytes, weights_to_bytes
from methods.pointcloud.knn.network import make_knn_network
from methods.pointcloud.neighbourhoods import knn_neighbourhoods, segment_neighbourhoods
from methods.pointcloud.training_set import TrainingPools, TrainingSet, TrainResult, train_steps

__all__ = ["KNNBudget", "KNN_FAMILY", "KNN_BUDGETS", "get_knn_budget", "knn_batch", "train", "knn_model_to_bytes",
           "knn_model_from_bytes"]


@dataclass(frozen=True)
class KNNBudget(TrainingSet):
    """The training budget of the K-NN networks (``sals-knn``, ``udf-knn``, ``occ-knn``).

    ``k``: neighbours per query. ``encoder_width``/``encoder_depth``, ``head_width``/``head_depth``:
    the network (:class:`methods.pointcloud.knn.network.LocalEncoder`, ``RegressionHead``; depth counts the hidden
    ``width -> width`` layers). Each of the ``steps`` optimizer steps takes ``shapes_per_batch``
    training shapes; each such item draws ``points_per_item`` input points (its cloud, from which the
    neighbourhoods are searched) and ``samples_per_item`` labelled samples (segments for ``sals-knn``,
    query points for ``udf-knn``/``occ-knn``), so a batch holds ``shapes_per_batch x samples_per_item``
    samples. AdamW at the constant ``lr`` with ``weight_decay`` (the paper states no decay: torch's
    default 0.01). ``log_every``: steps between loss reports.

    The training set (:class:`methods.pointcloud.training_set.TrainingSet`): ``training_shapes``
    built-in parts (plus any ``--train-dir`` meshes); per training shape a pool of ``pool_samples``
    labelled samples (the shared sampler, labelled by the exact fields) and a pool of
    ``pool_points`` surface points, from which each item draws its ``samples_per_item`` samples
    (with replacement) and its ``points_per_item`` input points (without replacement, so
    ``pool_points >= points_per_item``).
    """

    name: str = setting(Param(kind=str, help="budget name"))
    k: int = setting(Param(kind=int, help="neighbours per query", ge=1), override=True)
    encoder_width: int = setting(Param(kind=int, help="width of the local encoders", ge=1), override=True)
    encoder_depth: int = setting(Param(kind=int, help="hidden layers of the local encoders", ge=0), override=True)
    head_width: int = setting(Param(kind=int, help="width of the regression head", ge=1), override=True)
    head_depth: int = setting(Param(kind=int, help="hidden layers of the regression head", ge=0), override=True)
    steps: int = setting(Param(kind=int, help="optimizer steps", ge=1), override=True)
    shapes_per_batch: int = setting(Param(kind=int, help="training shapes per batch", ge=1))
    samples_per_item: int = setting(Param(kind=int, help="labelled samples per shape of a batch", ge=1),
                                    override=True)
    points_per_item: int = setting(Param(kind=int, help="input points per shape of a batch", ge=1), override=True)
    lr: float = setting(Param(1e-3, "AdamW learning rate (constant)", gt=0), override=True)
    weight_decay: float = setting(Param(0.01, "AdamW weight decay (torch's default)", ge=0))
    log_every: int = setting(Param(100, "steps between loss reports", ge=1))

    def __post_init__(self):
        check_fields(self, f"knn budget '{self.name}'")
        if self.points_per_item < self.k:
            raise ValueError(f"knn budget '{self.name}': points_per_item {self.points_per_item} < k {self.k}")
        if self.pool_points < self.points_per_item:
            raise ValueError(f"knn budget '{self.name}': pool_points {self.pool_points} < points_per_item "
                             f"{self.points_per_item} (an item's cloud is drawn without replacement)")

    def network_config(self) -> dict:
        """The network sizes, for ``make_knn_network(kind, out_dim=..., **budget.network_config())``."""
        return dict(encoder_width=self.encoder_width, encoder_depth=self.encoder_depth, head_width=self.head_width,
                    head_depth=self.head_depth)


#: The K-NN budgets (the measurements behind them: docs/PERFORMANCE.md, "K-NN training"):
#: *paper*: the paper's K-NN network (K = 20; encoders 4 -> 256, 4 x 256, 256 -> 256; head 512 -> 256,
#: 4 x 256, 256 -> out; batches of 4 shapes x 5,120 samples, each item with 40k input points; AdamW
#: 1e-3 constant, 10k steps; 100 training shapes, 1M labelled samples and 1M surface points each; GPU
#: scale). *cpu*: sized for a 2-core machine (its training time: that section): the paper's K and
#: cloud size (the local encoder sees the density it is tested at), width 64 with 2 hidden layers in
#: each encoder and the head, batches of 4 shapes x 1,024 samples, 1,500 steps, 24 built-in training
#: parts with pools of 200k samples and 200k surface points. *tiny*: tests: K = 16, width 32,
#: one hidden layer, lr 3e-3, 400 steps of 2 x 256 samples, 4 parts, pools of 20k, clouds of 10k points
#: (fewer points do not locate the surface to a fraction of a segment's length: the segment network
#: then cannot learn its s).

KNN_FAMILY = register_budget_family("knn", (
    KNNBudget("paper", k=20, encoder_width=256, encoder_depth=4, head_width=256, head_depth=4, steps=10_000,
              shapes_per_batch=4, samples_per_item=5_120, points_per_item=40_000, lr=1e-3, log_every=100,
              training_shapes=100, pool_samples=1_000_000, pool_points=1_000_000),
    KNNBudget("cpu", k=20, encoder_width=64, encoder_depth=2, head_width=64, head_depth=2, steps=1_500,
              shapes_per_batch=4, samples_per_item=1_024, points_per_item=40_000, lr=1e-3, log_every=50,
              training_shapes=24, pool_samples=200_000, pool_points=200_000),
    KNNBudget("tiny", k=16, encoder_width=32, encoder_depth=1, head_width=32, head_depth=1, steps=400,
              shapes_per_batch=2, samples_per_item=256, points_per_item=10_000, lr=3e-3, log_every=50,
              training_shapes=4, pool_samples=20_000, pool_points=20_000),
))
#: The K-NN budgets by name.
KNN_BUDGETS = KNN_FAMILY.budgets


def get_knn_budget(budget: str | KNNBudget, overrides: dict | None = None) -> KNNBudget:
    """A :class:`KNNBudget` by name (or the budget itself), with ``overrides`` of its fields marked
    ``override=True`` applied (typed, range-checked)."""
    return KNN_FAMILY.get(budget, overrides)


def knn_batch(pools: TrainingPools, budget: KNNBudget, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict]:
    """One training batch: (anchors (B, 3) or (B, 2, 3), neighbours (B, K, 3), targets {name: (B, ...)}),
    float32, ``B = shapes_per_batch x samples_per_item``, items in order (module docstring)."""
    n, items = len(pools.pools), budget.shapes_per_batch
    chosen = rng.choice(n, size=items, replace=items > n)
    S, P = budget.samples_per_item, budget.points_per_item
    anchors, neighbours, targets = [], [], {k: [] for k in pools.pools[0].targets}
    for index in chosen:
        pool = pools.pools[index]
        cloud = pool.cloud[rng.choice(len(pool.cloud), size=P, replace=False)]
        rows = rng.integers(0, len(pool), size=S)
        a = pool.anchors[rows]
        nearest = segment_neighbourhoods if pools.kind == "segment" else knn_neighbourhoods
        neighbours.append(cloud[nearest(cloud, a, budget.k)])
        anchors.append(a)
        for key, value in pool.targets.items():
            targets[key].append(value[rows])
    return (np.concatenate(anchors), np.concatenate(neighbours),
            {k: np.concatenate(v) for k, v in targets.items()})


# --------------------------------------------------------------------------------------------------
# Training
# --------------------------------------------------------------------------------------------------

def train(method, shapes: Sequence[Shape], budget: str | KNNBudget, seed: int = 0, device=None,
          progress: Callable[..., None] | None = None, pools: TrainingPools | None = None) -> TrainResult:
    """Train ``method``'s K-NN network across ``shapes`` under ``budget`` (module docstring).

    Parameters
    ----------
    method : a :class:`methods.base.LearnedPointCloudMethod` (``network_kind``, ``output_dim``,
        ``training_targets``, ``loss``).
    shapes : the training shapes (:func:`training_shapes`); ignored when ``pools`` is given.
    budget : a :class:`KNNBudget` or its name in :data:`KNN_BUDGETS`.
    seed : network initialisation, batch draws and (when built here) the pools.
    device : torch device (default :func:`methods.core.device.get_device`).
    progress : ``progress(step=int, loss=float, total=budget.steps)`` every ``budget.log_every`` steps
        and at the last.
    pools : :class:`TrainingPools` built beforehand (e.g. to report labelling progress); they must be
        of the method's network kind.
    """
    budget = get_knn_budget(budget)
    device = get_device(device)
    if pools is None:
        pools = TrainingPools(method, shapes, budget, seed)
    elif pools.kind != method.network_kind:
        raise ValueError(f"pools of '{pools.kind}' samples for a '{method.network_kind}' method")
    seeded_generator(seed, device)  # torch's global seed: the initialisation below
    rng = training_streams(seed).batch_rng()
    model = make_knn_network(method.network_kind, out_dim=method.output_dim, **budget.network_config()).to(device)
    optimizer = torch.optim.AdamW(model.parameters(), lr=budget.lr, weight_decay=budget.weight_decay)

    def step_loss(step: int) -> torch.Tensor:
        a, q, t = knn_batch(pools, budget, rng)
        anchors = torch.from_numpy(a).to(device)
        targets = {k: torch.from_numpy(v).to(device) for k, v in t.items()}
        return method.loss(model(anchors, torch.from_numpy(q).to(device)), targets)

    result = train_steps(method, model, optimizer, budget, "knn", step_loss, seed=seed,
                         batch=budget.shapes_per_batch * budget.samples_per_item, pool_seconds=pools.seconds,
                         device=device, progress=progress)
    model.knn_k = budget.k
    return result


# --------------------------------------------------------------------------------------------------
# Weights as bytes (the run layer stores them checksummed, foundation.storage)
# --------------------------------------------------------------------------------------------------

def knn_model_to_bytes(model, budget: str | KNNBudget, method_name: str, final_loss: float) -> bytes:
    """``torch.save`` bytes of ``{'state_dict', 'config' (network), 'budget', 'method', 'final_loss'}``
    (:func:`methods.core.weights.weights_to_bytes`)."""
    return weights_to_bytes(model, budget_values(get_knn_budget(budget)), method_name, final_loss)


def knn_model_from_bytes(data: bytes, device=None, method_name: str | None = None):
    """(model in eval mode on ``device``, ``knn_k`` set from the stored budget, final loss) from
    :func:`knn_model_to_bytes`' bytes, the network rebuilt by ``make_knn_network(**config)``.
    ``method_name``, when given, must match the stored one."""
    model, blob = weights_from_bytes(data, make_knn_network, device, method_name, what="K-NN weights")
    model.knn_k = int(blob["budget"]["k"])
    return model, float(blob["final_loss"])

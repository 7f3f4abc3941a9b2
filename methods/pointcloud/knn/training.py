"""Training a learned reconstruction method once across many shapes.

A learned point-cloud method (:class:`methods.base.LearnedPointCloudMethod`: ``sals-knn``,
``udf-knn``, ``occ-knn``) trains one K-NN local network (:mod:`methods.pointcloud.knn.network`) on a training
set of shapes disjoint from every test shape, under one :class:`methods.pointcloud.knn.network.KNNBudget`, and
then reconstructs every test cloud with it.

Training set (:func:`training_shapes`)
--------------------------------------
Built-in CAD-like parts ``generate_shape(i, kind, seed)`` for ``i in range(count)``, the kinds
cycling ``closed, open, nonmanifold`` (:data:`datasets.builtin.VARIANTS`; an index whose variant
cannot be generated, e.g. no piercing placement for a non-manifold pair, takes the next variant),
at the training generator seed (default 1). The built-in *test* dataset uses seed 0, and every
dimension of part ``i`` is drawn from ``default_rng([seed, i, stream])``, so no training part is a
test part; this is checked, not assumed: the content hashes of the training parts are compared
with those of every seed-0 built-in shape of the same indices in every variant (a superset of
any built-in test dataset of up to ``count`` shapes, whatever its variants), and a collision
raises. Training parts are renamed ``train<seed>_<name>`` so no name reads like a test shape's.
Then every mesh of each ``extra_dirs`` folder (the Thingi10K meshes of ``../shared/data/thingi10k``),
loaded in the canonical frame by the ``meshes`` dataset (and checked against the same hashes).

Generation is cached per process (:func:`functools.lru_cache` on (index, kind, seed): the training
shapes, and only the (hash, name) of the test shapes), so a second call (the cache key of the
weights, then the training) generates nothing; the list itself is built eagerly, since every shape
is labelled anyway. Costs: docs/PERFORMANCE.md, "K-NN training".

Pools (:class:`TrainingPools`)
------------------------------
Per training shape: ``budget.pool_samples`` samples of the shared five-group sampler
(:func:`benchmark.sampler.sample_training_data`), labelled by ``method.training_targets`` with the
shape's :class:`benchmark.fields.ExactFields`, keeping the network's anchors only (segments (M, 2, 3)
for a ``'segment'`` method, points (M, 3) for a ``'point'`` one), and ``budget.pool_points``
area-uniform surface points (:func:`benchmark.surface.sample_surface`), everything float32. All the
draws of a shape come from its own numpy Generator, ``SeedSequence(seed).spawn(2)[0].spawn(n)[i]``
for shape ``i`` of ``n``: the same (shapes, budget, seed) gives the same pools, in any process.
Non-finite labels raise :class:`methods.core.fitting.FittingError` naming the shape.

Batches and steps (:func:`train`)
---------------------------------
Network ``make_knn_network(method.network_kind, out_dim=method.output_dim, **budget.network_config())``,
AdamW (``budget.lr``, ``budget.weight_decay``), constant learning rate (the paper). Each of the
``budget.steps`` steps picks ``shapes_per_batch`` distinct training shapes (with repeats only when
there are fewer shapes); each such item draws ``points_per_item`` input points of its point pool
without replacement (its cloud) and ``samples_per_item`` labelled samples with replacement; one
KD-tree per item (:func:`knn_neighbourhoods`, or :func:`segment_neighbourhoods` at the midpoints)
gives every sample its K neighbours in that item's cloud, gathered to (S, K, 3) at once. The items
are concatenated into one batch (batch norm sees all of it), the network runs in train mode and the
loss is ``method.loss(prediction, targets)``. The loss is checked for NaN/inf and
reported to ``progress(step=..., loss=...)`` every ``budget.log_every`` steps (a non-finite loss
raises :class:`methods.core.fitting.FittingError`); the model comes back in eval mode with ``knn_k`` set
(the K the grid queries need, :mod:`methods.pointcloud.knn.query`).

Seeding: ``seed`` seeds torch's generator before the network is built (its initialisation,
:func:`methods.core.device.seeded_generator`, which also turns on deterministic algorithms on the CPU)
and the batch Generator ``SeedSequence(seed).spawn(2)[1]`` (shapes, clouds, samples of every
step); pools built inside :func:`train` use the same ``seed``. On the CPU the same seed gives the
same weights bit for bit (same thread count; the KD-tree is exact and deterministic).

Weights: :func:`knn_model_to_bytes` / :func:`knn_model_from_bytes` (the network rebuilt by
``make_knn_network(**config)``); :func:`training_set_digest` names a training set for the cache key
(training set, method, budget, code) of the run layer.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from benchmark.fields import ExactFields
from benchmark.sampler import sample_training_data
from benchmark.surface import sample_surface
from datasets import MeshError, Shape, get_dataset
from datasets.builtin import VARIANTS, generate_shape
from methods.base import LearnedPointCloudMethod
from methods.core.device import get_device, seeded_generator
from methods.core.weights import weights_from_bytes, weights_to_bytes
from methods.core.training_loop import FittingError, run_steps
from methods.pointcloud.knn.network import KNN_BUDGETS, KNNBudget, knn_neighbourhoods, make_knn_network, segment_neighbourhoods

__all__ = ["TEST_SEED", "DEFAULT_TRAINING_SEED", "TrainingSetError", "training_shapes", "builtin_test_hashes",
           "training_set_digest", "ShapePool", "TrainingPools", "KNNTrainResult", "train", "knn_model_to_bytes",
           "knn_model_from_bytes", "get_knn_budget", "KNNTrainedMethod"]

#: Generator seed of the built-in test dataset (``get_dataset('builtin')``'s default).
TEST_SEED = 0
#: Generator seed of the built-in training parts (anything but :data:`TEST_SEED`).
DEFAULT_TRAINING_SEED = 1


class TrainingSetError(ValueError):
    """A training set that would overlap the test shapes, or cannot be built; one-line message."""


def get_knn_budget(budget: str | KNNBudget, overrides: dict | None = None) -> KNNBudget:
    """A :class:`KNNBudget` by name in :data:`KNN_BUDGETS` (or the budget itself), with ``overrides``
    of :data:`methods.pointcloud.knn.network.KNN_BUDGET_PARAMS` applied (typed, checked)."""
    from benchmark.params import with_overrides
    from methods.pointcloud.knn.network import KNN_BUDGET_PARAMS

    base = budget if isinstance(budget, KNNBudget) else KNN_BUDGETS.get(budget)
    return with_overrides(base, overrides, KNN_BUDGET_PARAMS, "budget")


# --------------------------------------------------------------------------------------------------
# The training set
# --------------------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=None)
def _builtin(index: int, kind: str, seed: int) -> Shape | None:
    """``generate_shape(index, kind, seed)``, cached per process; None when it cannot be generated."""
    try:
        return generate_shape(index, kind, seed)
    except MeshError:
        return None


@functools.lru_cache(maxsize=None)
def _builtin_hash(index: int, kind: str, seed: int) -> tuple[str, str] | None:
    """(content hash, name) of ``generate_shape(index, kind, seed)``, cached per process (the hash
    only: the test shapes' arrays are not kept); None when it cannot be generated."""
    try:
        shape = generate_shape(index, kind, seed)
    except MeshError:
        return None
    return shape.content_hash, shape.name


def builtin_test_hashes(count: int, seed: int = TEST_SEED) -> dict[str, str]:
    """Content hash -> name of every built-in shape of ``seed`` with index < ``count``, in every
    variant: all the shapes any built-in test dataset of up to ``count`` shapes can hold."""
    out = {}
    for index in range(int(count)):
        for kind in VARIANTS:
            known = _builtin_hash(index, kind, int(seed))
            if known is not None:
                out[known[0]] = known[1]
    return out


def _training_part(index: int, seed: int) -> Shape:
    """Part ``index`` of the training set: variant ``VARIANTS[index % 3]``, or the next one that
    can be generated."""
    for step in range(len(VARIANTS)):
        kind = VARIANTS[(index + step) % len(VARIANTS)]
        shape = _builtin(index, kind, seed)
        if shape is not None:
            return dataclasses.replace(shape, name=f"train{seed}_{shape.name}", meta=dict(shape.meta))
    raise TrainingSetError(f"built-in part {index} (seed {seed}) cannot be generated in any variant")


def training_shapes(count: int = 200, seed: int = DEFAULT_TRAINING_SEED, extra_dirs: Sequence[Path] = (),
                    test_count: int | None = None) -> list[Shape]:
    """The training shapes of the learned reconstruction methods (module docstring).

    Parameters
    ----------
    count : built-in parts, indices ``0 .. count - 1``, variants cycling closed, open, nonmanifold.
    seed : their generator seed; must differ from :data:`TEST_SEED`.
    extra_dirs : folders whose every mesh (the ``meshes`` dataset, canonical frame) is added after
        the parts, folder by folder, in the dataset's (sorted) order.
    test_count : the built-in test shapes checked against, indices ``< test_count`` at
        :data:`TEST_SEED` in every variant (default ``count``).

    Raises
    ------
    TrainingSetError : ``seed`` is the test seed, or a training shape has the content hash of a
        built-in test shape (the message names both).
    datasets.MeshError, datasets.DatasetError : an extra folder's mesh is unusable, or a folder is
        missing / holds no mesh.
    """
    count, seed = int(count), int(seed)
    if count < 0:
        raise TrainingSetError(f"training shape count must be >= 0, got {count}")
    if seed == TEST_SEED:
        raise TrainingSetError(f"training seed {seed} is the built-in test dataset's seed; use another one")
    shapes = [_training_part(index, seed) for index in range(count)]
    for folder in extra_dirs:
        dataset = get_dataset("meshes", data_dir=Path(folder))
        shapes += [dataset.load(name) for name in dataset.names()]
    tests = builtin_test_hashes(count if test_count is None else test_count)
    for shape in shapes:
        if shape.content_hash in tests:
            raise TrainingSetError(f"training shape '{shape.name}' is the built-in test shape "
                                   f"'{tests[shape.content_hash]}' (content hash {shape.content_hash})")
    return shapes


def training_set_digest(shapes: Sequence[Shape]) -> str:
    """16 hex digits of the SHA-256 of the sorted ``content_hash name`` lines of ``shapes``: the
    training set's part of the weights' cache key (independent of the list's order)."""
    lines = sorted(f"{s.content_hash} {s.name}" for s in shapes)
    return hashlib.sha256("\n".join(lines).encode()).hexdigest()[:16]


# --------------------------------------------------------------------------------------------------
# Pools
# --------------------------------------------------------------------------------------------------

def _streams(seed: int) -> tuple[np.random.SeedSequence, np.random.SeedSequence]:
    """(pool stream, batch stream) of a training seed."""
    pools, batches = np.random.SeedSequence(int(seed)).spawn(2)
    return pools, batches


@dataclass
class ShapePool:
    """One training shape's pools, float32: ``anchors`` (M, 3) points or (M, 2, 3) segments,
    ``targets`` {name: (M, ...)}, ``cloud`` (P, 3) surface points."""

    name: str
    anchors: np.ndarray
    targets: dict[str, np.ndarray]
    cloud: np.ndarray

    def __len__(self) -> int:
        return len(self.anchors)


def _label(method, shape: Shape, budget: KNNBudget, rng: np.random.Generator) -> ShapePool:
    samples = sample_training_data(shape.vertices, shape.faces, budget.pool_samples, rng)
    cloud, _ = sample_surface(shape.vertices, shape.faces, budget.pool_points, rng)
    targets = {}
    for key, value in method.training_targets(ExactFields(shape.vertices, shape.faces), samples).items():
        value = np.asarray(value)
        if len(value) != len(samples):
            raise FittingError(f"target '{key}' of training shape '{shape.name}' has {len(value)} rows for "
                               f"{len(samples)} samples")
        if value.dtype.kind == "f" and not np.all(np.isfinite(value)):
            raise FittingError(f"target '{key}' of training shape '{shape.name}' contains NaN or infinite values")
        targets[key] = np.ascontiguousarray(value, dtype=np.float32)
    anchors = samples.segments if method.network_kind == "segment" else samples.points
    return ShapePool(shape.name, np.ascontiguousarray(anchors, dtype=np.float32), targets,
                     np.ascontiguousarray(cloud, dtype=np.float32))


class TrainingPools:
    """The labelled and surface pools of every training shape (module docstring), for one method.

    ``TrainingPools(method, shapes, budget, seed=0, progress=None)``; ``progress(done=i, total=n,
    name=shape name)`` after each shape. Attributes: ``pools`` (list of :class:`ShapePool`),
    ``kind`` (the method's ``network_kind``), ``seconds`` (sampling + labelling wall time).
    """

    def __init__(self, method, shapes: Sequence[Shape], budget: str | KNNBudget, seed: int = 0,
                 progress: Callable[..., None] | None = None):
        budget = get_knn_budget(budget)
        if method.network_kind not in ("segment", "point"):
            raise ValueError(f"method '{method.name}': network_kind must be 'segment' or 'point', "
                             f"got '{method.network_kind}'")
        if not shapes:
            raise FittingError("no training shapes")
        self.kind = method.network_kind
        self.seed = int(seed)
        t0 = time.perf_counter()
        self.pools: list[ShapePool] = []
        for i, (shape, child) in enumerate(zip(shapes, _streams(seed)[0].spawn(len(shapes)))):
            self.pools.append(_label(method, shape, budget, np.random.default_rng(child)))
            if progress is not None:
                progress(done=i + 1, total=len(shapes), name=shape.name)
        self.seconds = time.perf_counter() - t0

    def __len__(self) -> int:
        return len(self.pools)

    def batch(self, budget: KNNBudget, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict]:
        """One training batch: (anchors (B, 3) or (B, 2, 3), neighbours (B, K, 3), targets {name: (B, ...)}),
        float32, ``B = shapes_per_batch x samples_per_item``, items in order (module docstring)."""
        n, items = len(self.pools), budget.shapes_per_batch
        chosen = rng.choice(n, size=items, replace=items > n)
        S, P = budget.samples_per_item, budget.points_per_item
        anchors, neighbours, targets = [], [], {k: [] for k in self.pools[0].targets}
        for index in chosen:
            pool = self.pools[index]
            cloud = pool.cloud[rng.choice(len(pool.cloud), size=P, replace=False)]
            rows = rng.integers(0, len(pool), size=S)
            a = pool.anchors[rows]
            nearest = segment_neighbourhoods if self.kind == "segment" else knn_neighbourhoods
            neighbours.append(cloud[nearest(cloud, a, budget.k)])
            anchors.append(a)
            for key, value in pool.targets.items():
                targets[key].append(value[rows])
        return (np.concatenate(anchors), np.concatenate(neighbours),
                {k: np.concatenate(v) for k, v in targets.items()})


# --------------------------------------------------------------------------------------------------
# Training
# --------------------------------------------------------------------------------------------------

@dataclass
class KNNTrainResult:
    """model (eval mode, ``knn_k`` set), per-step losses (float32, length ``steps``), training wall
    seconds (the step loop; pools excluded), steps, samples per second (``steps x B / seconds``),
    final loss (mean of the last ``log_every`` steps), pool seconds (sampling + labelling)."""

    model: torch.nn.Module
    losses: np.ndarray
    seconds: float
    steps: int
    samples_per_s: float
    final_loss: float = float("nan")
    pool_seconds: float = 0.0


def train(method, shapes: Sequence[Shape], budget: str | KNNBudget, seed: int = 0, device=None,
          progress: Callable[..., None] | None = None, pools: TrainingPools | None = None) -> KNNTrainResult:
    """Train ``method``'s K-NN network across ``shapes`` under ``budget`` (module docstring).

    Parameters
    ----------
    method : a :class:`methods.base.LearnedPointCloudMethod` (``network_kind``, ``output_dim``,
        ``training_targets``, ``loss``).
    shapes : the training shapes (:func:`training_shapes`); ignored when ``pools`` is given.
    budget : a :class:`KNNBudget` or its name in :data:`KNN_BUDGETS`.
    seed : network initialisation, batch draws and (when built here) the pools.
    device : torch device (default :func:`methods.core.device.get_device`).
    progress : ``progress(step=int, loss=float)`` every ``budget.log_every`` steps and at the last.
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
    rng = np.random.default_rng(_streams(seed)[1])
    model = make_knn_network(method.network_kind, out_dim=method.output_dim, **budget.network_config()).to(device)
    optimizer = torch.optim.AdamW(model.parameters(), lr=budget.lr, weight_decay=budget.weight_decay)
    T = int(budget.steps)

    def step_loss(step: int) -> torch.Tensor:
        a, q, t = pools.batch(budget, rng)
        anchors = torch.from_numpy(a).to(device)
        targets = {k: torch.from_numpy(v).to(device) for k, v in t.items()}
        return method.loss(model(anchors, torch.from_numpy(q).to(device)), targets)

    result = run_steps(model, optimizer, T, step_loss, log_every=budget.log_every,
                       where=lambda i: f"step {i} of {T} (method '{method.name}', knn budget '{budget.name}', seed {seed})",
                       progress=progress, device=device)
    model.knn_k = budget.k
    B = budget.shapes_per_batch * budget.samples_per_item
    return KNNTrainResult(model=model, losses=result.losses, seconds=result.seconds, steps=T,
                          samples_per_s=T * B / max(result.seconds, 1e-9), final_loss=result.final_loss,
                          pool_seconds=pools.seconds)


# --------------------------------------------------------------------------------------------------
# Weights as bytes (the run layer stores them checksummed, benchmark.storage)
# --------------------------------------------------------------------------------------------------

def knn_model_to_bytes(model, budget: str | KNNBudget, method_name: str, final_loss: float) -> bytes:
    """``torch.save`` bytes of ``{'state_dict', 'config' (network), 'budget', 'method', 'final_loss'}``
    (:func:`methods.core.weights.weights_to_bytes`)."""
    return weights_to_bytes(model, get_knn_budget(budget).to_dict(), method_name, final_loss)


def knn_model_from_bytes(data: bytes, device=None, method_name: str | None = None):
    """(model in eval mode on ``device``, ``knn_k`` set from the stored budget, final loss) from
    :func:`knn_model_to_bytes`' bytes, the network rebuilt by ``make_knn_network(**config)``.
    ``method_name``, when given, must match the stored one."""
    model, blob = weights_from_bytes(data, make_knn_network, device, method_name, what="K-NN weights")
    model.knn_k = int(blob["budget"]["k"])
    return model, float(blob["final_loss"])


class KNNTrainedMethod(LearnedPointCloudMethod):
    """A learned reconstruction method whose network is the shared K-NN local network, trained by
    :func:`train` (``network_kind``, ``output_dim``, ``training_targets``, ``loss``)."""

    training_modules = ("methods.pointcloud.knn.training",)

    def train_network(self, shapes, budget, seed, device=None, progress=None) -> KNNTrainResult:
        return train(self, shapes, budget, seed=seed, device=device, progress=progress)

    def network_to_bytes(self, trained: KNNTrainResult, budget) -> bytes:
        return knn_model_to_bytes(trained.model, budget, self.name, trained.final_loss)

    def network_from_bytes(self, data: bytes, device=None):
        return knn_model_from_bytes(data, device=device, method_name=self.name)[0]

"""The training set of the learned point-cloud methods, and each training shape's labelled pools.

A learned point-cloud method (:class:`methods.base.LearnedPointCloudMethod`) trains one network
once across many shapes, disjoint from every test shape, then reconstructs every test cloud with
it. Every learned method's budget carries the :class:`TrainingSet` fields below, which say how many
shapes and how large their pools are.

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
Then every mesh of each ``extra_dirs`` folder (``--train-dir``), loaded in the canonical frame by
the ``meshes`` dataset (and checked against the same hashes).

Generation is cached per process (:func:`functools.lru_cache` on (index, kind, seed): the training
shapes, and only the (hash, name) of the test shapes), so a second call (the cache key of the
weights, then the training) generates nothing; the list itself is built eagerly, since every shape
is labelled anyway.

Pools (:class:`TrainingPools`)
------------------------------
Per training shape: ``budget.pool_samples`` samples of the shared five-group sampler
(:func:`foundation.sampler.sample_training_data`), labelled by ``method.training_targets`` with the
shape's :class:`foundation.fields.ExactFields`, keeping the network's anchors only (segments (M, 2, 3)
for a ``'segment'`` method, points (M, 3) for a ``'point'`` one), and ``budget.pool_points``
area-uniform surface points (:func:`foundation.surface.sample_surface`), everything float32. All the
draws of shape ``i`` come from its own Generator (:func:`foundation.seeding.training_streams`): the
same (shapes, budget, seed) gives the same pools, in any process. Non-finite labels raise
:class:`methods.core.training_loop.FittingError` naming the shape.
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

from foundation.fields import ExactFields
from foundation.params import Param, setting
from foundation.sampler import sample_training_data
from foundation.seeding import training_streams
from foundation.surface import sample_surface
from datasets import MeshError, Shape, get_dataset
from datasets.builtin import VARIANTS, generate_shape
from methods.core.training_loop import FittingError, run_steps


@dataclass(frozen=True, kw_only=True)
class TrainingSet:
    """The budget fields of a learned point-cloud method's training set (every learned method's
    budget record subclasses this): ``training_shapes`` built-in parts (plus any ``--train-dir``
    meshes), and per training shape a pool of ``pool_samples`` labelled samples and one of
    ``pool_points`` surface points."""

    training_shapes: int = setting(Param(100, "built-in training parts", ge=1), override=True)
    pool_samples: int = setting(Param(1_000_000, "labelled samples per training shape", ge=1), override=True)
    pool_points: int = setting(Param(1_000_000, "surface points per training shape", ge=1), override=True)


@dataclass
class TrainResult:
    """What training a learned method's network returns: ``model`` (eval mode), per-step
    ``losses`` (float32, length ``steps``), ``seconds`` of the step loop (pools excluded),
    ``steps``, ``samples_per_s`` (``steps x batch / seconds``), ``final_loss`` (mean of the last
    reported steps) and ``pool_seconds`` (sampling + labelling)."""

    model: torch.nn.Module
    losses: np.ndarray
    seconds: float
    steps: int
    samples_per_s: float
    final_loss: float = float("nan")
    pool_seconds: float = 0.0


#: Generator seed of the built-in test dataset (``get_dataset('builtin')``'s default).
TEST_SEED = 0


#: Generator seed of the built-in training parts (anything but :data:`TEST_SEED`).
DEFAULT_TRAINING_SEED = 1


class TrainingSetError(ValueError):
    """A training set that would overlap the test shapes, or cannot be built; one-line message."""


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


def _label(method, shape: Shape, budget: TrainingSet, rng: np.random.Generator) -> ShapePool:
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

    def __init__(self, method, shapes: Sequence[Shape], budget: TrainingSet, seed: int = 0,
                 progress: Callable[..., None] | None = None):
        if method.network_kind not in ("segment", "point"):
            raise ValueError(f"method '{method.name}': network_kind must be 'segment' or 'point', "
                             f"got '{method.network_kind}'")
        if not shapes:
            raise FittingError("no training shapes")
        self.kind = method.network_kind
        self.seed = int(seed)
        t0 = time.perf_counter()
        self.pools: list[ShapePool] = []
        for i, (shape, child) in enumerate(zip(shapes, training_streams(seed).shape_streams(len(shapes)))):
            self.pools.append(_label(method, shape, budget, np.random.default_rng(child)))
            if progress is not None:
                progress(done=i + 1, total=len(shapes), name=shape.name)
        self.seconds = time.perf_counter() - t0

    def __len__(self) -> int:
        return len(self.pools)


def train_steps(method, model: torch.nn.Module, optimizer: torch.optim.Optimizer, budget, family: str,
                step_loss: Callable[[int], torch.Tensor], *, seed: int, batch: int, pool_seconds: float,
                device, progress: Callable[..., None] | None = None) -> TrainResult:
    """``budget.steps`` optimizer steps of ``step_loss`` (:func:`methods.core.training_loop.run_steps`:
    every ``budget.log_every`` steps a loss check and ``progress(step=..., loss=..., total=steps)``; a
    non-finite loss names the step, the method, the ``family`` budget and the seed), as a
    :class:`TrainResult` of ``batch`` samples per step."""
    steps = int(budget.steps)
    report = None if progress is None else lambda step, loss: progress(step=step, loss=loss, total=steps)
    result = run_steps(model, optimizer, steps, step_loss, log_every=budget.log_every,
                       where=lambda i: (f"step {i} of {steps} (method '{method.name}', {family} budget "
                                        f"'{budget.name}', seed {seed})"),
                       progress=report, device=device)
    return TrainResult(model=model, losses=result.losses, seconds=result.seconds, steps=steps,
                       samples_per_s=steps * batch / max(result.seconds, 1e-9), final_loss=result.final_loss,
                       pool_seconds=pool_seconds)


#: Training shapes whose clouds measure the training density (:func:`training_neighbour_distance`).
DENSITY_SHAPES = 8


@functools.lru_cache(maxsize=None)
def training_neighbour_distance(points: int, seed: int = DEFAULT_TRAINING_SEED) -> float:
    """Mean distance of a training cloud's points to their nearest other point (canonical units):
    ``points`` area-uniform points on each of the first :data:`DENSITY_SHAPES` training parts,
    averaged over the parts. The density a learned network was trained at."""
    from pykdtree.kdtree import KDTree

    means = []
    shapes = training_shapes(DENSITY_SHAPES, seed)
    for shape, stream in zip(shapes, np.random.SeedSequence([int(seed), int(points)]).spawn(len(shapes))):
        cloud, _ = sample_surface(shape.vertices, shape.faces, int(points), np.random.default_rng(stream))
        dist, _ = KDTree(cloud).query(cloud, k=2)
        means.append(float(np.mean(np.asarray(dist).reshape(-1, 2)[:, 1])))
    return float(np.mean(means))

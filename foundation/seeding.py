"""Where every random number of a job comes from (the project's one seed derivation).

One :class:`numpy.random.SeedSequence` per (shape, seed)::

    root = SeedSequence([seed, int(sha256(shape_hash), 16)])
    sampler, fitting, metrics, calibration = root.spawn(4)

* ``sampler`` -> the ``numpy.random.Generator`` of the shared training sampler
  (:mod:`foundation.sampler`): every method of a shape and seed sees the same samples.
* ``fitting`` -> a 63-bit integer for ``torch.manual_seed`` and the batch-order generator
  (:mod:`methods.core.fitting`): network initialisation and batch order.
* ``metrics`` -> the SeedSequence :func:`foundation.metrics.evaluate` spawns its streams from
  (child 0: GT samples, child 1: prediction samples, child 2: the IoU's points), so every
  prediction of a shape and the floor row are scored against the same GT samples.
* ``calibration`` -> the generator of a method's calibration after its fit
  (:meth:`methods.base.FieldMethod.calibrate`, e.g. SALS's per-shape o threshold). Spawned fourth, so
  the three streams above are those of a three-way spawn.

A network trained once across shapes (the learned point-cloud methods, the UNDC networks) draws
from its training seed alone: ``pools, batches = SeedSequence(seed).spawn(2)``
(:func:`training_streams`); training shape i of n labels its pools from ``pools.spawn(n)[i]``, and
every batch draw comes from one Generator of ``batches``.

The shape enters by its content hash (``foundation.storage.mesh_hash``), never by its name or position,
so results do not depend on the order of shapes, the executor or the process.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

#: Seeds are stored as SQLite INTEGERs: [0, 2^63).
MAX_SEED = 2**63 - 1


def shape_entropy(shape_hash: str) -> int:
    """An integer from a shape's content hash (any string: it is hashed again)."""
    return int(hashlib.sha256(str(shape_hash).encode()).hexdigest(), 16)


def job_seed_sequence(shape_hash: str, seed: int) -> np.random.SeedSequence:
    """The root SeedSequence of (shape, seed)."""
    seed = int(seed)
    if not 0 <= seed <= MAX_SEED:
        raise ValueError(f"seed must lie in [0, 2^63), got {seed}")
    return np.random.SeedSequence([seed, shape_entropy(shape_hash)])


@dataclass(frozen=True)
class JobStreams:
    """The independent streams of one (shape, seed) (module docstring)."""

    sampler: np.random.SeedSequence
    fitting: np.random.SeedSequence
    metrics: np.random.SeedSequence
    calibration: np.random.SeedSequence

    def sampler_rng(self) -> np.random.Generator:
        return np.random.default_rng(self.sampler)

    def fitting_seed(self) -> int:
        """A 63-bit integer for ``torch.manual_seed`` (deterministic for the stream)."""
        return int(self.fitting.generate_state(2, dtype=np.uint32).astype(np.uint64) @ np.array([1, 2**32], dtype=np.uint64)) & MAX_SEED


def job_streams(shape_hash: str, seed: int) -> JobStreams:
    """Spawn the sampler, fitting, metric and calibration streams of (shape, seed)."""
    return JobStreams(*job_seed_sequence(shape_hash, seed).spawn(4))


@dataclass(frozen=True)
class TrainingStreams:
    """The streams of a network trained once across shapes from one training ``seed``: ``pools``
    spawns one child per training shape (its samples, labels and surface points), ``batches``
    seeds the Generator of every batch draw."""

    pools: np.random.SeedSequence
    batches: np.random.SeedSequence

    def shape_streams(self, count: int) -> list[np.random.SeedSequence]:
        """The pool streams of ``count`` training shapes, shape i's at index i."""
        return self.pools.spawn(int(count))

    def batch_rng(self) -> np.random.Generator:
        return np.random.default_rng(self.batches)


def training_streams(seed: int) -> TrainingStreams:
    """``SeedSequence(seed).spawn(2)``: the pool and batch streams of a training seed."""
    return TrainingStreams(*np.random.SeedSequence(int(seed)).spawn(2))

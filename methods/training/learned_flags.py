"""Training the learned intersection flags of ``sals-ndc`` (:mod:`methods.extractors.learned_flags`)
on *fitted* SALS fields, so the network learns the fitting error it is to correct.

Recipe:

* Shapes: :func:`methods.pointcloud.training_set.training_shapes` (the built-in CAD-like parts at the
  training seed, checked against the built-in test shapes by content hash) plus, with ``thingi``,
  the Thingi10K meshes of ``../shared/data/thingi10k``: no ABC part, no built-in evaluation shape.
* Per shape, as an encode job of ``sals`` with the seed ``seed`` would: the shared sampler on the
  job's sampler stream, the SALS fit under the budget's ``fit_budget`` (the job's fitting seed),
  then the fitted field on the grid's band (:func:`methods.core.segment_field.band_field`, ``o_low``)
  as the network's input (:func:`methods.extractors.learned_flags.network_input`); labels: the exact
  grid-edge crossings of the same grid (:meth:`foundation.fields.ExactFields.grid_edges`); the loss
  covers the candidate edges only (o_hat > ``o_low``), the only ones the extractor can flag.
* Batches: ``batch`` crops of ``crop``^3 output points, each of a random shape, centred on a random
  candidate edge's start point (shifted inside the grid); loss: BCE from the logits over the
  candidate edges of the batch, normalised by their count. No augmentation: the field's channels
  are tied to the axes and to the edges' direction.
* Optimiser: Adam at ``lr``, halved every ``lr_half_life`` steps; NDC's CNN_3d_rec7 with
  ``channels`` channels (:class:`methods.extractors.rec7.Rec7Network`).

Seeding: ``seed`` is each fit's seed (as a job's), initialises the network
(:func:`methods.core.device.seeded_generator`, deterministic algorithms on the CPU) and seeds the
crop generator: the same seed gives the same weights bit for bit on the CPU (same thread count).

``python -m methods.training.learned_flags --budget cpu --out PATH`` writes the weights file
(:func:`methods.extractors.learned_flags.save_weights`: the network, the budget, every training
shape's name and content hash, the losses and the seconds).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from foundation.params import Param, check_fields, setting
from foundation.sampler import sample_training_data
from foundation.seeding import job_streams
from methods.core import fitting
from methods.core.budgets import register_budget_family
from methods.core.device import seeded_generator
from methods.core.segment_field import band_field
from methods.core.training_loop import run_steps
from methods.extractors import learned_flags
from methods.extractors.rec7 import RECEPTIVE_PADDING, Rec7Network
from methods.pointcloud.training_set import DEFAULT_TRAINING_SEED, training_set_digest, training_shapes

#: The Thingi10K training meshes beside the checkout.
DEFAULT_THINGI_DIR = Path(__file__).resolve().parents[3] / "shared" / "data" / "thingi10k"


@dataclass(frozen=True)
class LearnedFlagsBudget:
    """How much training of ``sals-ndc``'s network (the budget family ``learned-flags``)."""

    name: str = setting(Param(kind=str, help="budget name"))
    shapes: int = setting(Param(kind=int, help="built-in training parts", ge=1))
    thingi: bool = setting(Param(kind=bool, help="also the Thingi10K meshes of the training folder"))
    grid: int = setting(Param(kind=int, help="grid points per axis of the training fields", ge=9))
    fit_budget: str = setting(Param(kind=str, help="the encode budget of the SALS fits"))
    o_low: float = setting(Param(kind=float, help="candidate edges: o_hat above this", gt=0, lt=1))
    channels: int = setting(Param(kind=int, help="convolution channels", ge=1))
    crop: int = setting(Param(kind=int, help="output grid points per side of a training crop", ge=1))
    batch: int = setting(Param(kind=int, help="crops per step", ge=1))
    steps: int = setting(Param(kind=int, help="Adam steps", ge=1))
    lr: float = setting(Param(kind=float, help="initial learning rate", gt=0))
    lr_half_life: int = setting(Param(kind=int, help="steps per halving of the learning rate (0: constant)", ge=0))
    log_every: int = setting(Param(kind=int, help="steps between loss checks and progress reports", ge=1))

    def __post_init__(self):
        check_fields(self, f"learned-flags budget '{self.name}'")


#: ``tiny``: tests (2 parts at 24^3, 40 steps). ``cpu``: 16 built-in parts and the Thingi10K
#: meshes, fitted at the ``cpu`` budget and read at 128^3 (the evaluation grid), 1,500 steps.
LEARNED_FLAGS_FAMILY = register_budget_family("learned-flags", (
    LearnedFlagsBudget("tiny", shapes=2, thingi=False, grid=24, fit_budget="tiny-grid", o_low=0.02, channels=8,
                       crop=8, batch=2, steps=40, lr=1e-3, lr_half_life=0, log_every=10),
    LearnedFlagsBudget("cpu", shapes=16, thingi=True, grid=128, fit_budget="cpu", o_low=0.02, channels=32,
                       crop=16, batch=4, steps=1500, lr=1e-3, lr_half_life=500, log_every=50),
))


@dataclass
class FieldItem:
    """One training shape's fitted field and labels: ``input`` (6, N + 6, ...) float16, ``labels``
    and ``candidates`` (3, N, N, N) bool, ``points`` (C, 3) the start points of its candidate edges."""

    name: str
    input: np.ndarray
    labels: np.ndarray
    candidates: np.ndarray
    points: np.ndarray


def fitted_field_item(shape, budget: LearnedFlagsBudget, seed: int) -> FieldItem:
    """A shape's SALS fit (as a ``sals`` job of seed ``seed`` fits it) read on the grid, with the
    exact crossings as labels (module docstring)."""
    from foundation.fields import ExactFields
    from methods.fields.sals import SALSMethod

    N, method = budget.grid, SALSMethod()
    streams = job_streams(shape.content_hash, seed)
    fit_budget = fitting.get_budget(budget.fit_budget)
    fields = ExactFields(shape.vertices, shape.faces)
    samples = sample_training_data(shape.vertices, shape.faces, fit_budget.num_samples, streams.sampler_rng())
    fit = fitting.fit(method, samples, method.training_targets(fields, samples), fit_budget,
                      seed=streams.fitting_seed(), device="cpu")
    ids, o, s, _ = band_field(fit.model, N, budget.o_low, "cpu")
    candidates = learned_flags.edge_labels(N, learned_flags.candidate_edges(ids, o, budget.o_low))
    labels = learned_flags.edge_labels(N, np.flatnonzero(fields.grid_edges(N).hit))
    return FieldItem(shape.name, learned_flags.network_input(N, ids, o, s).astype(np.float16), labels, candidates,
                     np.argwhere(candidates.any(axis=0)))


def draw_batch(items: Sequence[FieldItem], budget: LearnedFlagsBudget, rng: np.random.Generator) -> dict:
    """``budget.batch`` crops stacked into tensors: ``input`` (B, 6, crop + 6, ...), ``labels`` and
    ``mask`` (B, 3, crop, ...) float32 (module docstring)."""
    crops = {"input": [], "labels": [], "mask": []}
    pad = 2 * RECEPTIVE_PADDING
    for _ in range(budget.batch):
        item = items[int(rng.integers(len(items)))]
        N = item.labels.shape[1]
        size = min(budget.crop, N)
        centre = item.points[int(rng.integers(len(item.points)))]
        a = np.clip(centre - size // 2, 0, N - size)
        window = tuple(slice(int(x), int(x) + size) for x in a)
        crops["input"].append(item.input[(slice(None),) + tuple(slice(int(x), int(x) + size + pad) for x in a)])
        crops["labels"].append(item.labels[(slice(None),) + window])
        crops["mask"].append(item.candidates[(slice(None),) + window])
    return {k: torch.from_numpy(np.stack(v).astype(np.float32)) for k, v in crops.items()}


def flag_loss(logits: torch.Tensor, batch: dict) -> torch.Tensor:
    """BCE of the flags from the logits over the batch's candidate edges / their count."""
    bce = F.binary_cross_entropy_with_logits(logits, batch["labels"], reduction="none")
    return (bce * batch["mask"]).sum() / batch["mask"].sum().clamp(min=1.0)


@dataclass
class LearnedFlagsResult:
    """The network (eval mode), its per-step losses, the seconds of the fits and of the steps, and the
    training shapes (names and content hashes)."""

    network: Rec7Network
    losses: np.ndarray
    seconds: float
    fit_seconds: float
    names: tuple[str, ...]
    hashes: tuple[str, ...]
    training_set: str

    def info(self, budget: LearnedFlagsBudget, seed: int) -> dict:
        return {"budget": dataclasses.asdict(budget), "seed": int(seed), "training_set": self.training_set,
                "training_names": list(self.names), "training_hashes": list(self.hashes),
                "final_loss": float(self.losses[-budget.log_every:].mean()), "train_seconds": float(self.seconds),
                "fit_seconds": float(self.fit_seconds)}


def train(shapes: Sequence, budget: str | LearnedFlagsBudget, seed: int = 0,
          progress: Callable[..., None] | None = None) -> LearnedFlagsResult:
    """Fit every shape's SALS field and train the flag network on them (module docstring), on the CPU.
    ``progress(stage=..., **facts)`` reports the fits and the losses."""
    budget = LEARNED_FLAGS_FAMILY.get(budget)
    t0 = time.perf_counter()
    items = []
    for done, shape in enumerate(shapes, start=1):
        items.append(fitted_field_item(shape, budget, seed))
        if progress is not None:
            progress(stage="fit", done=done, total=len(shapes), name=shape.name)
    fit_seconds = time.perf_counter() - t0
    seeded_generator(seed, "cpu")
    network = Rec7Network(budget.channels, in_channels=learned_flags.IN_CHANNELS, out_channels=3)
    rng = np.random.default_rng(np.random.SeedSequence(int(seed)))
    optimizer = torch.optim.Adam(network.parameters(), lr=budget.lr)

    def learning_rate(group, step):
        return budget.lr * 0.5 ** (step // budget.lr_half_life) if budget.lr_half_life else budget.lr

    def step_loss(step):
        batch = draw_batch(items, budget, rng)
        return flag_loss(network(batch["input"]), batch)

    result = run_steps(network, optimizer, budget.steps, step_loss,
                       log_every=budget.log_every, learning_rate=learning_rate, device="cpu",
                       where=lambda i: f"step {i} of the sals-ndc network (budget '{budget.name}', seed {seed})",
                       progress=None if progress is None else (lambda **kw: progress(stage="train", **kw)))
    return LearnedFlagsResult(network, result.losses, result.seconds, fit_seconds, tuple(s.name for s in shapes),
                              tuple(s.content_hash for s in shapes), training_set_digest(shapes))


def learned_flags_training_shapes(budget: str | LearnedFlagsBudget, thingi_dir: Path = DEFAULT_THINGI_DIR) -> list:
    """The training shapes of ``budget``: its built-in training parts, plus the Thingi10K meshes of
    ``thingi_dir`` with ``thingi`` (none of them an evaluation shape: module docstring)."""
    budget = LEARNED_FLAGS_FAMILY.get(budget)
    return training_shapes(count=budget.shapes, seed=DEFAULT_TRAINING_SEED,
                           extra_dirs=[thingi_dir] if budget.thingi else [])


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m methods.training.learned_flags",
                                     description="Fit SALS on the training shapes, train sals-ndc's flag network "
                                                 "on the fitted fields and write the weights file.")
    parser.add_argument("--budget", default="cpu", choices=LEARNED_FLAGS_FAMILY.names())
    parser.add_argument("--out", type=Path, default=learned_flags.DEFAULT_WEIGHTS, help="weights file to write")
    parser.add_argument("--seed", type=int, default=0, help="the fits' seed, the initialisation's and the crops'")
    parser.add_argument("--thingi-dir", type=Path, default=DEFAULT_THINGI_DIR, help="Thingi10K training meshes")
    args = parser.parse_args(argv)
    budget = LEARNED_FLAGS_FAMILY.get(args.budget)
    shapes = learned_flags_training_shapes(budget, args.thingi_dir)

    def report(stage, **facts):
        if stage == "fit":
            print(f"fitted {facts['done']}/{facts['total']} {facts['name']}", file=sys.stderr, flush=True)
        else:
            print(f"step {facts['step']} loss {facts['loss']:.6f}", file=sys.stderr, flush=True)

    result = train(shapes, budget, seed=args.seed, progress=report)
    digest = learned_flags.save_weights(args.out, result.network, result.info(budget, args.seed))
    print(f"wrote {args.out} (sha256 {digest}; training set {result.training_set}, {len(shapes)} shapes; "
          f"{result.fit_seconds:.0f} s fitting, {result.seconds:.0f} s training)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Training UNDC's two networks (:mod:`methods.extractors.undc`) across a training set of shapes.

Recipe, after NDC's ``main.py`` / ``dataset.py`` for ``--method undc --input_type udf``:

* Shapes: :func:`methods.pointcloud.training_set.training_shapes` (built-in CAD-like parts at the training seed,
  checked against the built-in test shapes by content hash, plus every mesh of the Thingi10K folder
  ``../shared/data/thingi10k`` beside the checkout), none of the ABC test parts.
* Labels per shape and grid resolution (:data:`UNDCBudget.grids`; NDC's 32 and 64 cells, 33 and 65
  points): :func:`methods.extractors.undc.ground_truth` (exact UDF in voxel units, edge flags, QEF vertices).
* Batches: ``batch`` random crops of ``crop``^3 output points, each of a random (shape, grid) item,
  centred on a random point of NDC's valid region (a point with a masked edge or a cell with a
  target) and shifted to lie inside the grid; the input is the crop's (crop + 6)^3 window of the
  padded, clipped input grid. NDC trains one shape's whole bounding box per step instead.
* Augmentation, as NDC's ``read_and_augment_data_undc``: one of the 6 axis permutations and one of
  the 8 axis reversals per crop (a reversed axis moves its edges' start points by one and mirrors
  the vertex coordinate, ``x -> 1 - x``); the sign inversion is moot for the UDF (``|udf|``).
* Losses: the bool network's BCE (from the logits) over the edges whose end points both have UDF
  < 1 voxel; the float network's squared error over the 3 coordinates of the cells with a target;
  both normalised by the mask's count, as NDC's.
* Optimiser: Adam (NDC: lr 1e-4, halved every 100 of 400 epochs), lr halved every
  ``lr_half_life`` steps; the two networks are trained one after the other, each for its steps.

Seeding: ``seed`` seeds torch (both networks' initialisation, bool first,
:func:`methods.core.device.seeded_generator`, which turns on deterministic algorithms on the CPU) and the
crop Generators ``SeedSequence(seed).spawn(2)`` (bool, float). On the CPU the same seed gives the
same weights bit for bit (same thread count).

``python -m methods.training.undc --budget cpu --out PATH`` trains both networks and writes the weights
file (:func:`methods.extractors.undc.save_weights`: both state dicts, the budget, the training-set digest and
the final losses).
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

from foundation.fields import ExactFields
from foundation.params import Param, check_fields, setting
from methods.core.budgets import register_budget_family
from methods.extractors import undc
from methods.core.device import seeded_generator
from methods.pointcloud.training_set import DEFAULT_TRAINING_SEED, training_set_digest, training_shapes
from methods.core.training_loop import run_steps

#: The Thingi10K training meshes beside the checkout.
DEFAULT_THINGI_DIR = Path(__file__).resolve().parents[3] / "shared" / "data" / "thingi10k"

#: NDC's axis permutations (new axis i is old axis ``perm[i]``).
PERMUTATIONS = ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0))


@dataclass(frozen=True)
class UNDCBudget:
    """How much UNDC training: shapes, grids, crops and steps (the budget family ``undc``).

    name : the budget's name.
    shapes : built-in training parts (indices 0 .. shapes - 1 at the training seed).
    thingi : also the Thingi10K meshes of the training folder.
    grids : grid resolutions (points per axis) every shape is labelled at.
    crop : output grid points per side of a training crop (input: crop + 6).
    batch : crops per step.
    bool_steps, float_steps : Adam steps of the bool and of the float network.
    lr : initial learning rate; ``lr_half_life``: steps per halving (0: constant).
    channels : convolution channels of both networks (NDC: 64).
    log_every : loss checks / progress reports every so many steps.
    """

    name: str = setting(Param(kind=str, help="budget name"))
    shapes: int = setting(Param(kind=int, help="built-in training parts", ge=1))
    thingi: bool = setting(Param(kind=bool, help="also the Thingi10K meshes of the training folder"))
    grids: tuple[int, ...] = setting(Param(kind=tuple, item=int, help="grid points per axis of each labelling", ge=9))
    crop: int = setting(Param(kind=int, help="output grid points per side of a training crop", ge=1))
    batch: int = setting(Param(kind=int, help="crops per step", ge=1))
    bool_steps: int = setting(Param(kind=int, help="Adam steps of the bool network", ge=1))
    float_steps: int = setting(Param(kind=int, help="Adam steps of the float network", ge=1))
    lr: float = setting(Param(kind=float, help="initial learning rate", gt=0))
    lr_half_life: int = setting(Param(kind=int, help="steps per halving of the learning rate (0: constant)", ge=0))
    channels: int = setting(Param(kind=int, help="convolution channels of both networks", ge=1))
    log_every: int = setting(Param(kind=int, help="steps between loss checks and progress reports", ge=1))

    def __post_init__(self):
        check_fields(self, f"UNDC budget '{self.name}'")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


#: The named budgets. ``tiny``: for tests. ``cpu``: both networks on one CPU core (its cost:
#: docs/PROTOCOL.md, "UNDC on the UDF") (1,200 Adam steps each of 2 crops of 16^3 output points, lr 1e-3
#: halved every 400 steps: NDC's 1e-4 is for millions of steps), after labelling 60 parts and the
#: Thingi10K meshes at 33^3 and 65^3.
UNDC_FAMILY = register_budget_family("undc", (
    UNDCBudget("tiny", shapes=2, thingi=False, grids=(33,), crop=8, batch=2, bool_steps=30,
               float_steps=30, lr=1e-3, lr_half_life=0, channels=8, log_every=5),
    UNDCBudget("cpu", shapes=60, thingi=True, grids=(33, 65), crop=16, batch=2, bool_steps=1200,
               float_steps=1200, lr=1e-3, lr_half_life=400, channels=undc.DEFAULT_CHANNELS, log_every=100),
))


def get_undc_budget(budget: str | UNDCBudget) -> UNDCBudget:
    """A budget of the ``undc`` family by name (unknown names list the known ones), or the budget itself."""
    return UNDC_FAMILY.get(budget)


def undc_training_shapes(budget: str | UNDCBudget, seed: int = DEFAULT_TRAINING_SEED,
                         thingi_dir: str | Path = DEFAULT_THINGI_DIR) -> list:
    """The training shapes of ``budget`` (:func:`methods.pointcloud.training_set.training_shapes`)."""
    budget = get_undc_budget(budget)
    return training_shapes(budget.shapes, seed, (Path(thingi_dir),) if budget.thingi else ())


# --------------------------------------------------------------------------------------------------
# Labelled items and augmented crops
# --------------------------------------------------------------------------------------------------

@dataclass
class LabelledItem:
    """One (shape, grid) item: the padded, clipped input grid (N + 6)^3 and the labels
    (:class:`methods.extractors.undc.UNDCLabels`), and the valid points (V, 3) crops are centred on."""

    name: str
    N: int
    grid: np.ndarray
    labels: undc.UNDCLabels
    valid: np.ndarray


def label_items(shapes: Sequence, grids: Sequence[int], progress: Callable[..., None] | None = None) -> list[LabelledItem]:
    """Label every shape at every grid resolution; ``progress(done=, total=, name=)`` per shape."""
    items = []
    for i, shape in enumerate(shapes):
        fields = ExactFields(shape.vertices, shape.faces)
        for N in grids:
            labels = undc.ground_truth(fields, int(N))
            valid = np.argwhere(labels.edge_mask.any(axis=-1) | labels.cell_mask)
            if len(valid):
                items.append(LabelledItem(shape.name, int(N), undc.network_input(labels.udf_voxels), labels, valid))
        if progress is not None:
            progress(done=i + 1, total=len(shapes), name=shape.name)
    if not items:
        raise ValueError("no training shape has a surface near its grid points")
    return items


def _original_indices(start: np.ndarray, size: int, n: int, permutation, reversal, shift: int) -> list[np.ndarray]:
    """Per original axis a, the original indices (along a) of the augmented positions
    ``start[i] .. start[i] + size - 1`` of augmented axis i = permutation^-1(a): ``n - 1 - shift - q``
    on a reversed axis, else q (may fall outside [0, n))."""
    out = [None] * 3
    for i in range(3):
        a = permutation[i]
        q = np.arange(start[i], start[i] + size)
        out[a] = (n - 1 - shift - q) if reversal[a] else q
    return out


def _take(array: np.ndarray, index: list[np.ndarray], permutation) -> tuple[np.ndarray, np.ndarray]:
    """``array[ix_(index)]`` (first 3 axes) in augmented axis order, and where every index was valid."""
    ok = [(ix >= 0) & (ix < array.shape[a]) for a, ix in enumerate(index)]
    clipped = [np.clip(ix, 0, array.shape[a] - 1) for a, ix in enumerate(index)]
    sub = array[np.ix_(*clipped)]
    valid = ok[0][:, None, None] & ok[1][None, :, None] & ok[2][None, None, :]
    return np.transpose(sub, tuple(permutation) + tuple(range(3, sub.ndim))), np.transpose(valid, permutation)


def augmented_crop(item: LabelledItem, start: np.ndarray, size: int, permutation, reversal) -> dict[str, np.ndarray]:
    """The crop of ``size``^3 output points at ``start`` (augmented frame) of ``item`` reversed along the
    axes a with ``reversal[a]`` and then transposed by ``permutation`` (NDC's order).

    Returns float32 arrays: ``input`` (1, size + 6, ...), ``flags`` and ``flag_mask`` (3, size, ...),
    ``offsets`` (3, size, ...) and ``cell_mask`` (1, size, ...). Augmented channel i is original
    channel ``permutation[i]``; on a reversed axis a the edges along a start one point earlier and the
    vertex coordinate a is ``1 - x``."""
    N, lab = item.N, item.labels
    pad = 2 * undc.RECEPTIVE_PADDING
    grid, _ = _take(item.grid, _original_indices(start, size + pad, N + pad, permutation, reversal, 0), permutation)
    plain = _original_indices(start, size, N, permutation, reversal, 0)
    flags = np.zeros((3, size, size, size), dtype=np.float32)
    flag_mask = np.zeros_like(flags)
    for i in range(3):
        a = permutation[i]
        index = list(plain)
        if reversal[a]:
            index[a] = index[a] - 1
        f, ok = _take(lab.edge_flags[..., a], index, permutation)
        m, _ = _take(lab.edge_mask[..., a], index, permutation)
        flags[i] = f & ok
        flag_mask[i] = m & ok
    cells = _original_indices(start, size, N, permutation, reversal, 1)
    values, ok = _take(lab.cell_offsets, cells, permutation)
    mask, _ = _take(lab.cell_mask, cells, permutation)
    values = values[..., list(permutation)]
    for i in range(3):
        if reversal[permutation[i]]:
            values[..., i] = 1.0 - values[..., i]
    mask = mask & ok
    offsets = np.where(mask[..., None], values, 0.0).astype(np.float32)
    return {"input": grid[None].astype(np.float32), "flags": flags, "flag_mask": flag_mask,
            "offsets": np.moveaxis(offsets, -1, 0), "cell_mask": mask[None].astype(np.float32)}


def draw_batch(items: Sequence[LabelledItem], budget: UNDCBudget, rng: np.random.Generator) -> dict[str, torch.Tensor]:
    """``budget.batch`` augmented crops (:func:`augmented_crop`) stacked into tensors (B, C, ...).
    Per crop: an item, a permutation, a reversal, a valid point (all uniform), the crop centred on
    the point's augmented position and shifted inside the grid."""
    crops = []
    for _ in range(budget.batch):
        item = items[int(rng.integers(len(items)))]
        permutation = PERMUTATIONS[int(rng.integers(len(PERMUTATIONS)))]
        reversal = tuple(int(r) for r in rng.integers(0, 2, size=3))
        point = item.valid[int(rng.integers(len(item.valid)))]
        flipped = np.where(reversal, item.N - 1 - point, point)
        centre = flipped[list(permutation)]
        size = min(budget.crop, item.N)
        start = np.clip(centre - size // 2, 0, item.N - size)
        crops.append(augmented_crop(item, start, size, permutation, reversal))
    return {k: torch.from_numpy(np.stack([c[k] for c in crops])) for k in crops[0]}


def bool_loss(logits: torch.Tensor, batch: dict) -> torch.Tensor:
    """NDC's masked BCE of the edge flags (from the logits): sum over masked edges / their count."""
    mask = batch["flag_mask"]
    bce = F.binary_cross_entropy_with_logits(logits, batch["flags"], reduction="none")
    return (bce * mask).sum() / mask.sum().clamp(min=1.0)


def float_loss(values: torch.Tensor, batch: dict) -> torch.Tensor:
    """NDC's masked squared error of the cell vertices: sum over the 3 coordinates of the cells with a
    target / (3 x their count)."""
    mask = batch["cell_mask"].expand_as(values)
    return (((values - batch["offsets"]) ** 2) * mask).sum() / mask.sum().clamp(min=1.0)


# --------------------------------------------------------------------------------------------------
# Training
# --------------------------------------------------------------------------------------------------

@dataclass
class UNDCTrainResult:
    """Both networks (eval mode), their per-step losses, the training seconds (step loops), the
    labelling seconds and the training-set digest."""

    bool_network: undc.UNDCNetwork
    float_network: undc.UNDCNetwork
    bool_losses: np.ndarray
    float_losses: np.ndarray
    seconds: float
    label_seconds: float
    training_set: str
    training_hashes: tuple[str, ...] = ()

    def info(self, budget: UNDCBudget, seed: int) -> dict:
        """What the weights file records beside the networks (with each training shape's content
        hash, so a result row can say whether its shape was seen in training)."""
        return {"budget": budget.to_dict(), "seed": int(seed), "training_set": self.training_set,
                "training_hashes": list(self.training_hashes),
                "bool_final_loss": float(self.bool_losses[-budget.log_every:].mean()),
                "float_final_loss": float(self.float_losses[-budget.log_every:].mean()),
                "train_seconds": float(self.seconds), "label_seconds": float(self.label_seconds)}


def train(shapes: Sequence, budget: str | UNDCBudget, seed: int = 0,
          progress: Callable[..., None] | None = None) -> UNDCTrainResult:
    """Train the bool and the float network on ``shapes`` under ``budget`` (module docstring), on the
    CPU. ``progress(stage=..., **facts)`` reports labelling and losses."""
    budget = get_undc_budget(budget)
    t0 = time.perf_counter()
    items = label_items(shapes, budget.grids,
                        None if progress is None else (lambda **kw: progress(stage="label", **kw)))
    label_seconds = time.perf_counter() - t0
    seeded_generator(seed, "cpu")
    networks = {"bool": undc.UNDCNetwork(budget.channels), "float": undc.UNDCNetwork(budget.channels)}
    streams = dict(zip(("bool", "float"), np.random.SeedSequence(int(seed)).spawn(2)))
    losses, seconds = {}, 0.0
    for kind, steps, loss_of in (("bool", budget.bool_steps, bool_loss), ("float", budget.float_steps, float_loss)):
        network, rng = networks[kind], np.random.default_rng(streams[kind])
        optimizer = torch.optim.Adam(network.parameters(), lr=budget.lr)

        def step_loss(step, network=network, rng=rng, loss_of=loss_of):
            batch = draw_batch(items, budget, rng)
            return loss_of(network(batch["input"]), batch)

        def learning_rate(group, step):
            return budget.lr * 0.5 ** (step // budget.lr_half_life) if budget.lr_half_life else budget.lr

        result = run_steps(network, optimizer, steps, step_loss, log_every=budget.log_every,
                           where=lambda i, kind=kind: f"step {i} of the UNDC {kind} network (budget '{budget.name}', seed {seed})",
                           learning_rate=learning_rate,
                           progress=None if progress is None else (lambda kind=kind, **kw: progress(stage=kind, **kw)),
                           device="cpu")
        losses[kind] = result.losses
        seconds += result.seconds
    return UNDCTrainResult(networks["bool"], networks["float"], losses["bool"], losses["float"], seconds,
                           label_seconds, training_set_digest(shapes), tuple(s.content_hash for s in shapes))


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m methods.training.undc",
                                     description="Train UNDC's bool and float networks and write the weights file.")
    parser.add_argument("--budget", default="cpu", choices=UNDC_FAMILY.names())
    parser.add_argument("--out", type=Path, default=undc.DEFAULT_WEIGHTS, help="weights file to write")
    parser.add_argument("--seed", type=int, default=0, help="initialisation and crop seed")
    parser.add_argument("--thingi-dir", type=Path, default=DEFAULT_THINGI_DIR, help="Thingi10K training meshes")
    args = parser.parse_args(argv)
    budget = get_undc_budget(args.budget)
    shapes = undc_training_shapes(budget, thingi_dir=args.thingi_dir)

    def report(stage, **facts):
        if stage == "label":
            print(f"labelled {facts['done']}/{facts['total']} {facts['name']}", file=sys.stderr, flush=True)
        else:
            print(f"{stage} network: step {facts['step']} loss {facts['loss']:.6f}", file=sys.stderr, flush=True)

    result = train(shapes, budget, seed=args.seed, progress=report)
    digest = undc.save_weights(args.out, result.bool_network, result.float_network, result.info(budget, args.seed))
    print(f"wrote {args.out} (sha256 {digest}; training set {result.training_set}, {len(shapes)} shapes; "
          f"{result.label_seconds:.0f} s labelling, {result.seconds:.0f} s training)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

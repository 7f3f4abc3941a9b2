"""``poco``: POCO, Point Convolution for Surface Reconstruction (Boulch & Marlet, CVPR 2022), written
here after the authors' code (github.com/valeoai/POCO), not copied from it.

Network (:mod:`methods.pointcloud.poco.network`): an FKAConv point-convolution U-Net gives every input point a
latent vector; a query's occupancy comes from the latents of its K nearest input points and its
offsets to them, aggregated with learned attention weights, as two logits (outside, inside).

Training (:func:`train_poco`): once across the training shapes, on the pools of
:class:`methods.pointcloud.training_set.TrainingPools` (the shared five-group sampler's points, labelled inside
where the generalised winding number of the mesh exceeds 1/2, ``ExactFields.occupancy``, and
area-uniform surface points). Each step takes ``batch`` items; an item is a training shape's cloud of
``input_points`` surface points (drawn without replacement from its pool) and ``queries`` labelled
points, both turned by one random rotation (three axis rotations, each angle uniform in
[-180, 180] degrees, as the authors' ABC configuration). Loss: cross-entropy of the two logits; Adam
at a constant learning rate (the authors' ``train.py``).

Reconstruction (:meth:`POCOMethod.reconstruct`):

1. latents (:func:`point_latents`): the network was trained on clouds of ``input_points`` points,
   so a larger test cloud is covered by random subsets of that size until every point's latent has
   been computed ``views`` times, then averaged (the authors' ``gen_subsample_manifold``, 10 views);
2. the grid points within ``band`` h of an input point get the network's probability of inside
   (softmax of the logits; the K nearest input points among the whole cloud); every other grid point
   is outside if its connected far region touches the grid's border, inside otherwise
   (:func:`methods.extractors.marching_cubes.far_occupancy`);
3. marching cubes at 0.5 (:func:`methods.extractors.marching_cubes.marching_cubes_grid`);
4. every vertex on a grid edge between two queried points moves to the network's 0.5 crossing on
   that edge by ``refine_steps`` bisection steps starting at the marching-cubes vertex (the authors'
   ``refine_iter``, 10).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from foundation.grid import LOWER, spacing
from foundation.params import Param, check_fields, setting
from foundation.sampler import GROUPS
from foundation.timing import stage
from foundation.grid import point_inputs
from foundation.seeding import training_streams
from methods.base import Extraction, register_method
from methods.core.budgets import register_budget_family
from methods.core.device import get_device, seeded_generator
from methods.extractors.marching_cubes import far_occupancy, marching_cubes_grid
from methods.pointcloud.errors import TooFewPointsError
from methods.pointcloud.neighbourhoods import band_points, knn_neighbourhoods
from methods.pointcloud.own_network import OwnNetworkMethod
from methods.pointcloud.poco.network import POCONetwork, batch_structures, cloud_structure, make_poco_network
from methods.pointcloud.training_set import TrainingPools, TrainingSet, TrainResult, train_steps

__all__ = ["POCOBudget", "POCO_FAMILY", "random_rotation", "draw_batch", "train_poco",
           "point_latents", "inside_probability", "refine_vertices", "POCOMethod"]


@dataclass(frozen=True)
class POCOBudget(TrainingSet):
    """POCO's budget: its architecture and schedule, and its training set (:class:`TrainingSet`)."""

    name: str = setting(Param(kind=str, help="budget name"))
    hidden: int = setting(Param(kind=int, help="backbone width at level 0 (doubles per level)", ge=2), override=True)
    levels: int = setting(Param(kind=int, help="subsampled backbone levels (ratio 1/4 each)", ge=0), override=True)
    conv_k: int = setting(Param(kind=int, help="neighbours of an FKAConv support point", ge=1), override=True)
    latent: int = setting(Param(kind=int, help="latent vector size per input point", ge=1), override=True)
    decoder_k: int = setting(Param(kind=int, help="input points a query's occupancy aggregates", ge=1), override=True)
    heads: int = setting(Param(kind=int, help="attention heads of the decoder", ge=1), override=True)
    input_points: int = setting(Param(kind=int, help="points of a training item's cloud and of an inference view", ge=1), override=True)
    queries: int = setting(Param(kind=int, help="labelled query points per training item", ge=1), override=True)
    batch: int = setting(Param(kind=int, help="training items per step", ge=1), override=True)
    steps: int = setting(Param(kind=int, help="optimizer steps", ge=1), override=True)
    lr: float = setting(Param(1e-3, "Adam learning rate (constant)", gt=0), override=True)
    rotate: bool = setting(Param(True, "turn every training item by a random rotation"), override=True)
    log_every: int = setting(Param(50, "steps between loss reports", ge=1))

    def __post_init__(self):
        check_fields(self, f"poco budget '{self.name}'")
        if self.input_points < self.decoder_k:
            raise ValueError(f"poco budget '{self.name}': input_points {self.input_points} < decoder_k {self.decoder_k}")
        if self.pool_points < self.input_points:
            raise ValueError(f"poco budget '{self.name}': pool_points {self.pool_points} < input_points "
                             f"{self.input_points} (an item's cloud is drawn without replacement)")

    def network_config(self) -> dict:
        """Keyword arguments of :func:`methods.pointcloud.poco.network.make_poco_network`."""
        return dict(hidden=self.hidden, levels=self.levels, conv_k=self.conv_k, latent=self.latent,
                    decoder_k=self.decoder_k, heads=self.heads, input_points=self.input_points)


#: *paper*: the authors' ABC configuration (``configs/config_abc.yaml`` over ``config_default.yaml``):
#: FKAConv backbone of width 64 and 4 subsampled levels (64 .. 1024 channels), 16 neighbours per
#: convolution, latent 32, decoder K 64 with 64 heads, items of 3,000 input points and 2,000
#: labelled queries, batches of 16, Adam 1e-3 for 100k steps (``training_iter_nbr``; the ABC
#: file's ``iter_nbr`` is read by nothing). *cpu*: a training for one CPU core (its cost:
#: docs/PROTOCOL.md, "poco"): width 32 (the FKAConv alignment, whose cost does not depend on the
#: width, dominates), the paper's levels, convolution K and item clouds, decoder K 32 with 16 heads,
#: items of 1,024 queries, batches of 4, 1,200 steps. *tiny*: tests. The training sets are those of
#: the K-NN budgets of the same name (paper: 100 parts, pools of 1M; cpu: 24 parts, pools of 200k;
#: tiny: 4 parts, pools of 20k).
POCO_FAMILY = register_budget_family("poco", (
    POCOBudget("paper", hidden=64, levels=4, conv_k=16, latent=32, decoder_k=64, heads=64, input_points=3_000,
               queries=2_000, batch=16, steps=100_000, lr=1e-3, log_every=500,
               training_shapes=100, pool_samples=1_000_000, pool_points=1_000_000),
    POCOBudget("cpu", hidden=32, levels=4, conv_k=16, latent=32, decoder_k=32, heads=16, input_points=3_000,
               queries=1_024, batch=4, steps=1_200, lr=1e-3, log_every=50,
               training_shapes=24, pool_samples=200_000, pool_points=200_000),
    POCOBudget("tiny", hidden=16, levels=2, conv_k=8, latent=16, decoder_k=16, heads=8, input_points=500,
               queries=512, batch=4, steps=300, lr=3e-3, rotate=True, log_every=25,
               training_shapes=4, pool_samples=20_000, pool_points=20_000),
))


# --------------------------------------------------------------------------------------------------
# Training
# --------------------------------------------------------------------------------------------------

def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """(3, 3) rotation ``Rz Ry Rx``, each angle uniform in [-pi, pi] (the authors' augmentation)."""
    a, b, c = rng.uniform(-np.pi, np.pi, size=3)
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _draw(rows: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` of ``rows``, without replacement when there are enough."""
    return rng.choice(rows, size=count, replace=count > len(rows))


def draw_batch(pools: TrainingPools, budget: POCOBudget, rng: np.random.Generator):
    """One training batch: clouds (B, input_points, 3), queries (B, queries, 3) float32 and their
    occupancy labels (B, queries) int64; B = ``budget.batch`` distinct shapes (repeats only when
    there are fewer), each item turned by its own :func:`random_rotation` when ``budget.rotate``."""
    n = len(pools.pools)
    chosen = rng.choice(n, size=budget.batch, replace=budget.batch > n)
    clouds, queries, labels = [], [], []
    for index in chosen:
        pool = pools.pools[index]
        cloud = pool.cloud[rng.choice(len(pool.cloud), size=budget.input_points, replace=False)]
        volume = pool.targets["volume"] > 0.5
        half = budget.queries // 2
        rows = np.concatenate([_draw(np.flatnonzero(volume), half, rng),
                               _draw(np.flatnonzero(~volume), budget.queries - half, rng)])
        rotation = (random_rotation(rng) if budget.rotate else np.eye(3)).astype(np.float32)
        clouds.append(cloud @ rotation.T)
        queries.append(pool.anchors[rows] @ rotation.T)
        labels.append(pool.targets["occupancy"][rows] > 0.5)
    return np.stack(clouds), np.stack(queries), np.stack(labels).astype(np.int64)


def train_poco(method, shapes: Sequence, budget: POCOBudget, seed: int = 0, device=None,
               progress: Callable[..., None] | None = None) -> TrainResult:
    """Train POCO across ``shapes`` (module docstring) at ``budget`` (its architecture, schedule
    and training pools).

    ``seed``: the pools, the network's initialisation (:func:`methods.core.device.seeded_generator`) and
    every batch draw (:func:`foundation.seeding.training_streams`); on the CPU the same seed gives the same
    weights. ``progress(step=..., loss=..., total=steps)`` every ``log_every`` steps. Returns a
    :class:`methods.pointcloud.training_set.TrainResult` (model in eval mode)."""
    device = get_device(device)
    pools = TrainingPools(method, shapes, budget, seed)
    seeded_generator(seed, device)
    rng = training_streams(seed).batch_rng()
    model = make_poco_network(**budget.network_config()).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=budget.lr)

    def step_loss(step: int) -> torch.Tensor:
        clouds, queries, labels = draw_batch(pools, budget, rng)
        structures = batch_structures([cloud_structure(c, budget.levels, budget.conv_k) for c in clouds], device)
        index = np.stack([knn_neighbourhoods(c, q, budget.decoder_k) for c, q in zip(clouds, queries)])
        logits = model(structures, torch.from_numpy(queries).to(device), torch.from_numpy(index).to(device))
        return method.loss(logits.reshape(-1, 2), {"occupancy": torch.from_numpy(labels.reshape(-1)).to(device)})

    return train_steps(method, model, optimizer, budget, "poco", step_loss, seed=seed,
                       batch=budget.batch * budget.queries, pool_seconds=pools.seconds, device=device,
                       progress=progress)


# --------------------------------------------------------------------------------------------------
# Inference
# --------------------------------------------------------------------------------------------------

def point_latents(model: POCONetwork, points: np.ndarray, views: int, rng: np.random.Generator,
                  device=None) -> tuple[np.ndarray, int]:
    """(latents (P, latent) float32 of every input point, backbone passes).

    A cloud of at most ``model.input_points`` points takes one pass. A larger one is covered by
    subsets of ``input_points`` points: for view v = 0..views-1, while some point has fewer than
    v + 1 latents, a subset draws (without replacement) from the points with exactly v, filled up
    with random other points; each point's latents are averaged (the authors' test-time
    ``gen_subsample_manifold``)."""
    points = np.asarray(points, dtype=np.float32)
    device = device or next(model.parameters()).device
    P, n = len(points), model.input_points
    config = model.config

    def latents_of(ids: np.ndarray) -> np.ndarray:
        structure = batch_structures([cloud_structure(points[ids], config["levels"], config["conv_k"])], device)
        with torch.inference_mode():
            return model.latents(structure)[0].float().cpu().numpy()

    if P <= n:
        return latents_of(np.arange(P)), 1
    sums = np.zeros((P, config["latent"]), dtype=np.float64)
    counts = np.zeros(P, dtype=np.int64)
    passes = 0
    for view in range(int(views)):
        while counts.min() < view + 1:
            pending = np.flatnonzero(counts == view)
            ids = rng.choice(pending, size=min(n, len(pending)), replace=False)
            if len(ids) < n:
                others = np.setdiff1d(np.arange(P), ids, assume_unique=True)
                ids = np.concatenate([ids, rng.choice(others, size=n - len(ids), replace=False)])
            sums[ids] += latents_of(ids)
            counts[ids] += 1
            passes += 1
    return (sums / counts[:, None]).astype(np.float32), passes


def inside_probability(model: POCONetwork, points: np.ndarray, latents: np.ndarray, queries: np.ndarray,
                       device=None, chunk: int = 8_192) -> np.ndarray:
    """(Q,) float32 probability of inside (softmax of the two logits) of ``queries`` (Q, 3) from the
    ``latents`` (P, C) of ``points`` (P, 3), each query with its ``decoder_k`` nearest input points."""
    queries = np.ascontiguousarray(queries, dtype=np.float32)
    if len(queries) == 0:
        return np.zeros(0, dtype=np.float32)
    device = device or next(model.parameters()).device
    with stage("knn"):
        index = knn_neighbourhoods(points, queries, model.decoder_k)
    cloud = torch.from_numpy(np.asarray(points, dtype=np.float32)).to(device)[None]
    codes = torch.from_numpy(np.asarray(latents, dtype=np.float32)).to(device)[None]
    out = []
    with torch.inference_mode():
        for i in range(0, len(queries), chunk):
            q = torch.from_numpy(queries[i:i + chunk]).to(device)[None]
            k = torch.from_numpy(index[i:i + chunk]).to(device)[None]
            out.append(torch.softmax(model.decode(codes, cloud, q, k)[0], dim=-1)[:, 1].float().cpu().numpy())
    return np.concatenate(out)


def refine_vertices(vertices: np.ndarray, volume: np.ndarray, known: np.ndarray, probability: Callable,
                    steps: int) -> tuple[np.ndarray, int]:
    """Move marching-cubes vertices to the 0.5 crossing of ``probability`` on their grid edge.

    A vertex (canonical frame) lies on the grid edge between points i1 and i2 = i1 + e_axis; where both
    are ``known`` (queried), ``steps`` bisection steps run between the two points, the first
    evaluation at the vertex itself: the side (probability > 0.5) of each evaluation replaces the edge
    end of the same side, and the vertex becomes the midpoint of the two ends (the authors'
    ``refine_iter``). ``volume`` (N, N, N): the grid probabilities; ``probability(x (M, 3)) -> (M,)``.
    Returns (vertices, number of refined vertices).
    """
    vertices = np.array(vertices, dtype=np.float64)
    N = volume.shape[0]
    if steps <= 0 or len(vertices) == 0:
        return vertices, 0
    h = spacing(N)
    u = (vertices - LOWER) / h
    r = np.rint(u)
    off = np.abs(u - r) > 1e-6
    on_edge = off.sum(axis=1) == 1
    i1 = np.where(off, np.floor(u), r).astype(np.int64)
    i1 = np.clip(i1, 0, N - 1)
    i2 = np.clip(i1 + off, 0, N - 1)
    on_edge &= known[tuple(i1.T)] & known[tuple(i2.T)]
    if not on_edge.any():
        return vertices, 0
    i1, i2 = i1[on_edge], i2[on_edge]
    x1, x2 = LOWER + i1 * h, LOWER + i2 * h
    inside1 = volume[tuple(i1.T)] > 0.5
    v = vertices[on_edge]
    for _ in range(int(steps)):
        same1 = (probability(v) > 0.5) == inside1
        x1[same1] = v[same1]
        x2[~same1] = v[~same1]
        v = 0.5 * (x1 + x2)
    vertices[on_edge] = v
    return vertices, int(on_edge.sum())


@register_method(order=180, color="#5b8c2a")
class POCOMethod(OwnNetworkMethod):
    name = "poco"
    description = "POCO: FKAConv point-convolution latents + attention decoder to occupancy, marching cubes"
    network_kind = "point"
    output_dim = 2
    extractor = "marching cubes"
    network_label = "POCO"
    build_network = staticmethod(make_poco_network)
    budget_family = "poco"
    training_modules = ("methods.pointcloud.poco.network", "methods.pointcloud.training_set")
    parameters = {
        "band": Param(3.0, "grid points within this many h of an input point are queried", gt=0),
        "views": Param(10, "latents computed (and averaged) per input point over random subsets", ge=1),
        "refine_steps": Param(10, "bisection steps moving each vertex to the network's 0.5 crossing", ge=0),
    }

    def training_targets(self, fields, samples) -> dict[str, np.ndarray]:
        """The occupancy of every sample and whether it is a volume sample (1: the sampler's
        ``bbox`` or ``space`` groups, 0: a surface group), so a batch can take half of each."""
        volume = [i for i, group in enumerate(GROUPS) if group[2] != "surface"]
        return {"occupancy": np.asarray(fields.occupancy(samples.points), dtype=np.float32),
                "volume": np.isin(samples.group, volume).astype(np.float32)}

    def loss(self, prediction, targets):
        """Cross-entropy of the (B, 2) logits [outside, inside] against the labels (B,) (0/1)."""
        return F.cross_entropy(prediction, targets["occupancy"].long())

    def training_cloud_points(self, budget) -> int:
        return int(budget.input_points)

    def train_network(self, shapes, budget, seed, device=None, progress=None) -> TrainResult:
        return train_poco(self, shapes, budget, seed=seed, device=device, progress=progress)

    def reconstruct(self, points, N, device=None, seed=0, model=None) -> Extraction:
        model, device = self.network_on_device(model, device)
        points = self.checked_points(points)
        if len(points) < model.decoder_k:
            raise TooFewPointsError("poco", len(points), model.decoder_k, "the decoder")
        with stage("latents"):
            latents, passes = point_latents(model, points, self.params["views"], np.random.default_rng(seed), device)

        def probability(x):
            return inside_probability(model, points, latents, x, device)

        with stage("band"):
            ijk = band_points(points, N, self.params["band"] * spacing(N))
        with stage("field"):
            known = np.zeros((N, N, N), dtype=bool)
            known[tuple(ijk.T)] = True
            volume = far_occupancy(known)
            volume[tuple(ijk.T)] = probability(point_inputs(N, ijk))
        mesh = marching_cubes_grid(volume, 0.5, inside="high")
        with stage("refine"):
            V, refined = refine_vertices(mesh.vertices, volume, known, probability, self.params["refine_steps"])
        return Extraction(V, mesh.faces, info={"queried_points": int(len(ijk)), "backbone_passes": int(passes),
                                       "refined_vertices": refined})

"""``gifs``: GIFS, Neural Implicit Function for General Shape Representation (Ye, Chen, Wang & Wang,
CVPR 2022), written here after the authors' code (github.com/jianglongye/gifs), not copied from it.

Network (:mod:`methods.pointcloud.gifs.network`): the cloud as a binary voxel grid, an IF-Net encoder, multi-scale
features sampled at query points; one decoder gives a point's UDF, another the flag of a pair of
points (u, v): ~1 where the surface separates them (the segment u-v crosses it), ~0 where not.

Training (:func:`train_gifs`): once across the training shapes, on the pools of
:class:`methods.pointcloud.training_set.TrainingPools`: the shared five-group sampler's segments (u, v) =
(c + e1, c + e2), the same construction as the authors' pairs (a centre, two Gaussian offsets of
the same sigma), labelled by the exact fields: flag = the segment hits the mesh (``ExactFields.segments``,
the authors' CGAL ``do_intersect``), UDF of u and of v (``ExactFields.udf``). Each step takes
``batch`` items; an item is a training shape's cloud of ``budget.points_per_item`` surface points,
voxelized, and ``pairs`` labelled pairs drawn per sampler group in the group's share, half of them
separated and half not (the authors' ``balance_data``; with replacement where a group has too few).
Loss (the authors' ``ddp_train.py``): ``udf_weight * L1(min(udf_hat, clamp), min(udf, clamp)) +
L1(flag_hat, flag)`` over both endpoints' UDFs and all pairs; Adam at a constant learning rate.

Reconstruction (:meth:`GIFSMethod.reconstruct`), on the run's grid (N points per axis):

1. encode the voxelized cloud once;
2. candidate cubes: the grid cells with a corner within ``band`` h of an input point
   (:func:`methods.pointcloud.knn.query.band_points`); the network's UDF at all their corners;
3. queried cubes: the candidates with a corner UDF below ``udf_threshold`` h (the authors keep a
   cell when its smallest corner UDF is below one cell in their units, 2 h here); the flags of their
   28 corner pairs;
4. :func:`methods.pointcloud.gifs.extraction.flag_split_marching_cubes`: per cube the corner partition that best
   agrees with its flags, signed corner values +-UDF, marching cubes per cube, welded vertices;
5. optionally (``refine_steps`` > 0; the authors' ``mesh_refine``, off in their released
   ``generate_mesh``): RMSprop on the vertex positions minimising the mean squared UDF of one random
   point per face (barycentric weights ~ Dirichlet(1/2, 1/2, 1/2)).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import torch

from foundation.grid import LOWER, spacing
from foundation.params import Param, check_fields, setting
from foundation.seeding import training_streams
from foundation.sampler import group_counts
from foundation.timing import stage
from methods.base import Extraction, register_method
from methods.core.budgets import register_budget_family
from methods.core.device import get_device, seeded_generator
from methods.pointcloud.gifs.extraction import CORNER_PAIRS, CORNERS, flag_split_marching_cubes
from methods.pointcloud.gifs.network import GIFSNetwork, make_gifs_network, voxelize_cloud
from methods.pointcloud.neighbourhoods import band_points
from methods.pointcloud.training_set import TrainingPools, TrainingSet, TrainResult, train_steps
from methods.pointcloud.own_network import OwnNetworkMethod

__all__ = ["GIFSBudget", "GIFS_FAMILY", "draw_pairs", "draw_batch", "gifs_loss", "train_gifs",
           "encode_cloud", "point_udf", "cube_flags", "refine_vertices", "GIFSMethod"]


@dataclass(frozen=True)
class GIFSBudget(TrainingSet):
    """GIFS's budget: its architecture and schedule, the cloud of a training item
    (``points_per_item`` points of its shape's pool) and its training set (:class:`TrainingSet`)."""

    name: str = setting(Param(kind=str, help="budget name"))
    points_per_item: int = setting(Param(kind=int, help="input points of a training item's cloud", ge=1), override=True)
    resolution: int = setting(Param(kind=int, help="voxel grid points per axis of the input", ge=2), override=True)
    channels: tuple = setting(Param(kind=tuple, item=int, help="encoder widths (full resolution, then / 2 each)"), override=True)
    hidden: int = setting(Param(kind=int, help="decoder width", ge=1), override=True)
    batch: int = setting(Param(kind=int, help="training items (shapes) per step", ge=1), override=True)
    pairs: int = setting(Param(kind=int, help="labelled pairs per training item", ge=2), override=True)
    steps: int = setting(Param(kind=int, help="optimizer steps", ge=1), override=True)
    lr: float = setting(Param(1e-4, "Adam learning rate (constant)", gt=0), override=True)
    udf_weight: float = setting(Param(5.0, "weight of the UDF term (the authors' 10 in half units)", ge=0), override=True)
    udf_clamp: float = setting(Param(0.2, "UDFs are clamped at this (canonical units; the authors' 0.1 in half units)",
                                     gt=0), override=True)
    log_every: int = setting(Param(50, "steps between loss reports", ge=1))

    def __post_init__(self):
        check_fields(self, f"gifs budget '{self.name}'")
        if self.resolution % (2 ** (len(self.channels) - 1)):
            raise ValueError(f"gifs budget '{self.name}': resolution {self.resolution} is not a multiple of "
                             f"2^{len(self.channels) - 1}")
        if self.pool_points < self.points_per_item:
            raise ValueError(f"gifs budget '{self.name}': pool_points {self.pool_points} < points_per_item "
                             f"{self.points_per_item} (an item's cloud is drawn without replacement)")

    def network_config(self) -> dict:
        """Keyword arguments of :func:`methods.pointcloud.gifs.network.make_gifs_network`."""
        return dict(resolution=self.resolution, channels=tuple(self.channels), hidden=self.hidden)


#: *paper*: the authors' configuration (``models/local_model.py``, ``configs/config_loader.py``,
#: ``configs/shapenet_cars.txt``): voxel grid 256^3, encoder widths 16, 32, 64, 128, 128, 128, decoders
#: of width 256 (512 -> 256 -> 256 -> 256), items of 50,000 pairs, batches of 2, Adam 1e-6; their
#: schedule is wall-clock (released checkpoint at 44 h), 400k steps is our stand-in. *cpu*: a training
#: for one CPU core (its cost: docs/PROTOCOL.md, "gifs"; why the voxel grid and the learning rate:
#: docs/PERFORMANCE.md, section 10): voxel grid 96^3, widths 8, 16, 32, 64,
#: 64, 64, decoders of width 128, items of 2,048 pairs, batches of 2, Adam 1e-4, 900 steps. *tiny*:
#: tests.
GIFS_FAMILY = register_budget_family("gifs", (
    GIFSBudget("paper", resolution=256, channels=(16, 32, 64, 128, 128, 128), hidden=256, batch=2, pairs=50_000,
               steps=400_000, lr=1e-6, log_every=500,
               points_per_item=40_000, training_shapes=100, pool_samples=1_000_000, pool_points=1_000_000),
    GIFSBudget("cpu", resolution=96, channels=(8, 16, 32, 64, 64, 64), hidden=128, batch=2, pairs=2_048,
               steps=900, lr=1e-4, log_every=50,
               points_per_item=40_000, training_shapes=24, pool_samples=200_000, pool_points=200_000),
    GIFSBudget("tiny", resolution=32, channels=(8, 16, 32), hidden=32, batch=2, pairs=1_024, steps=200, lr=1e-3,
               log_every=25,
               points_per_item=10_000, training_shapes=4, pool_samples=20_000, pool_points=20_000)
))



# --------------------------------------------------------------------------------------------------
# Training
# --------------------------------------------------------------------------------------------------

def draw_pairs(flag: np.ndarray, group: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """Rows of ``count`` training pairs: per sampler group (:data:`foundation.sampler.GROUPS`) its share
    of ``count`` (:func:`foundation.sampler.group_counts`), half of it from the group's separated
    pairs (``flag`` > 0.5) and half from the others, each half without replacement when there are
    enough rows, else with; a half whose kind the group lacks is drawn from the other kind, a group
    the pool lacks from the whole pool. ``flag``, ``group``: (M,) of the pool."""
    flag = np.asarray(flag) > 0.5
    group = np.asarray(group).astype(np.int64)
    rows = []
    for g, n in enumerate(group_counts(int(count))):
        members = group == g
        if not members.any():
            members = np.ones(len(flag), dtype=bool)
        positive, negative = np.flatnonzero(members & flag), np.flatnonzero(members & ~flag)
        half = int(n) // 2
        for kind, k in ((positive, half), (negative, int(n) - half)):
            kind = kind if len(kind) else np.flatnonzero(members)
            rows.append(rng.choice(kind, size=k, replace=k > len(kind)))
    return np.concatenate(rows)


def draw_batch(pools: TrainingPools, budget: GIFSBudget, rng: np.random.Generator):
    """One training batch: voxel grids (B, R, R, R), pairs (B, pairs, 6), UDF labels (B, pairs, 2)
    and flag labels (B, pairs), float32; B = ``budget.batch`` distinct training shapes (repeats only
    when there are fewer), each with a cloud of ``budget.points_per_item`` points of its pool (without
    replacement) and pairs by :func:`draw_pairs`."""
    n = len(pools.pools)
    chosen = rng.choice(n, size=budget.batch, replace=budget.batch > n)
    voxels, pairs, udfs, flags = [], [], [], []
    for index in chosen:
        pool = pools.pools[index]
        cloud = pool.cloud[rng.choice(len(pool.cloud), size=budget.points_per_item, replace=False)]
        rows = draw_pairs(pool.targets["flag"], pool.targets["group"], budget.pairs, rng)
        voxels.append(voxelize_cloud(cloud, budget.resolution))
        pairs.append(pool.anchors[rows].reshape(-1, 6))
        udfs.append(np.stack([pool.targets["udf_u"][rows], pool.targets["udf_v"][rows]], axis=1))
        flags.append(pool.targets["flag"][rows])
    return np.stack(voxels), np.stack(pairs), np.stack(udfs), np.stack(flags)


def gifs_loss(udf_hat: torch.Tensor, flag_hat: torch.Tensor, udf: torch.Tensor, flag: torch.Tensor,
              udf_weight: float, udf_clamp: float) -> torch.Tensor:
    """``udf_weight * mean |min(udf_hat, c) - min(udf, c)| + mean |flag_hat - flag|`` (c = ``udf_clamp``)."""
    udf_term = (torch.clamp(udf_hat, max=udf_clamp) - torch.clamp(udf, max=udf_clamp)).abs().mean()
    return udf_weight * udf_term + (flag_hat - flag).abs().mean()


def train_gifs(method, shapes: Sequence, budget: GIFSBudget, seed: int = 0, device=None,
               progress: Callable[..., None] | None = None) -> TrainResult:
    """Train GIFS across ``shapes`` (module docstring) at ``budget`` (its architecture, schedule,
    item clouds and training pools).

    ``seed``: the pools, the network's initialisation (:func:`methods.core.device.seeded_generator`) and
    every batch draw (:func:`foundation.seeding.training_streams`); on the CPU the same seed gives the same
    weights. ``progress(step=..., loss=..., total=steps)`` every ``log_every`` steps. Returns a
    :class:`methods.pointcloud.training_set.TrainResult` (model in eval mode)."""
    device = get_device(device)
    pools = TrainingPools(method, shapes, budget, seed)
    seeded_generator(seed, device)
    rng = training_streams(seed).batch_rng()
    model = make_gifs_network(**budget.network_config()).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=budget.lr)

    def step_loss(step: int) -> torch.Tensor:
        voxels, pairs, udf, flag = (torch.from_numpy(a).to(device) for a in draw_batch(pools, budget, rng))
        udf_hat, flag_hat = model(pairs, voxels)
        return gifs_loss(udf_hat, flag_hat, udf, flag, budget.udf_weight, budget.udf_clamp)

    return train_steps(method, model, optimizer, budget, "gifs", step_loss, seed=seed,
                       batch=budget.batch * budget.pairs, pool_seconds=pools.seconds, device=device,
                       progress=progress)


# --------------------------------------------------------------------------------------------------
# Inference
# --------------------------------------------------------------------------------------------------

#: Points (UDF) / cubes (28 flags each) per forward pass, by device type.
POINT_CHUNK = {"cpu": 16_384, "cuda": 262_144}
CUBE_CHUNK = {"cpu": 1_024, "cuda": 16_384}


def _chunk(table: dict, device) -> int:
    return table.get(torch.device(device).type, min(table.values()))


def encode_cloud(model: GIFSNetwork, points: np.ndarray, device=None) -> list[torch.Tensor]:
    """The feature grids of ``points`` (P, 3) voxelized at the model's resolution (eval mode)."""
    device = device or next(model.parameters()).device
    voxels = torch.from_numpy(voxelize_cloud(points, model.resolution)).to(device)[None]
    with torch.inference_mode():
        return model.encode(voxels)


def point_udf(model: GIFSNetwork, grids: list[torch.Tensor], points: np.ndarray, device=None) -> np.ndarray:
    """(Q,) float32 network UDF (canonical units) of ``points`` (Q, 3)."""
    device = device or grids[0].device
    points = np.ascontiguousarray(points, dtype=np.float32)
    out = [np.zeros(0, dtype=np.float32)]
    chunk = _chunk(POINT_CHUNK, device)
    with torch.inference_mode():
        for i in range(0, len(points), chunk):
            q = torch.from_numpy(points[i:i + chunk]).to(device)[None]
            out.append(model.udf(q, grids)[0].float().cpu().numpy())
    return np.concatenate(out)


def cube_flags(model: GIFSNetwork, grids: list[torch.Tensor], cubes: np.ndarray, N: int, device=None) -> np.ndarray:
    """(C, 28) float32 network flags of the 28 corner pairs (:data:`methods.pointcloud.gifs.extraction.CORNER_PAIRS`)
    of the grid cubes with lower grid points ``cubes`` (C, 3)."""
    device = device or grids[0].device
    h = spacing(N)
    corner_offsets = torch.from_numpy(CORNERS.astype(np.float32) * np.float32(h)).to(device)
    a, b = torch.from_numpy(CORNER_PAIRS[:, 0]).to(device), torch.from_numpy(CORNER_PAIRS[:, 1]).to(device)
    lower = (LOWER + np.asarray(cubes, dtype=np.float64) * h).astype(np.float32)
    out = [np.zeros((0, len(CORNER_PAIRS)), dtype=np.float32)]
    chunk = _chunk(CUBE_CHUNK, device)
    with torch.inference_mode():
        for i in range(0, len(lower), chunk):
            corners = torch.from_numpy(lower[i:i + chunk]).to(device)[:, None, :] + corner_offsets  # (c, 8, 3)
            features = model.point_features(corners.reshape(1, -1, 3), grids)[0].reshape(len(corners), 8, -1)
            out.append(model.flag_from_features(features[:, a], features[:, b]).float().cpu().numpy())
    return np.concatenate(out)


def refine_vertices(model: GIFSNetwork, grids: list[torch.Tensor], vertices: np.ndarray, faces: np.ndarray,
                    steps: int, lr: float, rng: np.random.Generator, device=None) -> np.ndarray:
    """Vertices (V, 3) moved by ``steps`` RMSprop steps (learning rate ``lr``) on the mean squared
    network UDF of one point per face, a new random barycentric point (Dirichlet(1/2, 1/2, 1/2),
    from ``rng``) each step (the authors' ``mesh_refine``)."""
    if steps <= 0 or len(faces) == 0:
        return np.asarray(vertices, dtype=np.float64)
    device = device or grids[0].device
    v = torch.tensor(np.asarray(vertices, dtype=np.float32), device=device, requires_grad=True)
    f = torch.from_numpy(np.asarray(faces, dtype=np.int64)).to(device)
    grids = [g.detach().clone() for g in grids]  # inference tensors cannot enter autograd
    optimizer = torch.optim.RMSprop([v], lr=lr)
    for _ in range(int(steps)):
        weights = torch.from_numpy(rng.dirichlet((0.5, 0.5, 0.5), size=len(faces)).astype(np.float32)).to(device)
        points = (v[f] * weights[:, :, None]).sum(dim=1)
        loss = model.udf(points[None], grids).pow(2).mean()
        (v.grad,) = torch.autograd.grad(loss, v)  # the network's own parameters get no gradient
        optimizer.step()
    return v.detach().cpu().numpy().astype(np.float64)


@register_method(order=170, color="#d4a017")
class GIFSMethod(OwnNetworkMethod):
    name = "gifs"
    description = "GIFS: IF-Net voxel features -> UDF + pair separation flags, per-cube signs, marching cubes"
    network_kind = "segment"
    input_kind = "segments"
    output_dim = 3
    extractor = "GIFS marching cubes"
    network_label = "GIFS"
    build_network = staticmethod(make_gifs_network)
    budget_family = "gifs"
    training_modules = ("methods.pointcloud.gifs.network", "methods.pointcloud.training_set")
    parameters = {
        "band": Param(3.0, "cubes with a corner within this many h of an input point are candidates", gt=0),
        "udf_threshold": Param(2.0, "cubes whose smallest corner UDF is below this many h are queried", gt=0),
        "flag_threshold": Param(0.5, "a cube holds surface only where some pair flag exceeds this", gt=0),
        "refine_steps": Param(0, "RMSprop steps moving the vertices onto the UDF's zero (authors: 30, off)", ge=0),
        "refine_lr": Param(2e-4, "learning rate of the vertex refinement (canonical units)", gt=0),
    }

    def training_targets(self, fields, samples) -> dict[str, np.ndarray]:
        """Per segment (u, v): flag (the segment hits the mesh, 0/1), the UDF of u and of v, and the
        sampler group (index into :data:`foundation.sampler.GROUPS`)."""
        u, v = samples.segments[:, 0], samples.segments[:, 1]
        hit, _, _ = fields.segments(u, v)
        return {"flag": hit.astype(np.float32), "udf_u": fields.udf(u).astype(np.float32),
                "udf_v": fields.udf(v).astype(np.float32), "group": np.asarray(samples.group, dtype=np.float32)}

    def train_network(self, shapes, budget, seed, device=None, progress=None) -> TrainResult:
        return train_gifs(self, shapes, budget, seed=seed, device=device, progress=progress)

    def reconstruct(self, points, N, device=None, seed=0, model=None) -> Extraction:
        model, device = self.network_on_device(model, device)
        points = self.checked_points(points)
        h = spacing(N)
        with stage("encode"):
            grids = encode_cloud(model, points, device)
        with stage("band"):
            near = np.zeros((N, N, N), dtype=bool)
            near[tuple(band_points(points, N, self.params["band"] * h).T)] = True
            candidate = np.zeros((N - 1,) * 3, dtype=bool)
            for di, dj, dk in CORNERS:
                candidate |= near[di:di + N - 1, dj:dj + N - 1, dk:dk + N - 1]
            corner_mask = np.zeros((N, N, N), dtype=bool)
            for di, dj, dk in CORNERS:
                corner_mask[di:di + N - 1, dj:dj + N - 1, dk:dk + N - 1] |= candidate
            cubes = np.argwhere(candidate)
        with stage("udf"):
            corner_points = np.argwhere(corner_mask)
            udf = np.full((N, N, N), np.inf, dtype=np.float32)
            udf[tuple(corner_points.T)] = point_udf(model, grids, LOWER + corner_points * h, device)
            corners = cubes[:, None, :] + CORNERS[None]
            corner_udf = udf[corners[..., 0], corners[..., 1], corners[..., 2]]
            queried = corner_udf.min(axis=1) < self.params["udf_threshold"] * h
            cubes, corner_udf = cubes[queried], corner_udf[queried]
        with stage("flags"):
            flags = cube_flags(model, grids, cubes, N, device)
        with stage("mesh"):
            mesh = flag_split_marching_cubes(cubes, flags, corner_udf, N, self.params["flag_threshold"])
            V, F, info = mesh.vertices, mesh.faces, mesh.info
        if self.params["refine_steps"] > 0:
            with stage("refine"):
                V = refine_vertices(model, grids, V, F, self.params["refine_steps"], self.params["refine_lr"],
                                    np.random.default_rng(seed), device)
        info.update({"queried_points": int(len(corner_points)), "candidate_cubes": int(candidate.sum()),
                     "queried_cubes": int(len(cubes))})
        return Extraction(V, F, info=info)

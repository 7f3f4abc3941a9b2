"""``geoudf``: GeoUDF (Ren, Hou, Chen, He, Wang; ICCV 2023), "Surface reconstruction from 3D point
clouds via geometry-guided distance representation", written after the authors' code
(github.com/rsy6318/GeoUDF: ``model.py``, ``main_pu.py``, ``main_rec.py``, ``scripts/sample.py``,
``shapenet_small_dataset.py``, ``eval_rec.py``), not copied from it.

Frame: the networks run in the authors' frame, a shape's bounding box centred with largest side 1:
canonical coordinates (largest side 1.99) divided by :data:`FRAME_SCALE`; every constant below in
"authors' units" is theirs, and the UDF comes back multiplied by it.

Networks (:mod:`methods.pointcloud.geoudf.network`): LGR-Net upsamples the cloud R-fold with normals (a
quadratic patch per point from DGCNN features); the geometry-guided UDF of a query is a learned
softmax-weighted sum of its distances to the tangent planes of its K nearest upsampled points, its
gradient the weighted sum of their normals turned towards it.

Training (:func:`train_geoudf`), two stages as the authors' ``main_pu.py`` then ``main_rec.py``:

1. LGR-Net alone: loss ``100 CD`` (Chamfer distance, squared, mean both ways, authors' units)
   between its R M upsampled points and the R M target points; Adam at ``pu_lr``, constant.
2. Both networks: ``100 CD + |UDF - d| + 0.1 (1 - g . g_gt)`` (means over the queries; the UDF is
   read from the *detached* upsampled points and normals, so LGR-Net learns from the CD only);
   Adam at ``rec_lr``, constant, LGR-Net continuing from stage 1.

Items (:func:`draw_items`). The authors' item is a whole ShapeNet shape: 3,000 random surface
points in, 48,000 Poisson-disk points as the target (R = 16), 2,048 queries of its labelled pool.
The test clouds here hold 40,000 points, and the upsampler must see that density, so an item is a
*patch* at the test density: a training shape's cloud of ``budget.points_per_item`` points (drawn
without replacement from its pool of ``budget.pool_points`` area-uniform points), the
``patch_points`` of them nearest a random seed point of it (radius r: the farthest of them), the
``R patch_points`` points of the shape's target pool (``R budget.points_per_item`` area-uniform
points: R times the input density) nearest the same seed, and ``queries`` queries of the shape's pool
whose closest surface point lies within 0.75 r of the seed (their nearest upsampled points are those
of the patch).

Query pool (:func:`query_pool`), the authors' ``scripts/sample.py``: ``budget.pool_samples`` points,
10 % / 40 % / 50 % of them area-uniform surface points plus Gaussian noise of standard deviation
0.05 / 0.02 / 0.003 authors' units (x 1.99 here); labels from :class:`foundation.fields.ExactFields`:
the distance d and the unit gradient (x - c) / |x - c| (c the closest point).

Reconstruction (:meth:`GeoUDFMethod.reconstruct`), the authors' ``eval_rec.py``:

1. upsampling (:func:`upsample`, with ``upsample=true``): LGR-Net (eval mode) on patches of
   ``patch_points`` points covering the cloud, as it was trained (the authors' network sees whole
   3,000-point shapes in training and at test; here both are patches at the test density); each
   point's R upsampled points and normals from the patch whose seed is nearest to it, its (u, v) set
   drawn from the job seed;
2. band: the grid points within ``band`` h (2 h) of an upsampled point get the network's UDF and
   gradient (their K nearest upsampled points among all); the other corners of the cells that
   E-MC tests keep their distance to the nearest upsampled point (the authors' initial grid UDF);
3. E-MC (:func:`methods.pointcloud.geoudf.extraction.edge_marching_cubes`) at the run's N.

By default (``upsample=false``) step 1 is the authors' path for dense inputs (``eval_rec_dense.py``;
their sparse inputs hold 3,000 points, ours 40,000): the input points themselves with PCA normals
of their 10 nearest points (pymeshlab's ``compute_normal_for_point_clouds``,
:func:`methods.extractors.meshlab.oriented_point_set`), no LGR-Net.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import torch
from pykdtree.kdtree import KDTree

from foundation.fields import ExactFields
from foundation.grid import spacing
from foundation.params import Param, check_fields, setting
from foundation.seeding import training_streams
from foundation.surface import sample_surface
from foundation.timing import stage
from methods.base import Extraction, register_method
from methods.core.budgets import register_budget_family
from methods.core.device import get_device, seeded_generator
from methods.pointcloud.geoudf.extraction import CORNERS, edge_marching_cubes
from methods.pointcloud.geoudf.network import GeoUDFNetwork, make_geoudf_network, nearest_indices
from methods.pointcloud.errors import TooFewPointsError
from methods.pointcloud.neighbourhoods import knn_neighbourhoods
from methods.pointcloud.neighbourhoods import band_points, nearest_distance
from methods.pointcloud.training_set import TrainingSet, TrainResult
from methods.extractors.meshlab import current_mesh, oriented_point_set
from methods.pointcloud.own_network import OwnNetworkMethod
from foundation.grid import point_inputs
from methods.core.training_loop import FittingError, run_steps

__all__ = ["FRAME_SCALE", "QUERY_SIGMAS", "QUERY_RATIOS", "GeoUDFBudget", "GEOUDF_FAMILY",
           "GeoUDFPool", "query_pool", "build_pools", "draw_items", "chamfer_loss", "train_geoudf", "cover_patches",
           "upsample", "udf_and_gradient", "GeoUDFMethod"]

#: Canonical units per authors' unit: the canonical frame's largest side (the authors' is 1).
FRAME_SCALE = 1.99
#: Gaussian noise (authors' units) and share of the query groups (``scripts/sample.py``).
QUERY_SIGMAS = (0.05, 0.02, 0.003)
QUERY_RATIOS = (0.1, 0.4, 0.5)
#: Queries of an item have their closest surface point within this share of the patch radius.
QUERY_PATCH_SHARE = 0.75
#: Neighbours of the PCA normals of the dense-input path (pymeshlab's default, as ``eval_rec_dense.py``).
DENSE_NORMAL_K = 10
#: UDF of grid points nobody queried (canonical units): far above every threshold of E-MC.
FAR = 1.0


@dataclass(frozen=True)
class GeoUDFBudget(TrainingSet):
    """GeoUDF's budget: its architecture and schedule, the density of a training shape's cloud
    (``points_per_item`` points of its pool) and its training set (:class:`TrainingSet`)."""

    name: str = setting(Param(kind=str, help="budget name"))
    points_per_item: int = setting(Param(kind=int, help="input points of a training shape's cloud (drawn from its pool)", ge=1), override=True)
    knn: int = setting(Param(kind=int, help="neighbours of LGR-Net's EdgeConv graphs", ge=1), override=True)
    width: int = setting(Param(kind=int, help="LGR-Net feature width", ge=1), override=True)
    coefficient_widths: tuple = setting(Param(kind=tuple, item=int, help="hidden widths of the patch head", ge=1), override=True)
    up_ratio: int = setting(Param(kind=int, help="upsampled points per input point", ge=2), override=True)
    udf_k: int = setting(Param(kind=int, help="upsampled points a query's UDF weighs", ge=1), override=True)
    feature_widths: tuple = setting(Param(kind=tuple, item=int, help="widths of the UDF point MLP", ge=1), override=True)
    attention_widths: tuple = setting(Param(kind=tuple, item=int, help="hidden widths of the weight heads", ge=1), override=True)
    patch_points: int = setting(Param(kind=int, help="input points of a training item", ge=1), override=True)
    queries: int = setting(Param(kind=int, help="labelled queries of a training item", ge=1), override=True)
    pu_batch: int = setting(Param(kind=int, help="items per step, stage 1", ge=1), override=True)
    pu_steps: int = setting(Param(kind=int, help="steps of stage 1 (LGR-Net alone)", ge=0), override=True)
    pu_lr: float = setting(Param(kind=float, help="Adam learning rate of stage 1 (constant)", gt=0), override=True)
    rec_batch: int = setting(Param(kind=int, help="items per step, stage 2", ge=1), override=True)
    rec_steps: int = setting(Param(kind=int, help="steps of stage 2 (both networks)", ge=1), override=True)
    rec_lr: float = setting(Param(kind=float, help="Adam learning rate of stage 2 (constant)", gt=0), override=True)
    cd_weight: float = setting(Param(100.0, "weight of the Chamfer distance", ge=0), override=True)
    udf_weight: float = setting(Param(1.0, "weight of the UDF L1 loss", ge=0), override=True)
    grad_weight: float = setting(Param(0.1, "weight of the gradient cosine loss", ge=0), override=True)
    log_every: int = setting(Param(50, "steps between loss reports", ge=1))

    def __post_init__(self):
        check_fields(self, f"geoudf budget '{self.name}'")
        if self.patch_points < self.knn:
            raise ValueError(f"geoudf budget '{self.name}': patch_points {self.patch_points} < knn {self.knn}")
        if self.points_per_item < self.patch_points:
            raise ValueError(f"geoudf budget '{self.name}': points_per_item {self.points_per_item} < patch_points "
                             f"{self.patch_points}")
        if self.pool_points < self.points_per_item:
            raise ValueError(f"geoudf budget '{self.name}': pool_points {self.pool_points} < points_per_item "
                             f"{self.points_per_item} (a shape's cloud is drawn without replacement)")

    def network_config(self) -> dict:
        """Keyword arguments of :func:`methods.pointcloud.geoudf.network.make_geoudf_network`."""
        return dict(knn=self.knn, width=self.width, coefficient_widths=self.coefficient_widths,
                    up_ratio=self.up_ratio, udf_k=self.udf_k, feature_widths=self.feature_widths,
                    attention_widths=self.attention_widths, patch_points=self.patch_points)


#: *paper*: the authors' configuration (``model.py``, ``main_pu.py``, ``main_rec.py``): EdgeConv
#: K 20, width 128, patch head 1152 -> 256 -> 128 -> 64 -> 18, R 16, UDF K 10 with the 64-128-128-128
#: point MLP and 263 -> 256 -> 128 -> 32 -> 1 weight heads; items of 3,000 input points and 2,048
#: queries; stage 1: batches of 16, Adam 1e-3, 100 epochs of the 30,661 ShapeNet training shapes
#: (191,600 steps); stage 2: batches of 12, Adam 1e-4, 300 epochs (766,500 steps). *cpu*: a training
#: for one CPU core (its cost: docs/PROTOCOL.md, "geoudf"): width 32, patch head 64 -> 32 -> 16, the
#: UDF MLP 32-64-64-64 and heads 64 -> 32 -> 16; the authors' K, R, UDF K, learning rates and loss
#: weights; items of 512 points and 512 queries, batches of 4, 1,000 + 2,000 steps. *tiny*: tests.
GEOUDF_FAMILY = register_budget_family("geoudf", (
    GeoUDFBudget("paper", knn=20, width=128, coefficient_widths=(256, 128, 64), up_ratio=16, udf_k=10,
                 feature_widths=(64, 128, 128, 128), attention_widths=(256, 128, 32), patch_points=3_000,
                 queries=2_048, pu_batch=16, pu_steps=191_600, pu_lr=1e-3, rec_batch=12, rec_steps=766_500,
                 rec_lr=1e-4, log_every=500,
               points_per_item=40_000, training_shapes=100, pool_samples=1_000_000, pool_points=1_000_000),
    GeoUDFBudget("cpu", knn=20, width=32, coefficient_widths=(64, 32, 16), up_ratio=16, udf_k=10,
                 feature_widths=(32, 64, 64, 64), attention_widths=(64, 32, 16), patch_points=512,
                 queries=512, pu_batch=4, pu_steps=1_000, pu_lr=1e-3, rec_batch=4, rec_steps=2_000, rec_lr=1e-4,
                 log_every=50,
               points_per_item=40_000, training_shapes=24, pool_samples=200_000, pool_points=200_000),
    GeoUDFBudget("tiny", knn=8, width=16, coefficient_widths=(32, 16), up_ratio=4, udf_k=6,
                 feature_widths=(16, 32), attention_widths=(32, 16), patch_points=256, queries=256, pu_batch=2,
                 pu_steps=60, pu_lr=3e-3, rec_batch=2, rec_steps=120, rec_lr=1e-3, log_every=20,
               points_per_item=10_000, training_shapes=4, pool_samples=20_000, pool_points=20_000)
))



# --------------------------------------------------------------------------------------------------
# Training data
# --------------------------------------------------------------------------------------------------

@dataclass
class GeoUDFPool:
    """One training shape's pools, canonical frame, float32: ``cloud`` (P, 3) input surface points,
    ``target`` (T, 3) upsampling targets, ``queries`` (Q, 3) with ``udf`` (Q,), ``grad`` (Q, 3) and
    ``closest`` (Q, 3) (the closest surface point of each query)."""

    name: str
    cloud: np.ndarray
    target: np.ndarray
    queries: np.ndarray
    udf: np.ndarray
    grad: np.ndarray
    closest: np.ndarray


def query_pool(vertices: np.ndarray, faces: np.ndarray, count: int, rng: np.random.Generator):
    """The authors' query points of a mesh (canonical frame) and their labels (module docstring):
    (queries (Q, 3), udf (Q,), grad (Q, 3), closest (Q, 3)) float64, ``Q = count``, groups in
    :data:`QUERY_SIGMAS` order (sizes by :data:`QUERY_RATIOS`, the remainder to the last)."""
    sizes = [int(count * r) for r in QUERY_RATIOS[:-1]]
    sizes.append(int(count) - sum(sizes))
    groups = []
    for size, sigma in zip(sizes, QUERY_SIGMAS):
        surface, _ = sample_surface(vertices, faces, size, rng)
        groups.append(surface + rng.normal(0.0, sigma * FRAME_SCALE, size=surface.shape))
    queries = np.concatenate(groups)
    udf, grad = ExactFields(vertices, faces).udf(queries, return_grad=True)
    return queries, udf, grad, queries - udf[:, None] * grad


def build_pools(shapes: Sequence, budget: GeoUDFBudget, seed: int) -> list[GeoUDFPool]:
    """The pools of every training shape: ``budget.pool_points`` input points, ``up_ratio x
    budget.points_per_item`` target points, ``budget.pool_samples`` labelled queries; shape i draws
    from its stream of :func:`foundation.seeding.training_streams`. Non-finite labels raise FittingError."""
    if not shapes:
        raise FittingError("no training shapes")
    pools = []
    streams = training_streams(seed).shape_streams(len(shapes))
    for shape, stream in zip(shapes, streams):
        rng = np.random.default_rng(stream)
        cloud, _ = sample_surface(shape.vertices, shape.faces, budget.pool_points, rng)
        target, _ = sample_surface(shape.vertices, shape.faces, budget.up_ratio * budget.points_per_item, rng)
        queries, udf, grad, closest = query_pool(shape.vertices, shape.faces, budget.pool_samples, rng)
        if not (np.all(np.isfinite(udf)) and np.all(np.isfinite(grad))):
            raise FittingError(f"non-finite UDF labels on training shape '{shape.name}'")
        pools.append(GeoUDFPool(shape.name, *(np.ascontiguousarray(a, dtype=np.float32)
                                             for a in (cloud, target, queries, udf, grad, closest))))
    return pools


def _nearest_rows(points: np.ndarray, centre: np.ndarray, count: int) -> tuple[np.ndarray, float]:
    """Indices of the ``count`` rows of ``points`` nearest ``centre`` (any order) and the largest
    of their distances."""
    offset = points - centre
    sq = np.einsum("ij,ij->i", offset, offset)
    rows = np.argpartition(sq, count - 1)[:count] if count < len(points) else np.arange(len(points))
    return rows, float(np.sqrt(sq[rows].max()))


def draw_items(pools: list[GeoUDFPool], budget: GeoUDFBudget, batch: int, with_queries: bool,
               rng: np.random.Generator) -> dict[str, np.ndarray]:
    """One batch of ``batch`` patches (module docstring), authors' frame, float32: ``points`` (B, M, 3),
    ``choice`` (B, M) int64 (each point's (u, v) set), ``target`` (B, R M, 3); with ``with_queries``
    also ``queries`` (B, S, 3), ``udf`` (B, S), ``grad`` (B, S, 3). Shapes distinct within a batch
    (repeats only when there are fewer)."""
    M, R, S = budget.patch_points, budget.up_ratio, budget.queries
    chosen = rng.choice(len(pools), size=batch, replace=batch > len(pools))
    out: dict[str, list] = {k: [] for k in ("points", "target", "queries", "udf", "grad")}
    for index in chosen:
        pool = pools[index]
        cloud = pool.cloud[rng.choice(len(pool.cloud), size=budget.points_per_item, replace=False)]
        seed = cloud[rng.integers(len(cloud))]
        rows, radius = _nearest_rows(cloud, seed, M)
        out["points"].append(cloud[rows])
        out["target"].append(pool.target[_nearest_rows(pool.target, seed, R * M)[0]])
        if with_queries:
            offset = pool.closest - seed
            near = np.flatnonzero(np.einsum("ij,ij->i", offset, offset) <= (QUERY_PATCH_SHARE * radius) ** 2)
            if len(near) == 0:
                near = _nearest_rows(pool.closest, seed, S)[0]
            pick = near[rng.choice(len(near), size=S, replace=S > len(near))]
            out["queries"].append(pool.queries[pick])
            out["udf"].append(pool.udf[pick])
            out["grad"].append(pool.grad[pick])
    batch_arrays = {k: np.stack(v).astype(np.float32) for k, v in out.items() if v}
    for key in ("points", "target", "queries", "udf"):
        if key in batch_arrays:
            batch_arrays[key] /= np.float32(FRAME_SCALE)
    batch_arrays["choice"] = rng.integers(0, R * R, size=(batch, M))
    return batch_arrays


# --------------------------------------------------------------------------------------------------
# Training
# --------------------------------------------------------------------------------------------------

def chamfer_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Chamfer distance of (B, n, 3) and (B, m, 3): per item, the mean squared distance of each
    point to its nearest point of the other set, both ways summed; the mean over the items (the
    authors' ``pytorch3d`` ``chamfer_distance``). The nearest points are found without gradient
    (:func:`methods.pointcloud.geoudf.network.nearest_indices`), the distances differentiated."""
    total = pred.new_zeros(())
    for p, t in zip(pred, target):
        to_target = nearest_indices(p, t)[:, 0].to(p.device)
        to_pred = nearest_indices(t, p)[:, 0].to(p.device)
        total = total + ((p - t[to_target]) ** 2).sum(-1).mean() + ((t - p[to_pred]) ** 2).sum(-1).mean()
    return total / len(pred)


def _udf_batch(model: GeoUDFNetwork, dense: torch.Tensor, normals: torch.Tensor, queries: torch.Tensor):
    """The UDF network on (B, S, 3) queries with their ``udf_k`` nearest points of each item's
    upsampled set (B, n, 3) and normals: (udf (B S,), grad (B S, 3))."""
    neighbours, neighbour_normals = [], []
    for d, n, q in zip(dense, normals, queries):
        idx = nearest_indices(q, d, model.udf_k).to(d.device)
        neighbours.append(d[idx])
        neighbour_normals.append(n[idx])
    return model.udf(queries.reshape(-1, 3), torch.cat(neighbours), torch.cat(neighbour_normals))


def train_geoudf(method, shapes: Sequence, budget: GeoUDFBudget, seed: int = 0, device=None,
                 progress: Callable[..., None] | None = None) -> TrainResult:
    """Train GeoUDF's two stages across ``shapes`` (module docstring) at ``budget`` (its
    architecture, schedule, training set and cloud density).

    ``seed``: the pools, the initialisation (:func:`methods.core.device.seeded_generator`) and every
    batch draw (:func:`foundation.seeding.training_streams`): on the CPU the same seed gives the same
    weights. ``progress(step=..., loss=..., total=pu_steps + rec_steps)`` every ``log_every`` steps.
    Returns a :class:`methods.pointcloud.training_set.TrainResult`: ``final_loss`` of stage 2, ``seconds``
    of both step loops, ``samples_per_s`` in training items (patches) per second."""
    device = get_device(device)
    t0 = time.perf_counter()
    pools = build_pools(shapes, budget, seed)
    pool_seconds = time.perf_counter() - t0
    seeded_generator(seed, device)
    rng = training_streams(seed).batch_rng()
    model = make_geoudf_network(**budget.network_config()).to(device)
    T1, T2 = budget.pu_steps, budget.rec_steps

    def where(offset: int):
        return lambda i: f"step {offset + i} of {T1 + T2} (method '{method.name}', budget '{budget.name}', seed {seed})"

    def tensors(items: dict) -> dict[str, torch.Tensor]:
        return {k: torch.from_numpy(v).to(device) for k, v in items.items()}

    def report(offset: int):
        return None if progress is None else lambda step, loss: progress(step=offset + step, loss=loss, total=T1 + T2)

    def pu_loss(step: int) -> torch.Tensor:
        b = tensors(draw_items(pools, budget, budget.pu_batch, False, rng))
        dense, _ = model.lgr(b["points"], b["choice"])
        return budget.cd_weight * chamfer_loss(dense.flatten(1, 2), b["target"])

    def rec_loss(step: int) -> torch.Tensor:
        b = tensors(draw_items(pools, budget, budget.rec_batch, True, rng))
        dense, normals = model.lgr(b["points"], b["choice"])
        dense, normals = dense.flatten(1, 2), normals.flatten(1, 2)
        cd = chamfer_loss(dense, b["target"])
        udf, grad = _udf_batch(model, dense.detach(), normals.detach(), b["queries"])
        l1 = (udf - b["udf"].reshape(-1)).abs().mean()
        cosine = (1.0 - (grad * b["grad"].reshape(-1, 3)).sum(-1)).mean()
        return budget.cd_weight * cd + budget.udf_weight * l1 + budget.grad_weight * cosine

    seconds = 0.0
    if T1 > 0:
        optimizer = torch.optim.Adam(model.lgr.parameters(), lr=budget.pu_lr)
        seconds += run_steps(model.lgr, optimizer, T1, pu_loss, log_every=budget.log_every, where=where(0),
                             progress=report(0), device=device).seconds
    optimizer = torch.optim.Adam(model.parameters(), lr=budget.rec_lr)
    result = run_steps(model, optimizer, T2, rec_loss, log_every=budget.log_every, where=where(T1),
                       progress=report(T1), device=device)
    seconds += result.seconds
    model.eval()
    items = T1 * budget.pu_batch + T2 * budget.rec_batch
    return TrainResult(model=model, losses=result.losses, seconds=seconds, steps=T1 + T2,
                          samples_per_s=items / max(seconds, 1e-9), final_loss=result.final_loss,
                          pool_seconds=pool_seconds)


# --------------------------------------------------------------------------------------------------
# Inference
# --------------------------------------------------------------------------------------------------

def cover_patches(points: np.ndarray, patch_points: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Patches covering a cloud (P, 3): (members (n, M) int64, seeds (n,) int64), M = min(patch_points,
    P). Greedy: the points in a random order; the first point not yet in a patch seeds the next patch,
    its M nearest points (seed included), until every point is in one."""
    P = len(points)
    M = min(int(patch_points), P)
    tree = KDTree(np.ascontiguousarray(points, dtype=np.float64))
    order = rng.permutation(P)
    covered = np.zeros(P, dtype=bool)
    members, seeds = [], []
    while True:
        free = order[~covered[order]]
        if len(free) == 0:
            break
        _, idx = tree.query(points[free[:1]], k=M)
        idx = np.asarray(idx, dtype=np.int64).reshape(M)
        members.append(idx)
        seeds.append(free[0])
        covered[idx] = True
    return np.stack(members), np.asarray(seeds, dtype=np.int64)


def upsample(model: GeoUDFNetwork, points: np.ndarray, rng: np.random.Generator, device=None,
             batch: int = 16) -> tuple[np.ndarray, np.ndarray, int]:
    """LGR-Net on a cloud (P, 3), authors' frame, eval mode, by patches of ``model.patch_points``
    points as it was trained (:func:`cover_patches`; ``batch`` patches per forward pass), each
    point's (u, v) set drawn from ``rng``; a point's R upsampled points come from the patch whose
    seed is nearest to it among those holding it. Returns (dense (R P, 3), normals (R P, 3)) float32
    (point i's at rows ``R i .. R i + R - 1``) and the number of patches."""
    device = device or next(model.parameters()).device
    points = np.ascontiguousarray(points, dtype=np.float32)
    R = model.lgr.up_ratio
    members, seeds = cover_patches(points, model.patch_points, rng)
    n, M = members.shape
    choice = rng.integers(0, R * R, size=(n, M))
    gap = points[members] - points[seeds][:, None, :]
    flat = members.reshape(-1)
    order = np.lexsort((np.einsum("ijk,ijk->ij", gap, gap).reshape(-1), flat))
    first = order[np.r_[True, flat[order][1:] != flat[order][:-1]]]  # per point, its nearest seed's slot
    dense, normals = [], []
    with torch.inference_mode():
        for i in range(0, n, batch):
            x = torch.from_numpy(points[members[i:i + batch]]).to(device)
            c = torch.from_numpy(choice[i:i + batch]).to(device)
            d, nrm = model.lgr(x, c)
            dense.append(d.float().cpu().numpy().reshape(-1, R, 3))
            normals.append(nrm.float().cpu().numpy().reshape(-1, R, 3))
    dense, normals = np.concatenate(dense)[first], np.concatenate(normals)[first]
    return dense.reshape(-1, 3), normals.reshape(-1, 3), n


def udf_and_gradient(model: GeoUDFNetwork, dense: np.ndarray, normals: np.ndarray, queries: np.ndarray,
                     device=None, chunk: int = 8_192) -> tuple[np.ndarray, np.ndarray]:
    """The geometry-guided UDF (Q,) and its unit gradient (Q, 3), float32, of ``queries`` (Q, 3),
    each with its ``udf_k`` nearest points of ``dense`` (n, 3) (and their ``normals``); authors' frame."""
    queries = np.ascontiguousarray(queries, dtype=np.float32)
    if len(queries) == 0:
        return np.zeros(0, np.float32), np.zeros((0, 3), np.float32)
    device = device or next(model.parameters()).device
    with stage("knn"):
        index = knn_neighbourhoods(dense, queries, model.udf_k)
    udf, grad = [], []
    with torch.inference_mode():
        for i in range(0, len(queries), chunk):
            rows = index[i:i + chunk]
            u, g = model.udf(torch.from_numpy(queries[i:i + chunk]).to(device),
                             torch.from_numpy(dense[rows]).to(device),
                             torch.from_numpy(normals[rows]).to(device))
            udf.append(u.float().cpu().numpy())
            grad.append(g.float().cpu().numpy())
    return np.concatenate(udf), np.concatenate(grad)


@register_method(order=160, color="#24347f")
class GeoUDFMethod(OwnNetworkMethod):
    name = "geoudf"
    description = "GeoUDF: LGR-Net upsampling with normals, geometry-guided UDF and gradient, edge-based marching cubes"
    network_kind = "point"
    output_dim = 1
    extractor = "E-MC"
    network_label = "GeoUDF"
    build_network = staticmethod(make_geoudf_network)
    budget_family = "geoudf"
    training_modules = ("methods.pointcloud.geoudf.network", "methods.pointcloud.training_set")
    parameters = {
        "band": Param(2.0, "grid points within this many h of an upsampled point get the network's UDF", gt=0),
        "cull": Param(2.0, "E-MC tests the cells whose lowest corner has UDF <= cull h", gt=0),
        "near": Param(1.1, "a corner pair is cut by gradients only if both UDFs are < near h", gt=0),
        "snap": Param(0.0005, "a UDF below it (authors' units) lies on the surface", ge=0),
        "upsample": Param(False, "LGR-Net's upsampled points and normals (false: the authors' dense-input path, "
                                 "the input points with PCA normals)"),
    }

    def train_network(self, shapes, budget, seed, device=None, progress=None) -> TrainResult:
        return train_geoudf(self, shapes, budget, seed=seed, device=device, progress=progress)

    def reconstruct(self, points, N, device=None, seed=0, model=None) -> Extraction:
        model, device = self.network_on_device(model, device)
        points = self.checked_points(points)
        if len(points) < model.lgr.knn:
            raise TooFewPointsError("geoudf", len(points), model.lgr.knn, "LGR-Net")
        h = spacing(N)
        if self.params["upsample"]:
            with stage("upsample"):
                dense, normals, patches = upsample(model, points / FRAME_SCALE, np.random.default_rng(seed), device)
        else:
            point_set = oriented_point_set(points, DENSE_NORMAL_K)  # keep the MeshSet alive while reading
            normals = np.array(current_mesh(point_set)[2].vertex_normal_matrix(), dtype=np.float32)
            dense = np.ascontiguousarray(points / FRAME_SCALE, dtype=np.float32)
            patches = 0
        dense_canonical = dense.astype(np.float64) * FRAME_SCALE
        with stage("band"):
            ijk = band_points(dense_canonical, N, self.params["band"] * h)
            udf = np.full((N, N, N), FAR)
            grad = np.zeros((N, N, N, 3))
            known = np.zeros((N, N, N), dtype=bool)
            known[tuple(ijk.T)] = True
            corners = np.unique(np.minimum(ijk[:, None, :] + CORNERS[None], N - 1).reshape(-1, 3), axis=0)
            corners = corners[~known[tuple(corners.T)]]
            udf[tuple(corners.T)] = nearest_distance(dense_canonical, point_inputs(N, corners))
        with stage("field"):
            u, g = udf_and_gradient(model, dense, normals, point_inputs(N, ijk) / FRAME_SCALE, device)
            udf[tuple(ijk.T)] = u.astype(np.float64) * FRAME_SCALE
            grad[tuple(ijk.T)] = g
        with stage("emc"):
            mesh = edge_marching_cubes(udf, grad, snap=self.params["snap"] * FRAME_SCALE,
                                       cull=self.params["cull"], near=self.params["near"])
        mesh.info.update(upsampled_points=int(len(dense)), patches=patches, queried_points=int(len(ijk)))
        return mesh

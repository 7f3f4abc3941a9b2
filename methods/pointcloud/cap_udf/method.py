"""``cap-udf``: CAP-UDF (Zhou, Ma, Li, Liu, Fang, Han; NeurIPS 2022 / TPAMI 2024), "Learning
consistency-aware unsigned distance functions progressively from raw point clouds", written after
the authors' code (github.com/junshengzhou/CAP-UDF: ``run.py``, ``models/dataset.py``,
``models/fields.py``, ``confs/base.conf``, ``tools/surface_extraction.py``, ``tools/utils.py``).

A per-shape optimisation from the raw cloud, no pre-training:

1. Frame: the cloud is centred on its bounding box and divided by its largest side (the authors'
   ``process_data``), ``x_a = (x - c) / s``; the network lives in that frame. The canonical cloud
   (bounding box largest side 1.99) is thus scaled by about 1 / 1.99, and the constants below
   (``df_filter``, ``outlier``) are in the authors' units. The run's grid points are mapped into
   that frame and the distances back (``s f(x_a)``), so the mesh comes out in the canonical frame.
2. Queries (:func:`query_samples`): per input point, sigma = distance to its 50th nearest other
   point; ``queries // P`` rounds of ``x = p + s sigma_p n``, n ~ N(0, I), s = 0.25 max(1,
   sqrt(P / 20000)); each query's target is its nearest input point.
3. Field consistency (:func:`field_consistency_loss`): a batch of queries is pulled to
   ``x' = x - f(x) grad f / |grad f|`` (:func:`methods.pointcloud.cap_udf.network.pull`) and compared with
   the batch's targets by the L1 Chamfer distance ``(mean_a min_b |a - b| + mean_b min_a |a - b|) / 2``.
4. Progressive surface approximation (:func:`densify`): after ``step1`` steps, queries drawn around
   the targets with ``1.1 x`` the standard deviation of the query offsets are pulled; the pulled
   points with ``f < df_filter`` within ``outlier`` of the cloud are downsampled to
   ``extra_points_rate x P`` points and added to the cloud; each query's target becomes its
   nearest point of the denser cloud, and the optimisation goes on with ``batch_step2`` queries.
5. Adam at ``lr``, linear warm-up over ``warm_up`` steps, then a cosine decay to 0 at ``steps``.
6. Extraction (:mod:`methods.pointcloud.cap_udf.extraction`): the network's distance and gradient on the run's
   grid, signs from the gradient field per cell, marching cubes per cell.

Budgets (:data:`CAP_UDF_FAMILY`, ``--budget``): ``paper`` is the authors' ``confs/base.conf``; ``cpu`` a reduced
network and schedule for one CPU core; ``tiny`` for tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy import ndimage
from scipy.spatial import cKDTree

from foundation.grid import spacing
from foundation.params import Param, check_fields, setting
from foundation.timing import stage
from methods.core.schedules import warmup_then_cosine
from methods.base import Extraction, PointCloudMethod, register_method
from methods.core.budgets import register_budget_family
from methods.pointcloud.cap_udf.extraction import gradient_sign_marching_cubes, remove_far_faces
from methods.pointcloud.cap_udf.network import CAPUDFNetwork, pull, udf_and_gradient
from methods.core.device import get_device, seeded_generator
from methods.pointcloud.neighbourhoods import band_points, knn_neighbourhoods
from foundation.grid import point_inputs
from methods.core.training_loop import run_steps

#: The authors' sigma: distance to the 51st point of a KD-tree query, the point itself the first.
SIGMA_NEIGHBOUR = 50
#: Pulled points per batch when the cloud is densified (the authors' ``get_train_data(5000)``).
DENSIFY_BATCH = 5000
#: The densification draws at most this many times the batches ``generated`` needs when every pulled
#: point is kept (the authors loop until ``generated`` are kept, which never ends on a network that
#: puts no query below ``df_filter``).
MAX_DENSIFY_ROUNDS = 20
#: Distance (canonical units) given to grid points that are not queried (far from the cloud).
FAR = 1.0


@dataclass(frozen=True)
class CAPUDFBudget:
    """CAP-UDF's budget: its per-shape optimisation (names of ``confs/base.conf`` in brackets).

    width, hidden_layers, skip : the MLP (``d_hidden`` 256, ``n_layers`` 8, ``skip_in`` [4]).
    queries : query points drawn in all (1,000,000; ``queries // P`` per input point).
    batch, batch_step2 : queries per step before / after the densification (5,000 / 20,000).
    step1, steps : the step of the densification and the last step (``step1_maxiter`` 40,000,
        ``step2_maxiter`` 60,000).
    warm_up, lr : linear warm-up steps and peak learning rate (1,000, 1e-3).
    generated : pulled points drawn at the densification (``eval_num_points`` 1,000,000).
    df_filter : pulled points with f below it are kept (0.01, authors' units).
    outlier : ... and within it of the cloud (0.002, authors' units).
    extra_points_rate : points added, per input point (1).
    low_range : the densification's queries spread ``low_range`` x the queries' offset std (1.1).
    """

    name: str = setting(Param(kind=str, help="budget name"))
    width: int = setting(Param(kind=int, help="width of the MLP", ge=1), override=True)
    hidden_layers: int = setting(Param(kind=int, help="hidden layers of the MLP", ge=1), override=True)
    skip: int = setting(Param(kind=int, help="layer that takes the input again (skip connection)", ge=1), override=True)
    queries: int = setting(Param(kind=int, help="query points drawn in all", ge=1), override=True)
    batch: int = setting(Param(kind=int, help="queries per step before the densification", ge=1), override=True)
    batch_step2: int = setting(Param(kind=int, help="queries per step after the densification", ge=1), override=True)
    step1: int = setting(Param(kind=int, help="step of the densification", ge=0), override=True)
    steps: int = setting(Param(kind=int, help="optimizer steps in all", ge=1), override=True)
    warm_up: int = setting(Param(kind=int, help="steps of the linear warm-up", ge=0), override=True)
    lr: float = setting(Param(1e-3, "peak Adam learning rate", gt=0), override=True)
    generated: int = setting(Param(1_000_000, "pulled points drawn at the densification", ge=1), override=True)
    df_filter: float = setting(Param(0.01, "pulled points with a distance below this are kept (authors' units)",
                                     gt=0), override=True)
    outlier: float = setting(Param(0.002, "... and within this of the cloud (authors' units)", gt=0), override=True)
    extra_points_rate: float = setting(Param(1.0, "points added at the densification, per input point", ge=0),
                                       override=True)
    low_range: float = setting(Param(1.1, "spread of the densification's queries, x the query offsets' std", gt=0),
                               override=True)

    def __post_init__(self):
        check_fields(self, f"cap-udf budget '{self.name}'")
        if not self.step1 <= self.steps:
            raise ValueError(f"cap-udf budget '{self.name}': step1 {self.step1} > steps {self.steps}")


#: *paper*: the authors' ``confs/base.conf`` (a GPU). *cpu*: a reduced network and schedule for one
#: CPU core (its cost per shape: docs/PROTOCOL.md, "cap-udf"). *tiny*: tests.
CAP_UDF_FAMILY = register_budget_family("cap-udf", (
    CAPUDFBudget("paper", width=256, hidden_layers=8, skip=4, queries=1_000_000, batch=5000, batch_step2=20000,
                 step1=40_000, steps=60_000, warm_up=1000),
    CAPUDFBudget("cpu", width=64, hidden_layers=8, skip=4, queries=1_000_000, batch=500, batch_step2=1000,
                 step1=5600, steps=8400, warm_up=140, generated=200_000),
    CAPUDFBudget("tiny", width=64, hidden_layers=4, skip=2, queries=60_000, batch=500, batch_step2=1000,
                 step1=200, steps=300, warm_up=10, generated=20_000),
))


def authors_frame(points: np.ndarray) -> tuple[np.ndarray, float]:
    """The authors' normalisation of a cloud: (centre (3,), scale) with ``(x - centre) / scale`` its
    bounding box centred at the origin with its largest side 1."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    scale = float((hi - lo).max())
    if not scale > 0:
        raise ValueError("cap-udf: the point cloud has no extent (all points coincide)")
    return (lo + hi) / 2, scale


def query_samples(cloud: np.ndarray, queries: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The authors' query points around ``cloud`` (P, 3) and their nearest cloud points.

    sigma_p: distance from p to its :data:`SIGMA_NEIGHBOUR`-th nearest other point; ``max(1, queries
    // P)`` rounds of ``p + s sigma_p n`` (n standard normal, s = 0.25 max(1, sqrt(P / 20000))).
    Returns (M, 3) float64 queries and (M, 3) float64 targets (each query's nearest cloud point).
    """
    P = len(cloud)
    tree = cKDTree(cloud)
    sigma = tree.query(cloud, k=SIGMA_NEIGHBOUR + 1)[0][:, -1]
    s = 0.25 * max(1.0, math.sqrt(P / 20000.0))
    rounds = max(1, queries // P)
    noise = rng.standard_normal((rounds, P, 3))
    samples = (cloud[None] + s * sigma[None, :, None] * noise).reshape(-1, 3)
    nearest = tree.query(samples)[1]
    return samples, cloud[nearest]


def nearest_indices(queries: torch.Tensor, points: torch.Tensor, chunk: int = 4096) -> torch.Tensor:
    """Index (Q,) int64 of the nearest row of ``points`` (R, 3) for each row of ``queries`` (Q, 3),
    no gradient: the project's KD-tree (:func:`knn_neighbourhoods`, float64) on the CPU, chunked
    ``cdist`` on CUDA (the same neighbours up to ties).

    It runs inside the fit's denormal flush (:func:`methods.core.device.flush_denormals`), where
    scipy's ``cKDTree`` can recurse without end on clouds with coplanar and repeated points (a
    segmentation fault, not an error): hence not ``cKDTree`` here."""
    if queries.device.type == "cpu":
        idx = knn_neighbourhoods(points.detach().numpy(), queries.detach().numpy(), 1)[:, 0]
        return torch.from_numpy(idx)
    with torch.no_grad():
        return torch.cat([torch.cdist(queries[i:i + chunk], points).argmin(dim=1)
                          for i in range(0, len(queries), chunk)])


def field_consistency_loss(targets: torch.Tensor, moved: torch.Tensor) -> torch.Tensor:
    """The authors' L1 Chamfer distance between ``targets`` (B, 3) and the pulled queries ``moved``
    (B', 3): ``(mean_t min_m |t - m| + mean_m min_t |m - t|) / 2`` (Euclidean distances)."""
    to_moved = (targets - moved[nearest_indices(targets, moved)]).norm(dim=1)
    to_targets = (moved - targets[nearest_indices(moved, targets)]).norm(dim=1)
    return 0.5 * (to_moved.mean() + to_targets.mean())


def learning_rate(step: int, config: CAPUDFBudget) -> float:
    """The authors' schedule at 0-based ``step``: ``lr step / warm_up`` during the warm-up, then
    ``lr (1 + cos(pi (step - warm_up) / (steps - warm_up))) / 2``."""
    return config.lr * warmup_then_cosine(step, config.steps, config.warm_up)


def voxel_downsample(points: np.ndarray, count: int, halvings: int = 24) -> np.ndarray:
    """Indices of about ``count`` (at least, when ``points`` has more) evenly spread rows of
    ``points`` (M, 3): the largest voxel size (bisection, ``halvings`` steps) whose occupied voxels
    number at least ``count``, one point per voxel (the one nearest its centre)."""
    if len(points) <= count:
        return np.arange(len(points))
    lo_corner = points.min(axis=0)

    def voxels(size):
        cell = np.floor((points - lo_corner) / size).astype(np.int64)
        return cell, np.unique(cell, axis=0).shape[0]

    small, large = 0.0, float((points.max(axis=0) - lo_corner).max()) + 1e-9
    for _ in range(halvings):
        mid = 0.5 * (small + large)
        if voxels(mid)[1] >= count:
            small = mid
        else:
            large = mid
    size = small if small > 0 else large
    cell, _ = voxels(size)
    off_centre = np.linalg.norm(points - lo_corner - (cell + 0.5) * size, axis=1)
    _, key = np.unique(cell, axis=0, return_inverse=True)
    order = np.lexsort((off_centre, key.reshape(-1)))
    first = np.ones(len(order), dtype=bool)
    first[1:] = key.reshape(-1)[order][1:] != key.reshape(-1)[order][:-1]
    return np.sort(order[first])


def densify(model: torch.nn.Module, cloud: np.ndarray, targets: torch.Tensor, samples: torch.Tensor,
            config: CAPUDFBudget, rng: np.random.Generator) -> np.ndarray:
    """The authors' progressive surface approximation (``gen_extra_pointcloud``): extra surface
    points (E, 3) from the network, in the authors' frame.

    Batches of :data:`DENSIFY_BATCH` (target, query) pairs: new queries ``target + n``, n ~ N(0,
    (low_range std)^2 I) with std the standard deviation of the batch's offsets ``query - target``,
    are pulled; those with ``f < df_filter`` are kept until ``generated`` are collected (or
    :data:`MAX_DENSIFY_ROUNDS` x ``generated / DENSIFY_BATCH`` batches are drawn); those within
    ``outlier`` of ``cloud`` are downsampled (:func:`voxel_downsample`, the authors: Poisson-disk) to
    ``extra_points_rate x P``.
    """
    kept, total = [], 0
    for _ in range(MAX_DENSIFY_ROUNDS * -(-config.generated // DENSIFY_BATCH)):
        if total >= config.generated:
            break
        rows = torch.from_numpy(rng.choice(len(samples), DENSIFY_BATCH, replace=False)).to(samples.device)
        near, query = targets[rows], samples[rows]
        std = float(torch.std(query - near)) * config.low_range
        noise = torch.from_numpy(rng.normal(0.0, std, size=(DENSIFY_BATCH, 3)).astype(np.float32)).to(near.device)
        moved, d = pull(model, near + noise)
        moved = moved.detach()[d.detach() < config.df_filter]
        kept.append(moved.cpu().numpy().astype(np.float64))
        total += len(moved)
    generated = np.concatenate(kept)[:config.generated] if kept else np.zeros((0, 3))
    dist = cKDTree(cloud).query(generated, distance_upper_bound=config.outlier)[0]
    generated = generated[dist < config.outlier]
    return generated[voxel_downsample(generated, int(config.extra_points_rate * len(cloud)))]


@dataclass
class CAPUDFFit:
    """A fitted CAP-UDF network (eval mode, authors' frame) and facts of the fit."""

    model: CAPUDFNetwork
    seconds: float
    final_loss: float
    extra_points: int


def fit_cap_udf(cloud: np.ndarray, config: CAPUDFBudget, seed: int = 0, device=None) -> CAPUDFFit:
    """Optimise a CAP-UDF network on ``cloud`` (P, 3) in the authors' frame (module docstring,
    steps 2-5), seeded from ``seed`` (network init, query noise, batches)."""
    device = get_device(device)
    rng = np.random.default_rng(seed)
    seeded_generator(seed, device)
    model = CAPUDFNetwork(config.width, config.hidden_layers, config.skip).to(device)
    with stage("queries"):
        samples_np, targets_np = query_samples(cloud, config.queries, rng)
        samples = torch.from_numpy(samples_np.astype(np.float32)).to(device)
        targets = torch.from_numpy(targets_np.astype(np.float32)).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    batch = [config.batch]

    def step_loss(step: int) -> torch.Tensor:
        rows = torch.from_numpy(rng.choice(len(samples), batch[0], replace=False)).to(device)
        moved, _ = pull(model, samples[rows], create_graph=True)
        return field_consistency_loss(targets[rows], moved)

    def where(i: int) -> str:
        return f"cap-udf step {i}"

    with stage("fit"):
        first = run_steps(model, optimizer, config.step1, step_loss, log_every=100, where=where,
                          learning_rate=lambda group, step: learning_rate(step, config), device=device)
    with stage("densify"):
        extra = densify(model, cloud, targets, samples, config, rng)
        dense = np.concatenate([cloud, extra])
        nearest = cKDTree(dense).query(samples_np)[1]
        targets = torch.from_numpy(dense[nearest].astype(np.float32)).to(device)
    batch[0] = config.batch_step2
    with stage("fit"):
        second = run_steps(model, optimizer, config.steps - config.step1, step_loss, log_every=100,
                           where=lambda i: where(config.step1 + i),
                           learning_rate=lambda group, step: learning_rate(config.step1 + step, config), device=device)
    return CAPUDFFit(model=model.eval(), seconds=first.seconds + second.seconds, final_loss=second.final_loss,
                     extra_points=int(len(extra)))


def grid_udf(model: torch.nn.Module, ijk: np.ndarray, N: int, centre: np.ndarray, scale: float,
             device=None, chunk: int = 16_384) -> tuple[np.ndarray, np.ndarray]:
    """The network at the grid points ``ijk`` (Q, 3): distances (Q,) float32 in canonical units and
    their gradients (Q, 3) float32 (direction as in the canonical frame)."""
    device = get_device(device)
    x = (point_inputs(N, ijk).astype(np.float64) - centre) / scale
    x = torch.from_numpy(x.astype(np.float32)).to(device)
    udf, grad = np.zeros(len(x), np.float32), np.zeros((len(x), 3), np.float32)
    for i in range(0, len(x), chunk):
        d, g = udf_and_gradient(model, x[i:i + chunk])
        udf[i:i + chunk] = (d.detach() * scale).cpu().numpy()
        grad[i:i + chunk] = g.detach().cpu().numpy()
    return udf, grad


@register_method(order=150, color="#b5179e")
class CAPUDFMethod(PointCloudMethod):
    name = "cap-udf"
    description = ("CAP-UDF: a per-shape UDF MLP pulled onto the raw cloud (field consistency, progressive "
                   "densification), gradient-sign marching cubes")
    extractor = "CAP-UDF gradient-sign marching cubes"
    budget_family = "cap-udf"
    parameters = {
        "band": Param(2.0, "grid points within this many h of an input point (and their grid neighbours) are "
                      "queried; the others are far", gt=0),
        "cell_threshold": Param(1.16, "cells whose smallest corner UDF exceeds this x h are skipped (the authors: "
                                "0.005 of the unit box at their 256 grid, 1.16 h)", gt=0),
        "far": Param(0.0, "faces whose mean vertex distance to the cloud is >= this x h are removed; 0: off "
                     "(the authors' base.conf)", ge=0),
    }

    def reconstruct(self, points: np.ndarray, N: int, device=None, seed: int = 0, *,
                    budget: CAPUDFBudget) -> Extraction:
        """A mesh from ``points`` by CAP-UDF's optimisation at ``budget`` (a record of its family)."""
        points = self.checked_points(points)
        if len(points) <= SIGMA_NEIGHBOUR:
            raise ValueError(f"cap-udf: {len(points)} points, it needs more than {SIGMA_NEIGHBOUR} (its query "
                             f"spread is the distance to the {SIGMA_NEIGHBOUR}th neighbour)")
        device = get_device(device)
        centre, scale = authors_frame(points)
        fitted = fit_cap_udf((points - centre) / scale, budget, seed=seed, device=device)
        h = spacing(N)
        with stage("field"):
            mask = np.zeros((N, N, N), dtype=bool)
            mask[tuple(band_points(points, N, self.params["band"] * h).T)] = True
            ijk = np.argwhere(ndimage.binary_dilation(mask, structure=np.ones((3, 3, 3), dtype=bool)))
            values, grads = grid_udf(fitted.model, ijk, N, centre, scale, device)
            udf = np.full((N, N, N), FAR, dtype=np.float32)
            grad = np.zeros((N, N, N, 3), dtype=np.float32)
            udf[tuple(ijk.T)], grad[tuple(ijk.T)] = values, grads
        with stage("extract"):
            mesh = gradient_sign_marching_cubes(udf, grad, self.params["cell_threshold"] * h)
            V, F = mesh.vertices, mesh.faces
            if self.params["far"] > 0:
                V, F = remove_far_faces(V, F, points, self.params["far"] * h)
        return Extraction(V, F, info={"fit_s": fitted.seconds, "final_loss": fitted.final_loss,
                                      "extra_points": fitted.extra_points, "queried_points": int(len(ijk))})

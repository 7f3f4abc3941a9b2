"""POCO (methods/pointcloud/poco/method.py, methods/pointcloud/poco/network.py): properties of its layers a reader can check by
hand, the weights' round trip, determinism, and a ``tiny`` training that reconstructs a sphere.

* FKAConv is a function of the point *set*: permuting the input cloud permutes its output rows the
  same way, and reordering each support point's neighbours changes nothing (sums and maxima over
  the neighbours); the whole backbone too, since its subsampling depends on positions only.
* The decoder's attention weights are a mean of softmaxes over the K neighbours: each is >= 0 and
  they sum to 1 for every query.
* The sphere: radius 0.7 at the origin, 1,000 area-uniform points (twice the ``tiny`` training
  cloud), grid 32 (h = 0.065). A ``tiny`` training (300 steps) reaches
  CD-L1 0.047 and a mean vertex radius error of 0.047 at seed 0; the bounds, 0.09 (under 1.4 h),
  fail a mesh whose sheets sit at the 3 h band's edge (0.19 off).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import trimesh

from methods.base import get_method
from methods.pointcloud.neighbourhoods import knn_neighbourhoods
from methods.pointcloud.training_set import training_shapes
import methods.pointcloud.poco.method as poco
from methods.pointcloud.errors import TooFewPointsError
from methods.pointcloud.poco.network import (AttentionDecoder, FKAConv, batch_structures, cloud_structure, make_poco_network,
                                  quantized_subsample)
from tests.learned_checks import check_training_is_deterministic, check_weights_round_trip, sphere_cloud

pytestmark = pytest.mark.usefixtures("torch_threads")

TINY = poco.POCO_FAMILY.budgets.get("tiny")
SPHERE_RADIUS = 0.7
SPHERE_CD_BOUND = 0.09
SPHERE_RADIUS_BOUND = 0.09


def _cloud(n: int, seed: int = 0) -> np.ndarray:
    return sphere_cloud(n, SPHERE_RADIUS, seed).astype(np.float32)


def _small_network(seed: int = 0):
    torch.manual_seed(seed)
    return make_poco_network(hidden=8, levels=2, conv_k=8, latent=8, decoder_k=8, heads=4, input_points=400).eval()


def test_fkaconv_output_follows_a_permutation_of_the_input_points():
    torch.manual_seed(0)
    conv = FKAConv(4, 6, kernel_size=8).eval()
    points = _cloud(300)
    features = np.random.default_rng(1).standard_normal((300, 4)).astype(np.float32)
    perm = np.random.default_rng(2).permutation(300)

    def run(p, f, index=None):
        index = knn_neighbourhoods(p, p, 8) if index is None else index
        pt, ft = torch.from_numpy(p)[None], torch.from_numpy(f)[None]
        with torch.no_grad():
            return conv(ft, pt, pt, torch.from_numpy(index)[None])[0].numpy(), index

    out, index = run(points, features)
    out_permuted, _ = run(points[perm], features[perm])
    np.testing.assert_allclose(out_permuted, out[perm], atol=1e-5)
    shuffled = np.take_along_axis(index, np.random.default_rng(3).permuted(np.tile(np.arange(8), (300, 1)), axis=1), 1)
    np.testing.assert_allclose(run(points, features, shuffled)[0], out, atol=1e-5)


def test_backbone_latents_follow_a_permutation_of_the_cloud():
    net = _small_network()
    points = _cloud(400)
    perm = np.random.default_rng(4).permutation(400)
    np.testing.assert_array_equal(np.sort(quantized_subsample(points[perm], 100)),
                                  np.sort(np.argsort(perm)[quantized_subsample(points, 100)]))

    def latents(p):
        with torch.no_grad():
            return net.latents(batch_structures([cloud_structure(p, 2, 8)], "cpu"))[0].numpy()

    np.testing.assert_allclose(latents(points[perm]), latents(points)[perm], atol=1e-4)


def test_decoder_attention_weights_are_nonnegative_and_sum_to_one():
    torch.manual_seed(0)
    decoder = AttentionDecoder(latent=8, heads=5)
    latents, offsets = torch.randn(7, 11, 8), torch.randn(7, 11, 3)
    weights, values = decoder.weights_and_values(latents, offsets)
    assert weights.shape == (7, 11) and values.shape == (7, 11, 8)
    assert float(weights.detach().min()) >= 0.0
    torch.testing.assert_close(weights.sum(dim=-1), torch.ones(7))
    logits = decoder(latents, offsets)
    torch.testing.assert_close(logits, decoder.out((weights.unsqueeze(-1) * values).sum(dim=1)))


def test_weights_round_trip_and_bad_weights_are_refused():
    check_weights_round_trip(get_method("poco"), _small_network(), TINY, "POCO weights", "occ-knn")


def test_reconstruct_is_deterministic_and_refuses_an_empty_cloud():
    method = get_method("poco", views=2, refine_steps=2)
    net = _small_network()
    points = _cloud(1000).astype(np.float64)
    a = method.reconstruct(points, 24, seed=3, model=net)
    b = method.reconstruct(points, 24, seed=3, model=net)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    assert a.info["backbone_passes"] >= 2 * 1000 // 400
    with pytest.raises(ValueError, match="no points"):
        method.reconstruct(np.zeros((0, 3)), 24, model=net)
    with pytest.raises(TooFewPointsError, match="poco: 7 points, fewer than the decoder's 8 neighbours"):
        method.reconstruct(points[:7], 24, model=net)


def test_a_block_window_too_sparse_for_the_decoder_gives_no_surface():
    from methods.pointcloud.blocks import Block, window_piece

    method, net = get_method("poco", views=2, refine_steps=2), _small_network()
    block = Block(32, (0, 0, 0), (16, 16, 16))  # the lower octant of a 32^3 scene grid, in a 24-point window
    corner = _cloud(1000).astype(np.float64)
    corner = corner[np.all(corner < 0, axis=1)][:6]  # 6 points, all inside the window: the decoder needs 8
    with pytest.raises(TooFewPointsError):
        method.reconstruct(corner, 24, model=net)
    V, F = window_piece(method, corner, block, 24, min_points=1, model=net)
    assert V.shape == (0, 3) and F.shape == (0, 3)


def test_training_is_deterministic():
    check_training_is_deterministic(get_method("poco"), dataclasses.replace(TINY, steps=3, log_every=1))


@pytest.mark.slow
@pytest.mark.learned
def test_tiny_training_reconstructs_a_sphere(measured):
    from foundation.metrics import evaluate

    method = get_method("poco", views=2)
    trained = method.train_network(training_shapes(TINY.training_shapes), TINY, seed=0)
    out = method.reconstruct(_cloud(1000).astype(np.float64), 32, model=trained.model)
    sphere = trimesh.creation.icosphere(5, radius=SPHERE_RADIUS)
    cd = evaluate(np.asarray(sphere.vertices), np.asarray(sphere.faces), out.vertices, out.faces, n_points=20_000)["cd"]
    radius_error = float(np.abs(np.linalg.norm(out.vertices, axis=1) - SPHERE_RADIUS).mean())
    measured(cd=cd, radius_error=radius_error, final_loss=trained.final_loss)
    assert len(out.faces) > 0
    assert cd <= SPHERE_CD_BOUND, f"CD {cd:.4f} > {SPHERE_CD_BOUND}"
    assert radius_error <= SPHERE_RADIUS_BOUND, f"mean radius error {radius_error:.4f} > {SPHERE_RADIUS_BOUND}"

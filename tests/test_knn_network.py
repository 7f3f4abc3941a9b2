"""The K-NN local networks of point-cloud reconstruction: a permutation-invariant local encoder, separate u and v encoders for segments, rebuild from config,
budgets, and a tiny overfit of a UDF."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from methods.pointcloud.knn.network import LocalEncoder, PointKNNNetwork, SegmentKNNNetwork, make_knn_network
from methods.pointcloud.knn.training import KNN_BUDGETS, KNNBudget
from methods.pointcloud.neighbourhoods import knn_neighbourhoods

SMALL = dict(encoder_width=16, encoder_depth=1, head_width=16, head_depth=1)


@pytest.fixture(autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _batch(B=64, K=8, seed=0, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    segments = torch.rand(B, 2, 3, generator=g, dtype=dtype) * 2 - 1
    neighbours = segments.mean(dim=1, keepdim=True) + 0.05 * torch.randn(B, K, 3, generator=g, dtype=dtype)
    return segments, neighbours


def _trained_stats(net, *inputs):
    """One train-mode forward (BatchNorm running statistics move off their init), then eval mode."""
    net.train()
    with torch.no_grad():
        net(*inputs)
    return net.eval()


@pytest.mark.parametrize("kind", ["segment", "point"])
def test_output_invariant_to_the_order_of_the_neighbours(kind):
    segments, neighbours = _batch(B=64, K=8)
    anchors = segments if kind == "segment" else segments[:, 0]
    torch.manual_seed(0)
    net = _trained_stats(make_knn_network(kind, **SMALL), anchors, neighbours)
    # a different random permutation of the K neighbours in every row
    perm = torch.argsort(torch.rand(64, 8, generator=torch.Generator().manual_seed(1)), dim=1)
    shuffled = torch.take_along_dim(neighbours, perm[:, :, None], dim=1)
    assert not torch.equal(shuffled, neighbours)
    with torch.no_grad():
        a, b = net(anchors, neighbours), net(anchors, shuffled)
    torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)


def test_segment_network_uses_separate_encoders_for_u_and_v_and_is_ordered():
    segments, neighbours = _batch(B=32, K=8)
    torch.manual_seed(0)
    net = _trained_stats(SegmentKNNNetwork(**SMALL), segments, neighbours)
    # separate weights: no parameter tensor is shared between the two encoders
    u_ptrs = {p.data_ptr() for p in net.encoder_u.parameters()}
    assert u_ptrs.isdisjoint(p.data_ptr() for p in net.encoder_v.parameters())
    with torch.no_grad():
        out = net(segments, neighbours)
        # the output is head([enc_u(u, q), enc_v(v, q)]): u only reaches encoder_u, v only encoder_v
        parts = net.head(torch.cat([net.encoder_u(segments[:, 0], neighbours),
                                    net.encoder_v(segments[:, 1], neighbours)], dim=1))
        torch.testing.assert_close(out, parts, rtol=0, atol=0)
        # (B, 6) = [u, v] is the same input
        torch.testing.assert_close(net(segments.reshape(-1, 6), neighbours), out, rtol=0, atol=0)
        # ordered: swapping u and v changes the outputs (the paper does not enforce s(v,u) = 1 - s(u,v))
        swapped = net(segments.flip(1), neighbours)
        assert (swapped - out).abs().max().item() > 1e-4
        # tying the weights (encoder_v := encoder_u) still does not make it symmetric: the head
        # sees [enc(u), enc(v)] in order
        net.encoder_v.load_state_dict(net.encoder_u.state_dict())
        assert (net(segments.flip(1), neighbours) - net(segments, neighbours)).abs().max().item() > 1e-4


@pytest.mark.parametrize("kind,out_dim", [("segment", 2), ("point", 1), ("point", 3)])
def test_make_knn_network_rebuilds_from_config_and_loads_weights(kind, out_dim):
    segments, neighbours = _batch(B=16, K=5)
    anchors = segments if kind == "segment" else segments[:, 0]
    torch.manual_seed(0)
    net = _trained_stats(make_knn_network(kind, out_dim=out_dim, **SMALL), anchors, neighbours)
    assert net.config == dict(kind=kind, out_dim=out_dim, **SMALL)
    torch.manual_seed(123)  # a different initialisation, overwritten by the state dict
    copy = make_knn_network(**net.config)
    assert type(copy) is type(net)
    copy.load_state_dict(net.state_dict())  # strict: same parameter and buffer names and shapes
    copy.eval()
    with torch.no_grad():
        torch.testing.assert_close(copy(anchors, neighbours), net(anchors, neighbours), rtol=0, atol=0)


def test_shapes_dtypes_and_paper_layer_sizes():
    segments, neighbours = _batch(B=10, K=20)
    seg_net, pt_net = make_knn_network("segment"), make_knn_network("point")  # paper defaults
    for net, anchors, out_dim in ((seg_net, segments, 2), (pt_net, segments[:, 1], 1)):
        net.eval()
        with torch.no_grad():
            y = net(anchors, neighbours)
        assert y.shape == (10, out_dim) and y.dtype == torch.float32
        # float64 networks take float64 inputs
        y64 = net.double()(anchors.double(), neighbours.double())
        assert y64.dtype == torch.float64
    linears = lambda m: [(l.in_features, l.out_features) for l in m.modules() if isinstance(l, torch.nn.Linear)]
    assert linears(seg_net.encoder_u) == [(4, 256)] + [(256, 256)] * 5  # 4 -> 256, 4 x 256, 256 -> 256
    assert linears(seg_net.head) == [(512, 256)] + [(256, 256)] * 4 + [(256, 2)]
    assert linears(pt_net.head) == [(256, 256)] * 5 + [(256, 1)]
    norms = [m for m in seg_net.encoder_u.modules() if isinstance(m, torch.nn.BatchNorm1d)]
    assert len(norms) == 5  # after every linear layer but the encoder's last
    # the encoder alone: (B, 3), (B, K, 3) -> (B, width)
    assert LocalEncoder(8, 0)(segments[:, 0], neighbours).shape == (10, 8)
    with pytest.raises(ValueError, match="segment anchors"):
        seg_net(segments[:, 0].double(), neighbours.double())
    with pytest.raises(ValueError, match="unknown K-NN network kind 'mesh'"):
        make_knn_network("mesh")


def test_budgets_registry_and_validation():
    assert KNN_BUDGETS.names() == ["paper", "cpu", "tiny"]
    paper = KNN_BUDGETS.get("paper")
    assert (paper.k, paper.encoder_width, paper.encoder_depth, paper.steps, paper.shapes_per_batch,
            paper.samples_per_item, paper.points_per_item, paper.lr) == (20, 256, 4, 10_000, 4, 5_120, 40_000, 1e-3)
    net = make_knn_network("segment", **paper.network_config())
    assert net.config == make_knn_network("segment").config  # the paper budget is the default network
    with pytest.raises(ValueError, match="unknown knn budget 'huge'; known knn budgets: paper, cpu, tiny"):
        KNN_BUDGETS.get("huge")
    with pytest.raises(ValueError, match="points_per_item 10 < k 20"):
        KNNBudget("bad", k=20, encoder_width=8, encoder_depth=1, head_width=8, head_depth=1, steps=1,
                  shapes_per_batch=1, samples_per_item=1, points_per_item=10)


@pytest.mark.learned
@pytest.mark.slow
def test_tiny_point_network_overfits_the_udf_of_a_sphere(fit_seed, torch_threads, measured):
    """200 points on the sphere of radius 0.5; 2,000 queries at radii in [0.3, 0.7] labelled with their
    distance to the sphere |r - 0.5| (mean ~0.1). The tiny budget's network, full batch, L1 loss, the
    budget's steps (300) and lr: the eval-mode loss ends below 1/8 of the initial loss (measured
    0.046-0.100 of it over seeds 0-4 x float paths x 1-2 threads, docs/spread/learned.md)."""
    budget = KNN_BUDGETS.get("tiny")
    rng = np.random.default_rng(0)

    def sphere(n, radii):
        d = rng.normal(size=(n, 3))
        return d / np.linalg.norm(d, axis=1, keepdims=True) * radii[:, None]

    points = sphere(200, np.full(200, 0.5))
    radii = rng.uniform(0.3, 0.7, 2000)
    queries = sphere(2000, radii)
    idx = knn_neighbourhoods(points, queries, budget.k)
    x = torch.tensor(queries, dtype=torch.float32)
    q = torch.tensor(points[idx], dtype=torch.float32)
    udf = torch.tensor(np.abs(radii - 0.5), dtype=torch.float32)

    torch.manual_seed(fit_seed)
    net = make_knn_network("point", out_dim=1, **budget.network_config())
    opt = torch.optim.AdamW(net.parameters(), lr=budget.lr, weight_decay=budget.weight_decay)
    with torch.no_grad():
        first = F.l1_loss(net.eval()(x, q)[:, 0], udf).item()
    net.train()
    for _ in range(budget.steps):
        loss = F.l1_loss(net(x, q)[:, 0], udf)
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        last = F.l1_loss(net.eval()(x, q)[:, 0], udf).item()
    measured(first=first, last=last, ratio=last / first)
    assert first > 0.08  # outputs start near 0: the loss is the mean UDF
    assert last < first / 8, (first, last)

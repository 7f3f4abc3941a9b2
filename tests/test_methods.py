"""The four registered methods: registry, oracle mode on hand-made CAD-like cases (sharp cube, open
sheet and tube, crossing planes), and a tiny neural fit of each on a sphere."""

import numpy as np
import pytest
import trimesh

from foundation.field_cache import FieldCache
from foundation.fields import ExactFields
from foundation.metrics import evaluate
from foundation.sampler import sample_training_data
from foundation.timing import StageTimer, stage
from methods.base import METHODS, FieldMethod, available_methods, get_method, presentation
from methods.core.fitting import BUDGETS, fit
from foundation.params import Param
from methods.fields.sals import PAPER_O_THRESHOLD, edge_draws

N_POINTS = 30_000  # metric samples: enough to separate sharp from rounded at N = 40


def _arrays(mesh):
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def _oracle(name, V, F, N, tmp_path, **params):
    method = get_method(name, **params)
    with StageTimer().active() as timer:
        with stage("query"):
            grid, _ = method.oracle_grid(ExactFields(V, F), N, FieldCache(tmp_path))
        with stage("extract"):
            ex = method.extract(grid, N)
    assert all(k.startswith(("query", "extract")) and k.endswith("_s") for k in timer.seconds)
    return ex


def _area(V, F):
    if len(F) == 0:
        return 0.0
    return float(trimesh.Trimesh(V, F, process=False).area)


# -- registry ----------------------------------------------------------------------------------
def test_registry_has_the_four_methods_and_lists_them_on_unknown_names():
    assert {"bof", "sdf", "udf", "sals"} <= set(available_methods())
    with pytest.raises(ValueError, match="unknown method 'nerf'; known methods: ") as err:
        get_method("nerf")
    listed = str(err.value).split("known methods: ")[1].split(", ")
    assert listed[:6] == ["bof", "sdf", "sdf-ndc", "nglod", "udf", "udf-dualmesh"]  # display order, from each method's metadata
    with pytest.raises(ValueError, match="no parameter"):
        get_method("sals", thresold=0.2)
    assert get_method("sals", o_threshold=0.2).params["o_threshold"] == 0.2
    assert get_method("sals").input_dim == 6 and get_method("udf").input_dim == 3
    assert len({presentation(m).color for m in listed}) == len(listed)  # one colour each


def test_parameters_are_typed_and_checked():
    assert get_method("sals", normals="no").params["normals"] is False
    assert get_method("sals", normals="TRUE").params["normals"] is True
    assert get_method("sals", stride="2").params["stride"] == 2
    for bad, message in ((dict(normals="nope"), "expected bool"), (dict(o_threshold=1.5), r"float in \(0, 1\)"),
                         (dict(qef_cutoff="abc"), "expected float"), (dict(faces="tri"), "one of 'fan4', 'quad2'"),
                         (dict(stride="2.5"), "expected int")):
        with pytest.raises(ValueError, match=message):
            get_method("sals", **bad)


def test_a_fifth_method_defined_here_is_found():
    class Constant(FieldMethod):
        name = "test-constant"
        parameters = {"value": Param(1.0, "the constant")}

    with METHODS.registered(Constant.name, Constant):
        assert "test-constant" in available_methods()
        assert get_method("test-constant", value=2.0).params == {"value": 2.0}
    assert "test-constant" not in available_methods()


# -- oracle mode -------------------------------------------------------------------------------
def test_oracle_cube_sals_keeps_edges_sharp_and_sdf_rounds_them(tmp_path):
    box = trimesh.creation.box(extents=(1.2, 1.2, 1.2))
    box.apply_transform(trimesh.transformations.rotation_matrix(0.1, [1, 2, 3]))  # off-axis
    V, F = _arrays(box)
    scores = {}
    for name in ("sals", "sdf", "bof", "udf"):
        ex = _oracle(name, V, F, 40, tmp_path)
        scores[name] = evaluate(V, F, ex.vertices, ex.faces, n_points=N_POINTS, seed=0)
        assert scores[name]["cd"] < 0.02, name
    # E-DC with exact normals puts vertices on the edges and corners; MC cuts them off
    assert scores["sals"]["ecd"] < 0.5 * scores["sdf"]["ecd"]
    assert scores["sals"]["ecd"] < 0.5 * scores["bof"]["ecd"]
    assert scores["sals"]["ef1"] > scores["sdf"]["ef1"] + 0.1
    assert scores["sdf"]["watertight"] and scores["bof"]["watertight"]


#: A rotation with every entry of magnitude >= 1/3: no face of a box turned by it is nearly parallel
#: to a grid axis, so no grid edge lies almost in a face plane (the ambiguous case, see PROTOCOL).
GENERIC_ROTATION = np.array([[2, -1, 2], [2, 2, -1], [-1, 2, 2]]) / 3.0


def generic_box(half=(0.55, 0.5, 0.45)):
    """The box [-half, half] turned by :data:`GENERIC_ROTATION`: (V, F, corners (8, 3), its 12 edges (12, 2))."""
    half = np.asarray(half)
    box = trimesh.creation.box(extents=2 * half)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half
    edges = np.array([(i, j) for i in range(8) for j in range(i + 1, 8) if (corners[i] != corners[j]).sum() == 1])
    V, F = _arrays(box)
    return V @ GENERIC_ROTATION.T, F, corners @ GENERIC_ROTATION.T, edges


def segment_distance(P, A, B):
    """Distance of points P (n, 3) to the nearest of the segments [A_k, B_k] (k, 3)."""
    d = B - A
    t = np.clip(np.einsum("nkc,kc->nk", P[:, None] - A, d) / (d * d).sum(-1), 0.0, 1.0)
    return np.linalg.norm(P[:, None] - (A + t[..., None] * d), axis=-1).min(axis=1)


def edge_coverage(mesh_V, mesh_F, corners, edges, n=200_000):
    """(per box edge: the fraction of 40 points along it within EF1's threshold 0.005 D of a sharp-edge
    point of the mesh, NDC's edge test at r = 0.004 D; the fraction of those edge points that lie within
    0.005 D of a box edge), D the box's diagonal."""
    from scipy.spatial import cKDTree

    from foundation.metrics import sharp_edge_points
    from foundation.surface import sample_surface

    D = np.linalg.norm(corners.max(0) - corners.min(0))
    P, normals = sample_surface(mesh_V, mesh_F, n, np.random.default_rng(0))
    Q = P[sharp_edge_points(P, normals, 0.004 * D)]
    t = np.linspace(0.05, 0.95, 40)[:, None]
    tree = cKDTree(Q)
    cover = [float((tree.query(corners[i] + t * (corners[j] - corners[i]))[0] < 0.005 * D).mean()) for i, j in edges]
    on_edges = float((segment_distance(Q, corners[edges[:, 0]], corners[edges[:, 1]]) < 0.005 * D).mean())
    return np.array(cover), on_edges


def test_oracle_sals_cube_is_closed_but_where_grid_edges_cross_its_sharp_edges_twice(tmp_path):
    """E-DC of the exact SALS field of a box in general position, N = 48: NDC's edge test finds all 12
    edges along their whole length and nothing else, and the mesh is closed except within 0.2 h of
    the box's edges. There a grid edge crossing both faces of a sharp edge carries one first-hit
    label, SALS's own representation, and E-DC adds its quad where a sign-based DC would add none:
    so even the exact field gives no watertight cube, and no fit of it can."""
    from foundation.grid import spacing

    V, F, corners, edges = generic_box()
    N = 48
    ex = _oracle("sals", V, F, N, tmp_path)
    cover, on_edges = edge_coverage(ex.vertices, ex.faces, corners, edges)
    assert cover.min() == 1.0 and on_edges == 1.0
    sides = np.sort(ex.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, count = np.unique(sides, axis=0, return_counts=True)
    defects = unique[count != 2]  # boundary (1 face) and non-manifold (3+) mesh edges
    assert 0 < len(defects) < 300
    mid = ex.vertices[defects].mean(axis=1)
    assert segment_distance(mid, corners[edges[:, 0]], corners[edges[:, 1]]).max() < 0.2 * spacing(N)


@pytest.mark.slow
@pytest.mark.learned
def test_neural_sals_cube_finds_the_twelve_sharp_edges(fit_seed, torch_threads, measured):
    """The cpu budget's grid network fitted 1,000 steps (of its 2,000) to the same box, E-DC at
    N = 64: NDC's edge test finds every one of the 12 box edges along >= 70 % of its length, along
    >= 90 % on average, and CD < 0.013. Measured over seeds 0-4 x float paths (default, avx2,
    native) x 1 and 2 threads (docs/spread/learned.md): worst edge 0.875-0.975, mean over the edges
    0.950-0.998, CD 0.0064-0.0101; another machine's run of seed 0 found a worst edge of 0.75, so the bound
    on the worst edge is the one that moves most from one CPU to another. Not closed: besides the
    sharp-edge quads the exact field has too (test above), the blurred o marks edges next to the
    faces (seed 0: 4,270 boundary and 4,985 non-manifold mesh edges), and most sharp-edge points
    (0.24-0.41 of them lie on a box edge) are the creases of those fins. Run at the paper's o
    threshold (0.1), at which the bounds were measured; at the default 0.5 (one thread, seeds 0-4 x
    float paths) the worst edge reached 0.70-0.925, the mean 0.929-0.973, CD 0.0065-0.0080."""
    from methods.core.fitting import get_budget

    V, F, corners, edges = generic_box()
    budget = get_budget("cpu", {"steps": 1000})
    samples = sample_training_data(V, F, budget.num_samples, np.random.default_rng(fit_seed))
    method = get_method("sals", o_threshold=PAPER_O_THRESHOLD)
    res = fit(method, samples, method.training_targets(ExactFields(V, F), samples), budget, seed=fit_seed, device="cpu")
    grid, _ = method.neural_grid(res.model, 64, "cpu")
    ex = method.extract(grid, 64)
    cover, on_edges = edge_coverage(ex.vertices, ex.faces, corners, edges)
    cd = evaluate(V, F, ex.vertices, ex.faces, n_points=50_000, seed=0)["cd"]
    measured(worst_cover=cover.min(), mean_cover=cover.mean(), edges_80=(cover >= 0.8).sum(), on_edges=on_edges, cd=cd)
    assert cover.min() >= 0.7 and cover.mean() >= 0.9, np.round(cover, 3)
    assert cd < 0.013


def _sheet():
    """An open square sheet 1.4 x 1.4 in a tilted plane (area 1.96)."""
    sheet = trimesh.creation.box(extents=(1.4, 1.4, 1e-9)).subdivide()
    V, F = _arrays(sheet)
    top = np.flatnonzero(V[F][:, :, 2].min(axis=1) > 0)  # keep the top face only
    m = trimesh.Trimesh(V, F[top], process=False)
    m.remove_unreferenced_vertices()
    m.apply_transform(trimesh.transformations.rotation_matrix(0.3, [1, 0.2, 0]))
    return _arrays(m)


@pytest.mark.parametrize("shape", ["sheet", "tube"])
def test_oracle_open_surfaces_stay_open_for_sals_and_udf_not_for_sdf_bof(shape, tmp_path):
    if shape == "sheet":
        V, F = _sheet()
    else:
        tube = trimesh.creation.cylinder(radius=0.5, height=1.4, sections=48)
        V, F = _arrays(tube)
        side = np.abs(trimesh.Trimesh(V, F, process=False).face_normals[:, 2]) < 0.5  # drop the caps
        F = F[side]
    gt_area = _area(V, F)
    N = 40
    for name in ("sals", "udf"):
        ex = _oracle(name, V, F, N, tmp_path)
        r = evaluate(V, F, ex.vertices, ex.faces, n_points=N_POINTS)
        assert r["boundary_edges"] > 0, name
        assert abs(_area(ex.vertices, ex.faces) / gt_area - 1) < 0.15, name
        assert r["cd"] < 0.02, name
    for name in ("sdf", "bof"):
        ex = _oracle(name, V, F, N, tmp_path)
        area = _area(ex.vertices, ex.faces)
        closed = len(ex.faces) > 0 and evaluate(V, F, ex.vertices, ex.faces, n_points=5000)["boundary_edges"] == 0
        # a signed field either sees no inside (nothing extracted) or closes the surface
        assert len(ex.faces) == 0 or closed or abs(area / gt_area - 1) > 0.3, name


def test_oracle_crossing_planes_sals_reproduces_the_nonmanifold_crossing(tmp_path):
    a = trimesh.creation.box(extents=(1.4, 1.4, 1e-9))
    b = a.copy()
    b.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2 + 0.2, [1, 0, 0]))
    Va, Fa = _arrays(a)
    Vb, Fb = _arrays(b)
    # both boxes are flat (two coincident faces); keep one side of each: two crossing squares
    Fa = Fa[Va[Fa][:, :, 2].min(axis=1) > 0]
    nb = trimesh.Trimesh(Vb, Fb, process=False).face_normals
    Fb = Fb[(nb @ np.array([0, -np.sin(np.pi / 2 + 0.2), np.cos(np.pi / 2 + 0.2)])) > 0]
    V = np.vstack([Va, Vb])
    F = np.vstack([Fa, Fb + len(Va)])
    V = V @ trimesh.transformations.rotation_matrix(0.15, [0, 1, 0])[:3, :3].T
    ex = _oracle("sals", V, F, 40, tmp_path)
    r = evaluate(V, F, ex.vertices, ex.faces, n_points=N_POINTS)
    assert r["nonmanifold_edges"] > 0
    assert r["cd"] < 0.01
    assert abs(_area(ex.vertices, ex.faces) / _area(V, F) - 1) < 0.15


def test_sals_edge_like_training_segments_replace_a_fraction_and_key_the_fit(sphere):
    """edge_segments = 0 (the paper's) trains on the shared segments as they are; 0.4 replaces the
    samples whose draw < 0.4 by (u, u +- L e_axis), u unchanged, labelled from the new segments."""
    V, F, fields, samples = sphere
    paper = get_method("sals")
    assert paper.training_segments(samples) is samples.segments
    assert paper.fit_params() == {"edge_segments": 0.0, "edge_length": 2 / 127}
    assert get_method("sdf").fit_params() == {}
    L = 0.05
    method = get_method("sals", edge_segments=0.4, edge_length=L)
    seg = method.training_segments(samples)
    direction, draw = edge_draws(samples.points)
    again = edge_draws(samples.points.copy())
    assert np.array_equal(direction, again[0]) and np.array_equal(draw, again[1])  # a function of the samples
    assert set(np.unique(direction)) == set(range(6)) and np.allclose(np.bincount(direction) / len(draw), 1 / 6, atol=0.02)
    swapped = draw < 0.4
    np.testing.assert_array_equal(seg[:, 0], samples.segments[:, 0])
    np.testing.assert_array_equal(seg[~swapped], samples.segments[~swapped])
    step = seg[swapped, 1] - seg[swapped, 0]
    d = direction[swapped]
    expected = np.zeros_like(step)
    expected[np.arange(len(d)), d % 3] = np.where(d < 3, L, -L)
    np.testing.assert_allclose(step, expected, atol=1e-6)
    assert abs(swapped.mean() - 0.4) < 0.02
    inputs, targets = method.network_inputs(samples), method.training_targets(fields, samples)
    np.testing.assert_array_equal(inputs, seg.reshape(-1, 6))
    # the icosphere lies between radius 0.69 and 0.7 (its faces sag < 0.002): one end inside 0.69 and
    # the other outside 0.7 is a hit; both inside 0.69 is none
    ru, rv = np.linalg.norm(seg[:, 0], axis=1), np.linalg.norm(seg[:, 1], axis=1)
    crossing = (np.minimum(ru, rv) < 0.69) & (np.maximum(ru, rv) > 0.7)
    inside = np.maximum(ru, rv) < 0.69
    assert crossing[swapped].sum() > 1000 and np.all(targets["o"][crossing] == 1)
    assert np.all(targets["o"][inside] == 0)


# -- neural mode ---------------------------------------------------------------------------------
#: CD bounds (canonical units) of the tiny fit on a sphere of radius 0.7 at N = 32, seed 0.
#: CD bounds of the tiny fits of a sphere, and the most the final loss may be of the first 10 steps'
#: mean. Measured over seeds 0-4 x float paths (default, avx2, native) x 1 and 2 threads
#: (docs/spread/learned.md): CD sdf 0.0129-0.0133, bof 0.0145-0.0159, udf 0.018-0.039, sals 0.079-0.086;
#: loss ratio sdf 0.24-0.31, bof 0.75-0.82, udf 0.57-0.82, sals 0.984-0.998. Every bound keeps a margin of at
#: least 1.2 over the worst measured value. SALS's tiny plain MLP barely moves its loss in 200 steps
#: (a ratio within 2 % of 1, which another float path could flip), so its mesh is its only check, at
#: the paper's o threshold 0.1: its o_hat stays below the default 0.5 on every edge for seeds 1-4 (an
#: empty mesh; seed 0: CD 0.120).
NEURAL_CD_BOUND = {"sdf": 0.03, "bof": 0.05, "udf": 0.05, "sals": 0.2}
LOSS_RATIO_BOUND = {"sdf": 0.5, "bof": 1.0, "udf": 1.0, "sals": None}
#: Method parameters of the tiny fits: SALS at the paper's o threshold (above).
TINY_FIT_PARAMS = {"sals": {"o_threshold": PAPER_O_THRESHOLD}}


@pytest.fixture(scope="module")
def sphere():
    V, F = _arrays(trimesh.creation.icosphere(subdivisions=3, radius=0.7))
    return V, F, ExactFields(V, F), sample_training_data(V, F, BUDGETS["tiny"].num_samples, np.random.default_rng(0))


@pytest.mark.learned
@pytest.mark.parametrize("name", ["sdf", "bof", "udf", "sals"])
def test_tiny_neural_fit_on_a_sphere(name, sphere, fit_seed, torch_threads, measured):
    V, F, fields, samples = sphere
    method = get_method(name, **TINY_FIT_PARAMS.get(name, {}))
    targets = method.training_targets(fields, samples)
    res = fit(method, samples, targets, "tiny", seed=fit_seed, device="cpu")
    grid, info = method.neural_grid(res.model, 32, "cpu")
    ex = method.extract(grid, 32)
    r = evaluate(V, F, ex.vertices, ex.faces, n_points=10_000)
    measured(cd=r["cd"], loss_ratio=res.final_loss / res.losses[:10].mean())
    assert np.isfinite(res.final_loss)
    if LOSS_RATIO_BOUND[name] is not None:
        assert res.final_loss < LOSS_RATIO_BOUND[name] * res.losses[:10].mean()
    assert info["query_fraction"] > 0  # (coarse + fine) / dense evaluations; above 1 when most blocks are near
    assert r["cd"] < NEURAL_CD_BOUND[name]

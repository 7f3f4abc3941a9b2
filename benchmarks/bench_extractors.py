"""Speed of the grid extractors (pytest-benchmark; not part of the default test run).

Shape: an analytic CAD-like "heat sink" (a base plate with fins, minus a cylindrical hole), with
its SDF, UDF, UDF gradient and exact-ish grid-edge hits (bisection of the SDF along every edge
whose endpoints change sign, normals from central differences of the SDF) on the grid of
foundation.grid. Compares, at N = 64 and 128:

* scikit-image ``marching_cubes`` on the SDF grid (the reference),
* oracle E-DC (:func:`methods.extractors.edc.edge_dual_contouring`, steps 2, 4, 5; the field is given),
* MeshUDF-style extraction (:func:`methods.extractors.meshudf.meshudf_marching_cubes`) on the UDF grid,
* DualMesh-UDF (:func:`methods.extractors.dualmesh.dualmesh_udf`) on the UDF grid, with the analytic UDF
  and its gradient at its samples; ``main`` reports its time without those queries and the queries
  apart (in a run they are the network's, part of the extraction),
* NDC (:mod:`methods.extractors.ndc`: its CNN on the cells that change sign, then dual contouring) on the SDF
  grid, where NDC's published weights are found,
* UNDC (the ``udf-ndc`` method: its two CNNs on the UDF grid, then dual contouring of the flagged
  edges), where its weights are found,
* DCUDF (:func:`methods.extractors.dcudf.dcudf`) on the UDF grid, the authors' r, the ``udf-dcudf``
  method's default iterations, the analytic UDF and its gradient at the moving vertices; one round
  (an optimisation per call), ``main`` reports it once per N with the queries apart.

Run: ``.venv/bin/pytest benchmarks/bench_extractors.py --benchmark-enable``. The machines are shared
and noisy, so the numbers to read are the ratios to marching cubes measured side by side:
``.venv/bin/python benchmarks/bench_extractors.py`` prints it (interleaved medians).
"""

from __future__ import annotations

import functools
import time

import numpy as np
import pytest
from skimage.measure import marching_cubes

from foundation.grid import edge_endpoint_values, edge_endpoints, grid_points, spacing
from foundation.timing import StageTimer
from methods.extractors.edc import edge_dual_contouring
from methods.extractors.dcudf import authors_r, dcudf
from methods.extractors.dualmesh import dualmesh_udf
from methods.extractors.meshudf import meshudf_marching_cubes
from methods.base import METHODS, get_method
from methods.fields.udf_dcudf import CPU_ITERATIONS


def _box_sdf(p, lo, hi):
    c = (lo + hi) / 2
    q = np.abs(p - c) - (hi - lo) / 2
    out = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    return out + np.minimum(q.max(axis=-1), 0.0)


def heat_sink_sdf(p: np.ndarray) -> np.ndarray:
    """Approximate SDF (exact sign, exact zero set) of a base plate + 6 fins minus a z-cylinder."""
    p = np.asarray(p, dtype=np.float64)
    d = _box_sdf(p, np.array([-0.8, -0.8, -0.7]), np.array([0.8, 0.8, -0.45]))
    for x in np.linspace(-0.7, 0.7, 6):
        fin = _box_sdf(p, np.array([x - 0.04, -0.75, -0.46]), np.array([x + 0.04, 0.75, 0.8]))
        d = np.minimum(d, fin)
    hole = np.sqrt((p[..., 0] - 0.13) ** 2 + (p[..., 1] - 0.11) ** 2) - 0.3
    return np.maximum(d, -hole)


def sdf_gradient(points, sdf=heat_sink_sdf, eps=1e-6):
    g = np.stack([(sdf(points + eps * e) - sdf(points - eps * e)) / (2 * eps) for e in np.eye(3)], axis=-1)
    return g / np.maximum(np.linalg.norm(g, axis=-1, keepdims=True), 1e-12)


@functools.lru_cache(maxsize=4)
def fields(N: int):
    """(sdf grid, udf grid, udf gradient grid, edge ids, s, normals) of the heat sink at resolution N."""
    P = grid_points(N)
    sdf = heat_sink_sdf(P)
    udf = np.abs(sdf)
    grad = np.sign(sdf)[..., None] * sdf_gradient(P)
    # intersected edges: the SDF changes sign between the endpoints (one crossing per edge)
    inside_u, inside_v = edge_endpoint_values(sdf < 0)
    ids = np.flatnonzero(inside_u != inside_v)
    u, v = edge_endpoints(N, ids, dtype=np.float64)
    t_lo, t_hi = np.zeros(len(ids)), np.ones(len(ids))
    su = heat_sink_sdf(u) < 0
    for _ in range(30):  # bisection for the crossing t in [0, 1] (to 1e-9 h)
        t = (t_lo + t_hi) / 2
        same = (heat_sink_sdf(u + t[:, None] * (v - u)) < 0) == su
        t_lo = np.where(same, t, t_lo)
        t_hi = np.where(same, t_hi, t)
    t = (t_lo + t_hi) / 2
    normals = sdf_gradient(u + t[:, None] * (v - u))
    return sdf, udf, grad, ids, 1.0 - t, normals


RESOLUTIONS = [64, 128]


@pytest.mark.parametrize("N", RESOLUTIONS)
def test_skimage_marching_cubes(benchmark, N):
    sdf = fields(N)[0]
    verts, faces, _, _ = benchmark(marching_cubes, sdf, 0.0)
    assert len(faces) > 0


@pytest.mark.parametrize("N", RESOLUTIONS)
def test_edc_oracle(benchmark, N):
    _, _, _, ids, s, normals = fields(N)
    benchmark.extra_info["intersected_edges"] = int(len(ids))
    extraction = benchmark(edge_dual_contouring, N, ids, s, normals)
    assert len(extraction.faces) > 0


@pytest.mark.parametrize("N", RESOLUTIONS)
def test_meshudf(benchmark, N):
    _, udf, grad, _, _, _ = fields(N)
    extraction = benchmark(meshudf_marching_cubes, udf, grad)
    assert len(extraction.faces) > 0


def heat_sink_udf_grad(points):
    """The heat sink's UDF and its unit gradient at ``points`` (P, 3)."""
    d = heat_sink_sdf(points)
    return np.abs(d), np.sign(d)[:, None] * sdf_gradient(points)


def _timed(query_seconds: list | None):
    """A wrapper of field queries that appends each call's seconds to ``query_seconds`` (if given)."""
    def timed(fn):
        def call(points):
            t = time.perf_counter()
            out = fn(points)
            if query_seconds is not None:
                query_seconds.append(time.perf_counter() - t)
            return out
        return call

    return timed


def dualmesh_on_heat_sink(udf: np.ndarray, query_seconds: list | None = None):
    """DualMesh-UDF on the heat sink; the seconds spent in the analytic field's queries are appended
    to ``query_seconds`` when given (they stand for a network's queries in a run)."""
    timed = _timed(query_seconds)
    return dualmesh_udf(udf, timed(heat_sink_udf_grad), timed(lambda p: np.abs(heat_sink_sdf(p))))


@pytest.mark.parametrize("N", RESOLUTIONS)
def test_dualmesh(benchmark, N):
    extraction = benchmark(dualmesh_on_heat_sink, fields(N)[1])
    assert len(extraction.faces) > 0


#: The ``sdf-ndc`` method, which runs NDC on an SDF grid (canonical units); None without NDC's weights.
NDC = None if METHODS.get("sdf-ndc").unavailable() else get_method("sdf-ndc")


@pytest.mark.parametrize("N", RESOLUTIONS)
def test_ndc(benchmark, N):
    if NDC is None:
        pytest.skip(METHODS.get("sdf-ndc").unavailable())
    extraction = benchmark(NDC.extract, fields(N)[0], N)
    assert len(extraction.faces) > 0


#: The ``udf-ndc`` method, which runs UNDC on a UDF grid; None without its weights.
UNDC = None if METHODS.get("udf-ndc").unavailable() else get_method("udf-ndc")


@pytest.mark.parametrize("N", RESOLUTIONS)
def test_undc(benchmark, N):
    if UNDC is None:
        pytest.skip(METHODS.get("udf-ndc").unavailable())
    extraction = benchmark(UNDC.extract, {"udf": fields(N)[1]}, N)
    assert len(extraction.faces) > 0


def dcudf_on_heat_sink(udf: np.ndarray, query_seconds: list | None = None):
    """DCUDF on the heat sink (the authors' r at this N, :data:`CPU_ITERATIONS` iterations); the
    analytic field's query seconds are appended to ``query_seconds`` when given."""
    N, timed = udf.shape[0], _timed(query_seconds)
    return dcudf(udf, timed(heat_sink_udf_grad), timed(lambda p: np.abs(heat_sink_sdf(p))),
                 r=authors_r(N), iterations=CPU_ITERATIONS)


@pytest.mark.parametrize("N", RESOLUTIONS)
def test_dcudf(benchmark, N):
    extraction = benchmark.pedantic(dcudf_on_heat_sink, args=(fields(N)[1],), rounds=1, iterations=1)
    benchmark.extra_info.update(extraction.info)
    assert len(extraction.faces) > 0


def edc_step_seconds(N, ids, s, normals) -> dict[str, float]:
    """Seconds of each step of E-DC on the given edges (``edge_points``, ``qef``, ``faces``)."""
    timer = StageTimer()
    with timer.active():
        edge_dual_contouring(N, ids, s, normals)
    return {key.removesuffix("_s"): seconds for key, seconds in timer.seconds.items()}


def _median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def main(repeats: int = 15):
    for N in RESOLUTIONS:
        sdf, udf, grad, ids, s, normals = fields(N)
        mc, edc, mu, nd, und, dm, dm_queries = [], [], [], [], [], [], []
        stages = []
        for _ in range(repeats):  # interleaved so that machine load hits all alike
            mc.append(_median_time(lambda: marching_cubes(sdf, 0.0), 1))
            edc.append(_median_time(lambda: stages.append(edc_step_seconds(N, ids, s, normals)), 1))
            mu.append(_median_time(lambda: meshudf_marching_cubes(udf, grad), 1))
            queries = []
            dm.append(_median_time(lambda: dualmesh_on_heat_sink(udf, queries), 1) - sum(queries))
            dm_queries.append(sum(queries))
            if NDC is not None:
                nd.append(_median_time(lambda: NDC.extract(sdf, N), 1))
            if UNDC is not None:
                und.append(_median_time(lambda: UNDC.extract({"udf": udf}, N), 1))
        mc, edc, mu = np.median(mc), np.median(edc), np.median(mu)
        st = {k: float(np.median([t[k] for t in stages])) for k in stages[0]}
        print(f"N={N}: intersected edges {len(ids)}, h={spacing(N):.4f}")
        print(f"  skimage MC {mc * 1e3:.1f} ms | E-DC {edc * 1e3:.1f} ms (ratio E-DC/MC {edc / mc:.2f}; "
              + ", ".join(f"{k} {v * 1e3:.1f} ms" for k, v in st.items())
              + f") | MeshUDF {mu * 1e3:.1f} ms (ratio {mu / mc:.2f})"
              + f" | DualMesh-UDF {np.median(dm) * 1e3:.1f} ms without its field queries (ratio {np.median(dm) / mc:.2f}, "
                f"DualMesh/E-DC {np.median(dm) / edc:.2f}; the analytic field's queries {np.median(dm_queries) * 1e3:.0f} ms)"
              + (f" | NDC {np.median(nd) * 1e3:.1f} ms (ratio {np.median(nd) / mc:.2f}, NDC/E-DC "
                 f"{np.median(nd) / edc:.2f})" if nd else " | NDC: weights absent")
              + (f" | UNDC {np.median(und) * 1e3:.1f} ms (ratio {np.median(und) / mc:.2f}, UNDC/E-DC "
                 f"{np.median(und) / edc:.2f})" if und else " | UNDC: weights absent"))
        queries = []
        dc = _median_time(lambda: dcudf_on_heat_sink(udf, queries), 1)
        print(f"  DCUDF ({CPU_ITERATIONS} iterations, one run) {(dc - sum(queries)):.1f} s without its field queries "
              f"(ratio to MC {(dc - sum(queries)) / mc:.0f}; the analytic field's queries {sum(queries):.1f} s)")


if __name__ == "__main__":
    main()

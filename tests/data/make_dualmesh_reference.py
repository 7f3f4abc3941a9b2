"""Make ``dualmesh_reference_box.npz``: DualMesh-UDF's own extraction of an analytic UDF, for
tests/test_dualmesh.py.

Runs the authors' code unchanged (github.com/cong-yi/DualMesh-UDF, built with its ``setup.py``)
outside this repository: ``DualMeshUDF.extract_mesh(udf, udf_grad, max_depth=5)`` (32^3 leaves on
[-1, 1]^3) on the exact UDF of a turned box and its unit gradient, float32 as the authors' network
wrapper returns them.

    PYTHONPATH=/path/to/DualMesh-UDF python tests/data/make_dualmesh_reference.py
"""

from pathlib import Path

import numpy as np

#: The box: half extents, rotation (every entry of magnitude >= 1/3: no face near a grid plane), shift.
HALF = np.array([0.55, 0.45, 0.35])
ROTATION = np.array([[2, -1, 2], [2, 2, -1], [-1, 2, 2]]) / 3.0
SHIFT = np.array([0.031, -0.017, 0.023])
MAX_DEPTH = 5


def box_udf_grad(points: np.ndarray):
    """Exact UDF of the turned box and its unit gradient (float64), points (P, 3)."""
    local = (np.asarray(points, dtype=np.float64) - SHIFT) @ ROTATION  # = R^T (p - t)
    q = np.abs(local) - HALF
    outside = np.maximum(q, 0.0)
    norm_out = np.linalg.norm(outside, axis=1)
    sdf = norm_out + np.minimum(q.max(axis=1), 0.0)
    grad_local = np.where((norm_out > 0)[:, None], outside / np.maximum(norm_out, 1e-300)[:, None],
                          np.eye(3)[np.argmax(q, axis=1)])
    grad_local *= np.sign(local)
    grad = grad_local @ ROTATION.T * np.where(sdf < 0, -1.0, 1.0)[:, None]
    return np.abs(sdf), grad


def main() -> None:
    from DualMeshUDF import extract_mesh

    def udf(points):
        return box_udf_grad(points)[0].astype(np.float32)[:, None]

    def udf_grad(points):
        d, g = box_udf_grad(points)
        return d.astype(np.float32)[:, None], g.astype(np.float32)

    V, F = extract_mesh(udf, udf_grad, max_depth=MAX_DEPTH)
    np.savez_compressed(Path(__file__).with_name("dualmesh_reference_box.npz"),
                        vertices=np.asarray(V, dtype=np.float64), faces=np.asarray(F, dtype=np.int64))
    print(len(V), "vertices,", len(F), "faces")


if __name__ == "__main__":
    main()

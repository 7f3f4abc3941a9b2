"""Make ``ndc_reference_box33.npz``: NDC's own inference on an analytic SDF, for tests/test_ndc.py.

Runs NDC's code unchanged from a checkout of github.com/czq142857/NDC (commit 9054e20, the
repository's HEAD; its network and input code are those of the weights' commit 7488574) outside
this repository: its ``dataset.single_shape_grid`` builds the padded, clipped input from an hdf5 file,
``model.CNN_3d_rec7_resnet`` with ``network_float.pth`` predicts the vertex offsets, which are clipped
to [0, 1] as its ``main.py`` does, and ``utils.dual_contouring_ndc_test`` makes the mesh.

    python tests/data/make_ndc_reference.py /path/to/NDC /path/to/network_float.pth   # needs h5py

The shape: a box with half extents (0.55, 0.4, 0.3), turned and shifted off the grid's axes, its
exact SDF on 33^3 points of [-1, 1]^3 in voxel units (one cell edge = 1). Stored: that input
(``sdf_voxels``) and NDC's vertices (grid index units) and triangles.
"""

import sys
from pathlib import Path

import numpy as np
import torch


def box_sdf_voxels(N: int = 33) -> np.ndarray:
    h = 2.0 / (N - 1)
    c = np.linspace(-1, 1, N)
    P = np.stack(np.meshgrid(c, c, c, indexing="ij"), -1)
    a, b = 0.5, 0.3
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]) @ \
        np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    q = np.abs((P - np.array([0.03, -0.02, 0.05])) @ R) - np.array([0.55, 0.4, 0.3])
    sdf = np.linalg.norm(np.maximum(q, 0), axis=-1) + np.minimum(q.max(-1), 0)
    return (sdf / h).astype(np.float32)


def main(ndc_dir: str, weights: str) -> None:
    import h5py

    sys.path.insert(0, ndc_dir)
    import dataset
    import model
    import utils

    sdf_voxels = box_sdf_voxels()
    n = sdf_voxels.shape[0] - 1
    hdf5 = Path("box.hdf5")
    with h5py.File(hdf5, "w") as f:
        f["64_sdf"] = sdf_voxels / np.float32(n)  # NDC multiplies by its grid size n (a power of 2: exact)
    grid, _ = dataset.single_shape_grid(str(hdf5), 3, "sdf", is_undc=False)[0]
    net = model.CNN_3d_rec7_resnet(out_bool=False, out_float=True)
    net.load_state_dict(torch.load(weights, map_location="cpu"))
    net.eval()
    with torch.no_grad():
        offsets = net(torch.from_numpy(grid)[None])
    inside = (grid[0, 3:-3, 3:-3, 3:-3] < 0).astype(np.int32)[..., None]
    V, T = utils.dual_contouring_ndc_test(inside, np.clip(np.transpose(offsets[0].numpy(), [1, 2, 3, 0]), 0, 1))
    np.savez_compressed(Path(__file__).with_name("ndc_reference_box33.npz"), sdf_voxels=sdf_voxels,
                        vertices=V.astype(np.float32), triangles=T.astype(np.int32))
    hdf5.unlink()


if __name__ == "__main__":
    main(*sys.argv[1:3])

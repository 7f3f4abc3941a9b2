"""salsbench datasets: loading meshes into the canonical frame and the dataset registry.

    from datasets import get_dataset
    for name in (ds := get_dataset("abc", data_dir="../shared/data/abc")).names():
        shape = ds.load(name)            # may raise MeshError for this one shape only

Registered datasets: ``builtin`` (default: 4 generated CAD-like shapes), ``abc``,
``abc-nonmanifold``, ``sals-abc50`` and ``sals-nonmanifold50`` (the SALS paper's two ABC test
sets, SHA-256 checked), ``meshes`` (any folder of mesh files), ``pointclouds`` (point-cloud files
with their GT meshes, for the reconstruct task), ``rooms`` (Synthetic-Rooms-style scenes
generated from a seed: floor, walls and CAD parts as one triangle soup) and ``street`` (a street
scanned by a rotating multi-beam LiDAR along its centreline; the GT is what the sensor could see).
"""

from datasets.io import (
    MESH_EXTENSIONS,
    MeshError,
    Normalization,
    Shape,
    canonical_transform,
    classify_topology,
    load_shape,
    mesh_hash,
    normalize_shape,
    read_mesh_arrays,
    save_mesh,
)
from datasets.registry import (
    DEFAULT_DATASET,
    Dataset,
    DatasetError,
    DatasetNotFoundError,
    MissingShapesWarning,
    available_datasets,
    get_dataset,
    register_dataset,
)

# importing the modules registers their datasets
from datasets import builtin as _builtin  # noqa: E402,F401
from datasets import abc as _abc  # noqa: E402,F401
from datasets import pointclouds as _pointclouds  # noqa: E402,F401
from datasets import rooms as _rooms  # noqa: E402,F401
from datasets import street as _street  # noqa: E402,F401

__all__ = [
    "MESH_EXTENSIONS", "MeshError", "Normalization", "Shape", "canonical_transform", "classify_topology",
    "load_shape", "mesh_hash", "normalize_shape", "read_mesh_arrays", "save_mesh",
    "DEFAULT_DATASET", "Dataset", "DatasetError", "DatasetNotFoundError", "MissingShapesWarning",
    "available_datasets", "get_dataset", "register_dataset",
]

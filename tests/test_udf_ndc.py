"""``udf-ndc``: the udf field extracted by UNDC with our weights. With tiny-trained weights (via
``$SALSBENCH_UNDC_WEIGHTS``) it extracts a sphere's exact UDF into a mesh near the sphere; without a
weights file it is unavailable with one line naming the file and the command that trains it."""

import numpy as np
import pytest
import trimesh

from foundation.field_cache import FieldCache
from foundation.fields import ExactFields
from foundation.grid import spacing
from methods.extractors import ndc, undc
from methods.training import undc as undc_training
from methods.base import available_methods, get_method
from tasks.cache import fit_code_digest
from runner.config import ConfigError, RunConfig
from runner.plan import resolve
from tests.test_methods import _oracle


@pytest.fixture(scope="module")
def tiny_weights(tmp_path_factory):
    shapes = undc_training.undc_training_shapes("tiny")
    result = undc_training.train(shapes, "tiny", seed=0)
    path = tmp_path_factory.mktemp("undc") / "undc_tiny.pt"
    undc.save_weights(path, result.bool_network, result.float_network,
                      result.info(undc_training.get_undc_budget("tiny"), 0))
    return path


def test_extracts_a_sphere_from_its_exact_udf_with_tiny_weights(tiny_weights, tmp_path, monkeypatch):
    monkeypatch.setenv(undc.WEIGHTS_ENV, str(tiny_weights))
    assert get_method("udf-ndc").unavailable() is None and "udf-ndc" in available_methods()
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.6)
    V, F = np.asarray(sphere.vertices), np.asarray(sphere.faces, dtype=np.int64)
    N = 32
    ex = _oracle("udf-ndc", V, F, N, tmp_path)
    assert ex.info["undc_edges"] > 0 and len(ex.faces) > 0 and ex.faces.max() < len(ex.vertices)
    assert np.isfinite(ex.vertices).all()
    # a vertex lies in a cell with a flagged edge, whose end points are within one voxel of the
    # surface: it is within (1 + sqrt(3)) h of the sphere whatever the weights
    d = ExactFields(V, F).udf(ex.vertices)
    assert d.max() < (1.0 + np.sqrt(3.0)) * spacing(N)
    # the extraction is the module's on the same grid
    grid, _ = get_method("udf-ndc").oracle_grid(ExactFields(V, F), N, FieldCache(None))
    bool_network, float_network, _ = undc.load_weights(tiny_weights)
    out = undc.undc_predict(bool_network, float_network, grid["udf"] / np.float32(spacing(N)))
    assert len(out["faces"]) == len(ex.faces) and int(out["edge_flags"].sum()) == ex.info["undc_edges"]


def test_shares_the_udf_fit():
    udf, udf_ndc = get_method("udf"), get_method("udf-ndc")
    assert udf_ndc.fit_name == "udf" and udf_ndc.fit_params() == udf.fit_params()
    assert fit_code_digest(udf_ndc) == fit_code_digest(udf)


def test_without_the_weights_it_is_unavailable_with_one_clear_line(tmp_path, monkeypatch):
    absent = tmp_path / "absent.pt"
    monkeypatch.setenv(undc.WEIGHTS_ENV, str(absent))
    line = get_method("udf-ndc").unavailable()
    assert line is not None and "\n" not in line and str(absent) in line
    assert "python -m methods.training.undc --budget cpu" in line
    assert "udf-ndc" not in available_methods() and "udf" in available_methods()
    with pytest.raises(ConfigError, match=r"method 'udf-ndc' cannot run here: UNDC weights not found at .*absent.pt"):
        resolve(RunConfig(methods=("udf", "udf-ndc"), limit=1))


def test_the_cache_key_of_its_meshes_follows_the_weights_file(tiny_weights, tmp_path, monkeypatch):
    """The digest that keys udf-ndc's cached meshes is the weights file's: other weights (another
    seed), another digest; sdf-ndc's is the published file's."""
    monkeypatch.setenv(undc.WEIGHTS_ENV, str(tiny_weights))
    first = get_method("udf-ndc").extraction_data_digest()
    other = undc_training.train(undc_training.undc_training_shapes("tiny"), "tiny", seed=1)
    path = tmp_path / "other.pt"
    undc.save_weights(path, other.bool_network, other.float_network,
                      other.info(undc_training.get_undc_budget("tiny"), 1))
    monkeypatch.setenv(undc.WEIGHTS_ENV, str(path))
    second = get_method("udf-ndc").extraction_data_digest()
    assert len(first) == 64 and second != first
    assert get_method("udf").extraction_data_digest() == ""
    assert get_method("sdf-ndc").extraction_data_digest() == ndc.WEIGHTS_SHA256


def test_the_committed_weights_are_the_cpu_recipe_output():
    """The checkout's weights file is what ``python -m methods.training.undc --budget cpu`` writes at
    seed 0: its recorded budget is the ``cpu`` budget as defined now."""
    _, _, info = undc.load_weights(undc.DEFAULT_WEIGHTS)
    assert info["budget"] == undc_training.get_undc_budget("cpu").to_dict() and info["seed"] == 0


@pytest.mark.learned
def test_the_committed_weights_extract_an_off_grid_box_near_its_surface_and_corners(tmp_path, monkeypatch):
    """The exact UDF of a box (sides 1.1, 0.9, 1.3, off the grid) at N = 64 through the committed
    networks: every vertex within 0.3 h of the box (measured 0.18 h), the mean within 0.05 h
    (0.027 h), and every one of the 8 corners has a vertex within 0.6 h (0.06-0.40 h)."""
    from scipy.spatial import cKDTree

    monkeypatch.delenv(undc.WEIGHTS_ENV, raising=False)
    box = trimesh.creation.box(extents=(1.1, 0.9, 1.3))
    box.apply_translation((0.013, -0.021, 0.017))
    V, F = np.asarray(box.vertices), np.asarray(box.faces, dtype=np.int64)
    N, h = 64, spacing(64)
    ex = _oracle("udf-ndc", V, F, N, tmp_path)
    d = ExactFields(V, F).udf(ex.vertices)
    assert d.max() < 0.3 * h and d.mean() < 0.05 * h
    assert cKDTree(ex.vertices).query(V)[0].max() < 0.6 * h

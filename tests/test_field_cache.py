"""The disk cache of exact grid fields (foundation/field_cache.py): hits, corrupt entries, caching off."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from foundation.field_cache import CACHE_KINDS, FieldCache
from foundation.fields import ExactFields
from foundation.grid import EdgeField
from foundation.storage import MAGIC, CacheStats

N = 12


def box_fields() -> ExactFields:
    m = trimesh.creation.box(extents=(1.0, 0.8, 0.6))
    return ExactFields(np.asarray(m.vertices) + 0.013, np.asarray(m.faces))


def computed(fields: ExactFields, kind: str):
    """The field straight from ExactFields (what the cache must give back, bit for bit)."""
    if kind == "occupancy":
        return fields.grid_occupancy(N)
    if kind == "sdf":
        return fields.grid_scalar(N, "sdf")
    if kind == "udf_grad":
        return fields.grid_udf_with_grad(N)
    return fields.grid_edges(N)


def assert_same(a, b):
    if isinstance(a, EdgeField):
        assert a.N == b.N
        a, b = (a.hit, a.s, a.normal), (b.hit, b.s, b.normal)
    if isinstance(a, tuple):
        for x, y in zip(a, b):
            assert x.dtype == y.dtype
            np.testing.assert_array_equal(x, y)
    else:
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)


def forbid_recomputing(monkeypatch):
    def fail(*args, **kwargs):
        raise AssertionError("recomputed instead of reading the cache")

    for name in ("grid_edges", "grid_scalar", "grid_udf_with_grad", "grid_occupancy"):
        monkeypatch.setattr(ExactFields, name, fail)


@pytest.mark.parametrize("kind", CACHE_KINDS)
def test_miss_stores_an_entry_and_the_second_get_is_an_identical_hit(tmp_path, monkeypatch, kind):
    fields = box_fields()
    expected = computed(fields, kind)
    stats = CacheStats()
    cache = FieldCache(tmp_path / "fields", stats)
    assert_same(cache.get(fields, N, kind), expected)
    assert stats.hits == [] and stats.rejected == []
    entry = cache.path(fields, N, kind)
    assert sorted(p.name for p in (tmp_path / "fields").iterdir()) == [entry.name]  # no temporary left
    assert entry.read_bytes().startswith(MAGIC)  # a checksummed entry
    forbid_recomputing(monkeypatch)
    assert_same(cache.get(box_fields(), N, kind), expected)  # a fresh ExactFields of the same mesh
    assert stats.hits == ["fields"] and stats.rejected == []


@pytest.mark.parametrize("kind", ["sdf", "edges"])
def test_entry_with_64_flipped_bytes_is_rejected_recomputed_and_overwritten(tmp_path, kind):
    fields = box_fields()
    cache = FieldCache(tmp_path)
    expected = cache.get(fields, N, kind)
    entry = cache.path(fields, N, kind)
    data = bytearray(entry.read_bytes())
    middle = len(data) // 2
    data[middle:middle + 64] = bytes(b ^ 0xFF for b in data[middle:middle + 64])
    entry.write_bytes(bytes(data))

    stats = CacheStats()
    again = FieldCache(tmp_path, stats).get(box_fields(), N, kind)
    assert_same(again, expected)
    assert len(stats.rejected) == 1 and "checksum mismatch" in stats.rejected[0]
    assert str(entry) in stats.rejected[0] and stats.hits == []
    # the entry was rewritten: the next read is a clean hit
    assert FieldCache(tmp_path, stats).get(fields, N, kind) is not None
    assert stats.hits == ["fields"] and len(stats.rejected) == 1


def test_files_that_are_not_entries_are_rejected(tmp_path):
    """A plain .npz (no checksum), a truncated entry, and a valid entry holding the
    wrong archive are all recomputed, never read as fields."""
    fields = box_fields()
    stats = CacheStats()
    cache = FieldCache(tmp_path, stats)
    path = cache.path(fields, N, "sdf")
    np.savez_compressed(path, sdf=np.zeros((N, N, N), np.float32))
    assert_same(cache.get(fields, N, "sdf"), computed(fields, "sdf"))
    path.write_bytes(path.read_bytes()[:40])
    assert_same(cache.get(fields, N, "sdf"), computed(fields, "sdf"))
    # a good checksum over an archive without the expected array
    edges_path = cache.path(fields, N, "edges")
    edges_path.write_bytes(path.read_bytes())  # an 'sdf' entry where an 'edges' one should be
    assert_same(cache.get(fields, N, "edges"), computed(fields, "edges"))
    assert len(stats.rejected) == 3 and stats.hits == []
    assert "no header" in stats.rejected[0] and "no header" in stats.rejected[1]
    assert "not a grid field archive" in stats.rejected[2]


def test_caching_off_computes_and_writes_nothing(tmp_path, monkeypatch):
    home, env = tmp_path / "home", tmp_path / "env"
    home.mkdir()
    env.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.setenv("SALSBENCH_CACHE", str(env))
    monkeypatch.chdir(tmp_path)
    fields = box_fields()
    stats = CacheStats()
    cache = FieldCache(None, stats)
    assert cache.path(fields, N, "sdf") is None
    for kind in CACHE_KINDS:
        assert_same(cache.get(fields, N, kind), computed(fields, kind))
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["env", "home"]
    assert stats.hits == [] and stats.rejected == []


def test_key_follows_mesh_band_and_kind(tmp_path, monkeypatch):
    fields = box_fields()
    cache = FieldCache(tmp_path)
    cache.get(fields, N, "sdf")
    cache.get(fields, N, "sdf", band=0.3)  # another band is another entry
    assert len(list(tmp_path.iterdir())) == 2
    moved = ExactFields(fields.vertices + np.array([1e-3, 0, 0]), fields.faces)
    forbid_recomputing(monkeypatch)
    with pytest.raises(AssertionError, match="recomputed"):  # a changed mesh is a new key
        cache.get(moved, N, "sdf")
    with pytest.raises(ValueError, match="unknown cached field kind 'bof'; known cached field kinds: "
                                         "occupancy, sdf, udf_grad, edges"):
        cache.get(fields, N, "bof")

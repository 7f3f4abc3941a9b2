"""The vendored JavaScript of the 3D viewer (reports/viewer_assets.py, reports/vendor/): read only
when every file is the one vendor.json records, with its version and licence."""

from __future__ import annotations

import json
import shutil

import pytest

from reports.viewer_assets import VENDOR, load_assets


def test_the_vendored_files_are_the_recorded_ones_with_their_licences():
    bundle = load_assets()
    record = json.loads((VENDOR / "vendor.json").read_text())
    assert record["three"]["version"] == record["three"]["npm"].split("@")[1]
    assert [(title.split()[0], name) for title, name, _ in bundle.notices] == [("three.js", "MIT"), ("Draco", "Apache-2.0")]
    assert "Permission is hereby granted" in bundle.notices[0][2] and "Apache License" in bundle.notices[1][2]
    assert bundle.three.startswith("var THREE=") and bundle.draco_wasm[:4] == b"\0asm"
    assert "salsbenchViewer" in bundle.viewer


@pytest.mark.parametrize("change", ["alter", "remove"])
def test_a_changed_or_missing_vendored_file_is_refused_by_name(tmp_path, change):
    folder = tmp_path / "vendor"
    shutil.copytree(VENDOR, folder)
    target = folder / "draco_wasm_wrapper.js"
    if change == "alter":
        target.write_text(target.read_text() + "\n// edited")
        message = "draco_wasm_wrapper.js differs from its SHA-256"
    else:
        target.unlink()
        message = "draco_wasm_wrapper.js is missing"
    with pytest.raises(RuntimeError, match=message):
        load_assets(folder)

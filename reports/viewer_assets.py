"""The vendored JavaScript of report.html's 3D viewer (``reports/vendor/``, made by
``scripts/vendor_three.sh``) and the viewer's own script (``reports/viewer.js``), read for inlining.

``vendor.json`` records the versions, the licences and the SHA-256 of every vendored file; a file
that is missing or differs from its record is refused in one line, so a report never embeds a
library other than the recorded one.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

VENDOR = Path(__file__).with_name("vendor")
VIEWER_JS = Path(__file__).with_name("viewer.js")


@dataclass(frozen=True)
class ViewerAssets:
    """What the page inlines: ``three`` (the bundle, a classic script defining ``THREE``),
    ``draco_wrapper`` (the decoder's JavaScript), ``draco_wasm`` (its WebAssembly bytes), ``viewer``
    (reports/viewer.js), ``notices`` [(library and version, licence name, licence text)] and
    ``record`` (vendor.json)."""

    three: str
    draco_wrapper: str
    draco_wasm: bytes
    viewer: str
    notices: tuple[tuple[str, str, str], ...]
    record: dict


def _checked_bytes(name: str, record: dict, folder: Path) -> bytes:
    path = folder / name
    if not path.is_file():
        raise RuntimeError(f"{path} is missing: run scripts/vendor_three.sh (needs npm) or restore it from git")
    data = path.read_bytes()
    if hashlib.sha256(data).hexdigest() != record["sha256"].get(name):
        raise RuntimeError(f"{path} differs from its SHA-256 in vendor.json: run scripts/vendor_three.sh or restore it")
    return data


def load_assets(folder: Path = VENDOR) -> ViewerAssets:
    """The viewer's scripts, each vendored file checked against ``folder/vendor.json``
    (RuntimeError naming the file otherwise)."""
    record = json.loads((folder / "vendor.json").read_text(encoding="utf-8"))
    text = {name: _checked_bytes(name, record, folder) for name in record["sha256"]}
    notices = tuple((record[lib]["title"], record[lib]["license"], text[record[lib]["license_file"]].decode("utf-8"))
                    for lib in ("three", "draco"))
    return ViewerAssets(three=text["three.bundle.min.js"].decode("utf-8"),
                        draco_wrapper=text["draco_wasm_wrapper.js"].decode("utf-8"),
                        draco_wasm=text["draco_decoder.wasm"], viewer=VIEWER_JS.read_text(encoding="utf-8"),
                        notices=notices, record=record)


@lru_cache(maxsize=1)
def assets() -> ViewerAssets:
    """:func:`load_assets` of ``reports/vendor/``, read once per process."""
    return load_assets()

"""SHA-256 manifests: mesh files pinned by their bytes, and the one check of a file against its pin.

A manifest is ``sha256sum``'s text format, so ``sha256sum -c`` reads it too: one line per file,
``<64 hex digits>  <path>``, the path relative to the data folder the manifest describes ('/'
separators); blank lines and lines starting with '#' are ignored. Every check here reads the
whole file (no size or date shortcut), so one altered byte is found.

Users: the ``manifest`` option of the ``abc`` and ``abc-nonmanifold`` datasets (a pinned file that
is missing or altered leaves its shape out, one warning line each), the named datasets of the SALS
paper's lists (``sals-abc50``, ``sals-nonmanifold50``: :mod:`datasets.abc`),
``scripts/fetch_abc_unseen.py`` (its CSV manifest) and the regression's frozen subset
(``reports/baselines/abc_subset.sha256``: :func:`verify_manifest`).
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path
from typing import Any

from datasets.registry import DatasetError, DatasetNotFoundError

__all__ = ["file_sha256", "read_manifest", "check_file", "verify_manifest", "shape_bytes_digest"]

_LINE = re.compile(r"^(?P<digest>[0-9a-fA-F]{64}) [ *](?P<path>\S.*)$")
_CHUNK = 1 << 20


def file_sha256(path: Any) -> str:
    """SHA-256 (hex) of a file's bytes, read in 1 MiB chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def read_manifest(path: Any) -> dict[str, str]:
    """``{relative path: lower-case hex digest}`` of a manifest, in file order.

    Raises DatasetNotFoundError when the manifest does not exist, DatasetError (one line naming
    the manifest and the line number) for a line that is neither blank, a '#' comment nor
    ``<digest>  <path>``, and for a path pinned twice."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise DatasetNotFoundError(f"manifest {path} does not exist")
    pins: dict[str, str] = {}
    for number, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        match = _LINE.match(line.rstrip())
        if match is None:
            raise DatasetError(f"{path}: line {number} is not '<sha256>  <path>': {line.strip()[:80]!r}")
        name = match["path"].strip()
        if name in pins:
            raise DatasetError(f"{path}: line {number} pins {name} a second time")
        pins[name] = match["digest"].lower()
    return pins


def check_file(path: Any, digest: str | None, pinned_by: str) -> str | None:
    """One problem line for ``path`` against its pinned ``digest``, or None when the bytes match.

    The line starts with the path: ``<path>: missing (pinned by <pinned_by>)``, ``<path>: SHA-256
    <12 hex>... differs from the pinned <12 hex>...``, or, for ``digest=None``, ``<path>: not
    pinned by <pinned_by>``."""
    path = Path(path)
    if digest is None:
        return f"{path}: not pinned by {pinned_by}"
    if not path.is_file():
        return f"{path}: missing (pinned by {pinned_by})"
    actual = file_sha256(path)
    if actual != digest.lower():
        return f"{path}: SHA-256 {actual[:12]}... differs from the pinned {digest.lower()[:12]}..."
    return None


def verify_manifest(data_dir: Any, manifest: Any) -> list[str]:
    """One problem line (:func:`check_file`) per file of ``manifest`` under ``data_dir`` that is
    missing or altered, in manifest order; empty when every SHA-256 matches. Files of the folder
    that the manifest does not name are not looked at."""
    manifest = Path(manifest)
    data_dir = Path(data_dir)
    return [p for name, digest in read_manifest(manifest).items()
            if (p := check_file(data_dir / name, digest, manifest.name))]


def shape_bytes_digest(dataset, name: str) -> str:
    """What shape ``name`` of ``dataset`` is made of, as one digest: the SHA-256 (hex) of the one file
    it reads (equal to its line in a manifest); of several files (a non-manifold pair), the SHA-256
    of their digests in reading order; of a generated shape (no file), ``generated:`` and the
    content hash of its canonical arrays (:meth:`datasets.io.Shape.content_hash`)."""
    files = [path for path, _ in dataset.stored_files(name)]
    if not files:
        return "generated:" + dataset.load(name).content_hash
    digests = [file_sha256(path) for path in files]
    return digests[0] if len(digests) == 1 else hashlib.sha256("\n".join(digests).encode()).hexdigest()

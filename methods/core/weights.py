"""A trained network as bytes, and back: the one storage format of every network the project
fits or trains (``{'state_dict', 'config', 'budget', 'method', 'final_loss'}`` through
``torch.save``), and the one error of a weights file that cannot be used.

``config`` is the keyword arguments that rebuild the network (``model.config``); the run layer
stores the bytes checksummed (:mod:`foundation.storage`). Everything but the tensors is plain data
(dicts, lists, tuples, numbers, strings), and bytes are read back with ``torch.load(...,
weights_only=True)``: a file that would run code when unpickled (an object with ``__reduce__``) is
refused unread, whoever wrote its checksum.
"""

from __future__ import annotations

import functools
import hashlib
import io
from pathlib import Path
from typing import Callable

import torch

from foundation.storage import CorruptEntry, read_checked, write_checked
from methods.core.device import get_device


class WeightsError(RuntimeError):
    """A weights file is absent, is not the network it should be, or cannot be read; the message
    is one line naming the file."""


def load_plain(data: bytes, what: str = "weights", device=None):
    """``torch.load(data, weights_only=True)`` on ``device`` (tensors and plain data only); any other
    content (an object that would run code when unpickled, foreign or truncated bytes) raises
    :class:`WeightsError` in one line naming ``what``, unread."""
    try:
        return torch.load(io.BytesIO(data), map_location=device, weights_only=True)
    except Exception as exc:  # torch raises UnpicklingError, RuntimeError, EOFError, ... on foreign bytes
        first = (str(exc).strip().splitlines() or [""])[0][:200]
        raise WeightsError(f"{what} refused unread: not a plain weights file ({type(exc).__name__}: {first})") from None


def weights_to_bytes(model, budget: dict, method_name: str, final_loss: float) -> bytes:
    """``torch.save`` bytes of ``{'state_dict', 'config' (``model.config``), 'budget', 'method', 'final_loss'}``."""
    buf = io.BytesIO()
    torch.save({"state_dict": model.state_dict(), "config": model.config, "budget": budget,
                "method": method_name, "final_loss": float(final_loss)}, buf)
    return buf.getvalue()


def refused_weights_from_bytes(data: bytes, build: Callable[..., torch.nn.Module], device=None,
                               method_name: str | None = None, what: str = "weights") -> torch.nn.Module:
    """The model of :func:`weights_from_bytes`; any failure (truncated or foreign bytes, another
    method's weights, another architecture) as one line ``ValueError("<what> refused (<error>): ...")``."""
    try:
        model, _ = weights_from_bytes(data, build, device, method_name, what=what)
    except Exception as exc:
        first = (str(exc).splitlines() or [""])[0][:200]
        raise ValueError(f"{what} refused ({type(exc).__name__}): {first}") from None
    return model


def weights_from_bytes(data: bytes, build: Callable[..., torch.nn.Module], device=None,
                       method_name: str | None = None, what: str = "weights") -> tuple[torch.nn.Module, dict]:
    """(``build(**config)`` with the stored weights, in eval mode on ``device``; the stored dict) from
    :func:`weights_to_bytes`' bytes. Bytes that are not a plain weights record (or would run code
    when unpickled) raise :class:`WeightsError` in one line, unread; ``method_name``, when given,
    must match the stored one (a clear ValueError otherwise, naming ``what``)."""
    device = get_device(device)
    blob = load_plain(data, what, device)
    if not isinstance(blob, dict) or not {"state_dict", "config"} <= set(blob):
        raise WeightsError(f"{what} refused: not a weights record (no state_dict and config)")
    if method_name is not None and blob.get("method") != method_name:
        raise ValueError(f"{what} of method '{blob.get('method')}', expected '{method_name}'")
    model = build(**blob["config"]).to(device)
    model.load_state_dict(blob["state_dict"])
    model.eval()
    return model, blob


def read_weights_file(path, what: str, train_command: str, env: str) -> tuple[dict, str]:
    """(the plain dict, the SHA-256 of the payload) of a weights file written checksummed
    (:func:`foundation.storage.write_checked`); :class:`WeightsError` in one line naming the file:
    absent (with ``train_command``, the command that trains it, and ``env``, the variable that names
    another file), damaged (re-train), or not plain data (:func:`load_plain`)."""
    try:
        payload = read_checked(path)
    except CorruptEntry as exc:
        raise WeightsError(f"{exc} (re-train: {train_command})") from None
    if payload is None:
        raise WeightsError(f"{what} not found at {path} (train them: {train_command}, or set {env})")
    return load_plain(payload, f"{what} {path}", "cpu"), hashlib.sha256(payload).hexdigest()


def load_cached(path, load: Callable):
    """``load(path)``, memoised per process by the file's (path, size, modification time), so a
    rewritten file is read again; an absent file calls ``load`` (which raises its one-line error)."""
    path = Path(path)
    if not path.is_file():
        return load(path)
    stat = path.stat()
    return _load_memo(str(path), stat.st_size, stat.st_mtime_ns, load)


@functools.lru_cache(maxsize=4)
def _load_memo(path: str, size: int, modified_ns: int, load: Callable):
    return load(path)


def write_weights_file(path, blob: dict) -> str:
    """``torch.save`` of the plain ``blob`` (state dicts, config, info) to ``path``, atomically and
    checksummed (:func:`foundation.storage.write_checked`), its folder made; returns the SHA-256 of the
    payload (what :func:`read_weights_file` returns for it)."""
    buf = io.BytesIO()
    torch.save(blob, buf)
    payload = buf.getvalue()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_checked(path, payload)
    return hashlib.sha256(payload).hexdigest()

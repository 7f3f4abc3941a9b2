"""A run directory: its checks, its lock, its config.json and where its meshes go.

* One protocol per directory: :func:`saved_config` reads the configuration a directory holds
  (``config.json``, the source of truth for ``--resume``).
* One writer at a time: :meth:`RunDirectory.lock` takes an exclusive ``fcntl.flock`` on
  ``.salsbench.lock`` for the driver's lifetime; a second driver gets :class:`RunDirectoryBusy`
  naming the holder (pid, host, command, start time). The lock dies with its process (kill -9
  included), so a crashed run never leaves the directory locked.
* Paths users choose are checked up front (:func:`check_writable_dir`): under a file, not
  writable, read-only file system: one line, before any work.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import socket
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

from runner.config import ConfigError, RunConfig
from foundation.serialize import dumps
from foundation.storage import atomic_write

CONFIG_NAME = "config.json"
LOCK_NAME = ".salsbench.lock"


class RunDirectoryBusy(ConfigError):
    """Another driver holds the run directory's lock."""


def check_writable_dir(path: str | os.PathLike, flag: str) -> Path:
    """``path`` as a directory this process can create and write in; ConfigError naming ``flag``."""
    path = Path(path).expanduser()
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{flag} {path}: exists and is not a directory")
    parent = path
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ConfigError(f"{flag} {path}: {parent} is a file, not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".salsbench-write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        reason = "read-only file system" if exc.errno == errno.EROFS else (exc.strerror or str(exc)).lower()
        raise ConfigError(f"{flag} {path}: not writable ({reason})") from None
    return path


def safe_name(name: str) -> str:
    """A shape or method name as one path component."""
    return str(name).replace(os.sep, "_").replace("/", "_") or "_"


def saved_config(run_dir: str | os.PathLike) -> RunConfig | None:
    """The configuration a run directory holds (None when it holds none)."""
    path = Path(run_dir) / CONFIG_NAME
    if not path.is_file():
        return None
    return RunConfig.load(path)


class RunDirectory:
    """One run directory (created by :meth:`prepare`)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)

    @property
    def config_path(self) -> Path:
        return self.path / CONFIG_NAME

    def write_config(self, record: dict[str, Any]) -> None:
        atomic_write(self.config_path, dumps(record, indent=2).encode())

    def read_record(self) -> dict[str, Any]:
        """The whole config.json (config, resolved facts, environment) or {} when absent;
        ConfigError (one line) when it is not a JSON object."""
        if not self.config_path.is_file():
            return {}
        try:
            record = json.loads(self.config_path.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError) as exc:  # ValueError: JSON and UTF-8 decode errors
            raise ConfigError(f"{self.config_path}: not readable JSON ({' '.join(str(exc).split())[:200]})") from None
        if not isinstance(record, dict):
            raise ConfigError(f"{self.config_path}: expected a JSON object, got {type(record).__name__}")
        for key in ("config", "resolved", "environment"):
            if not isinstance(record.get(key, {}), dict):
                raise ConfigError(f"{self.config_path}: expected its '{key}' to be a JSON object, got "
                                  f"{type(record[key]).__name__}")
        return record

    def mesh_relpath(self, shape: str, stem: str) -> str:
        return f"meshes/{safe_name(shape)}/{safe_name(stem)}.ply"

    def write_mesh(self, relpath: str, data: bytes) -> None:
        atomic_write(self.path / relpath, data)

    @contextmanager
    def lock(self) -> Iterator[None]:
        """Hold the exclusive lock of the directory (module docstring)."""
        self.path.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 4096, 0).decode(errors="replace").strip() or "another process"
                raise RunDirectoryBusy(f"--out {self.path} is in use by {holder}; wait for it or use another --out") from None
            from runner.job import now_iso

            command = " ".join([Path(sys.argv[0]).name] + sys.argv[1:])[:300] if sys.argv else "?"
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()} ({command}, since {now_iso()})".encode(), 0)
            try:
                yield
            finally:
                os.ftruncate(fd, 0)
                fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            os.close(fd)

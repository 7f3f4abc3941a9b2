"""Provenance of a run: git commit, package versions, device, CPU, host (for config.json and rows)."""

from __future__ import annotations

import os
import platform
import socket
import subprocess
import sys
from functools import lru_cache
from pathlib import Path
from typing import Any

#: The checkout: the folder holding run_benchmark.py and the project's packages.
REPO = Path(__file__).resolve().parents[1]

#: Packages whose versions go into config.json and every job row.
VERSION_PACKAGES = ("numpy", "torch", "trimesh", "scikit-image", "libigl", "scipy", "pandas", "embreex",
                    "manifold3d", "pykdtree", "ray")


@lru_cache(maxsize=1)
def package_versions() -> dict[str, str]:
    """Installed versions of :data:`VERSION_PACKAGES` (absent ones omitted), plus python."""
    from importlib import metadata

    out = {"python": platform.python_version()}
    for name in VERSION_PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    return out


def cpu_model() -> str | None:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def git_state() -> dict[str, Any]:
    """{'git_commit': hash or None, 'git_dirty': bool or None} of the checkout."""
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True, timeout=10)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=REPO,
                               capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return {"git_commit": None, "git_dirty": None}
    return {"git_commit": commit.stdout.strip() or None,
            "git_dirty": bool(dirty.stdout.strip()) if dirty.returncode == 0 else None}


def environment_record() -> dict[str, Any]:
    """Everything config.json records about where the run ran."""
    import torch

    from methods.core.device import describe_device, get_device

    return {
        "versions": package_versions(), "python": sys.version.split()[0], "platform": platform.platform(),
        "host": socket.gethostname(), "cpu_count": os.cpu_count(), "cpu_model": cpu_model(), **git_state(),
        "device": describe_device(get_device()), "torch_threads": torch.get_num_threads(),
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None, "cuda": torch.version.cuda,
    }

"""Installing salsbench: what a user's environment gets (behaviour, not file contents)."""

import shutil
import subprocess
import sys
import tomllib
import zipfile

import pytest
from packaging.requirements import Requirement

from tests.conftest import REPO


def test_the_built_distribution_installs_no_top_level_package(tmp_path):
    """`pip install .` must never shadow another distribution's names (e.g. Hugging Face `datasets`):
    the wheel holds metadata only; the suite is used from its checkout."""
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, src / name)
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                           "-w", str(tmp_path / "wheel"), str(src)], capture_output=True, text=True, timeout=300)
    if proc.returncode != 0 and "setuptools" in proc.stderr:
        pytest.skip(f"no build backend in this environment: {proc.stderr.strip().splitlines()[-1]}")
    assert proc.returncode == 0, proc.stderr
    (wheel,) = (tmp_path / "wheel").glob("*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert names and all(n.split("/")[0].endswith(".dist-info") for n in names), names


def test_the_torch_requirement_admits_the_pinned_cpu_wheel_and_no_newer_build():
    deps = [Requirement(d) for d in tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]]
    (torch,) = [d for d in deps if d.name == "torch"]
    assert torch.specifier.contains("2.13.0")          # the CPU wheel scripts/setup.sh installs
    assert not torch.specifier.contains("2.15.0")      # an open upper bound would let pip pull a CUDA build


def test_setup_script_refuses_unknown_options():
    proc = subprocess.run(["bash", str(REPO / "scripts" / "setup.sh"), "--tset"], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2 and "unknown option '--tset'" in proc.stderr

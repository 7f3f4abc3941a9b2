"""Installing salsbench must never shadow another distribution's top-level names (e.g. `datasets`)."""

import re
import tomllib

from tests.conftest import REPO


def test_install_puts_no_top_level_package_into_site_packages():
    config = tomllib.loads((REPO / "pyproject.toml").read_text())
    setuptools = config["tool"]["setuptools"]
    assert setuptools["packages"] == [] and setuptools["py-modules"] == []


def test_torch_is_pinned_in_setup_and_bounded_in_dependencies():
    setup = (REPO / "scripts" / "setup.sh").read_text()
    assert '"torch==2.13.0"' in setup
    deps = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]
    torch = [d for d in deps if re.match(r"torch\b", d)]
    assert torch and "<=" in torch[0]  # never an open upper bound that could pull a CUDA build


def test_readme_test_command_is_what_ci_runs():
    readme = (REPO / "README.md").read_text()
    ci = (REPO / ".ci" / "run").read_text()
    command = "bash scripts/setup.sh --test && .venv/bin/python -m pytest"
    assert command in readme and command in ci

"""The repository as a ROS 2 package: colcon (from pip, the extra `colcon`) builds it in a workspace as a ROS
user's `colcon build` would (package.xml, build type ament_python), and what it installs is what `ros2 run cq_ros
NAME` runs: the package found in the ament index from the workspace's setup.sh, every package of the source tree
imported from the install, its console scripts in lib/cq_ros, each answering --help from the installed copy.
The build runs with the setuptools a Jazzy workspace has: 68.1.2, Ubuntu 24.04's."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path
from xml.etree import ElementTree

import pytest
from test_install import source_packages

ROOT = Path(__file__).resolve().parent.parent
BUILD_TIMEOUT_S = 300.0  # the build takes about 6 s on 2 idle cores
JAZZY_SETUPTOOLS = "68.1.2"
# what a workspace copy of the repository leaves out: the repository's own state, results and the pages
SKIP = shutil.ignore_patterns(".git", ".venv", "results", "build", "install", "log", "__pycache__", "*.egg-info",
                              ".ruff_cache", "docs", "tests", "benchmarks")


def test_package_xml_is_format_3_for_ament_python_and_names_the_pyproject_version():
    import tomllib

    package = ElementTree.parse(ROOT / "package.xml").getroot()
    assert package.get("format") == "3" and package.findtext("name") == "cq_ros"
    assert package.find("export").findtext("build_type") == "ament_python"
    assert package.findtext("version") == tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


@pytest.mark.ros  # imports the node packages and runs their --help
@pytest.mark.slow
def test_colcon_builds_the_repository_and_ros2_run_finds_each_node(tmp_path):
    workspace = tmp_path / "ws"
    shutil.copytree(ROOT, workspace / "src" / "cq_ros", ignore=SKIP)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}  # the build reads the workspace's copy only
    setuptools = tmp_path / "setuptools"  # first on the build's path, before this environment's newer one
    got = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--target", str(setuptools),
                          f"setuptools=={JAZZY_SETUPTOOLS}"], capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    assert got.returncode == 0, got.stderr
    built = subprocess.run([sys.executable, "-m", "colcon", "build"], cwd=workspace, capture_output=True, text=True,
                           timeout=BUILD_TIMEOUT_S, env={**env, "PYTHONPATH": str(setuptools)})
    assert built.returncode == 0, built.stdout + built.stderr
    assert "Finished <<< cq_ros" in built.stdout, built.stdout

    # The environment `. install/setup.sh` gives, as a user's shell would have it.
    sourced = subprocess.run(["bash", "-c", ". install/setup.sh && env -0"], cwd=workspace, capture_output=True,
                             timeout=60, env=env, check=True)
    ws_env = dict(line.split("=", 1) for line in sourced.stdout.decode().split("\0") if "=" in line)
    # What `ros2 run cq_ros NAME` does: the package's prefix from the ament index, then lib/<package>/NAME.
    # Every package from the install, not the checkout (whose editable install this environment also has: a
    # package the build left out would be found there).
    found = subprocess.run([sys.executable, "-c", "import importlib, sys\n"
                            "from ament_index_python.packages import get_package_prefix\n"
                            "print(get_package_prefix('cq_ros'))\n"
                            "for name in sys.argv[1:]: print(importlib.import_module(name).__file__)",
                            *sorted(source_packages())], cwd=tmp_path, capture_output=True, text=True, timeout=60,
                           env=ws_env)
    assert found.returncode == 0, found.stderr
    prefix, *imported = found.stdout.split()
    assert Path(prefix) == workspace / "install" / "cq_ros"
    assert all(Path(f).is_relative_to(workspace / "install") for f in imported), imported
    executables = Path(prefix) / "lib" / "cq_ros"
    assert {"world_node", "agent_node", "cq-ros"} <= {p.name for p in executables.iterdir()}
    for name, first in (("world_node", "python -m world_node --ros-args"), ("agent_node", "python -m agent_node"),
                        ("cq-ros", "usage: cq-ros")):
        helped = subprocess.run([str(executables / name), "--help"], cwd=tmp_path, capture_output=True, text=True,
                                timeout=60, env=ws_env)
        assert helped.returncode == 0, helped.stderr
        assert helped.stdout.startswith(first), helped.stdout[:200]
    assert (Path(prefix) / "share" / "cq_ros" / "package.xml").is_file()

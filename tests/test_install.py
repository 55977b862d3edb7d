"""The project installed as a user installs it: a wheel built from the repository holds every package of the
source tree, and installed outside the repository it plays an experiment on the compiled engine and starts both
nodes' --help, every module it runs coming from the installed copy.

The wheel goes into a folder of its own (`pip install --target`), which the commands put first on their path; its
dependencies are this environment's. The checkout's editable install stays importable beside it, so each command
prints the files it ran from and the test checks they are the installed ones: a package missing from the wheel
would be found in the checkout and show there."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BUILD_TIMEOUT_S = 300.0
# a copy of the source tree to build from: a build/ folder an earlier build left in the checkout would fill the
# wheel with what that build held
SKIP = shutil.ignore_patterns(".git", ".venv", "results", "build", "*.egg-info", "__pycache__", ".ruff_cache")
COMPILE_S = 900.0  # the installed copy compiles the engine afresh (about 40 s on 2 cores; minutes when busy)


def source_packages() -> set[str]:
    """Every package of the source tree that a user runs: each folder with an __init__.py, outside tests,
    benchmarks and docs."""
    return {".".join(p.parent.relative_to(ROOT).parts) for p in ROOT.rglob("__init__.py")
            if p.parent.relative_to(ROOT).parts[0] not in ("tests", "benchmarks", "docs", ".venv", "build")}


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(the folder the wheel is installed in, the environment its commands run in, the wheel's file names)."""
    where = tmp_path_factory.mktemp("install")
    shutil.copytree(ROOT, where / "src", ignore=SKIP)
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                            str(where / "src"),
                            "-w", str(where / "dist")], capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    assert built.returncode == 0, built.stderr
    [wheel] = (where / "dist").glob("cq_ros-*.whl")
    target = where / "site"
    done = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(target),
                           str(wheel)], capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    assert done.returncode == 0, done.stderr
    env = {**os.environ, "PYTHONPATH": str(target), "NUMBA_CACHE_DIR": str(where / "numba")}
    return target, env, zipfile.ZipFile(wheel).namelist()


@pytest.mark.slow
def test_the_wheel_holds_every_package_of_the_source_tree(installed):
    _, _, names = installed
    in_wheel = {".".join(Path(n).parent.parts) for n in names if n.endswith("/__init__.py")}
    assert source_packages() <= in_wheel
    assert {"cq_ros/maps/tunnel_to_goal.txt", "msgs_spec/README.md", "node_runtime/fastdds_profile.xml"} <= set(names)


@pytest.mark.ros  # the nodes' programs, if only for --help
@pytest.mark.slow
def test_the_installed_copy_plays_on_the_compiled_engine_and_starts_both_nodes(installed, tmp_path):
    target, env, _ = installed
    ran = subprocess.run([sys.executable, "-c", "import importlib, sys\n"
                          "for name in sys.argv[1:]: print(importlib.import_module(name).__file__)",
                          *sorted(source_packages())], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=120)
    assert ran.returncode == 0, ran.stderr
    assert all(Path(f).is_relative_to(target) for f in ran.stdout.split()), ran.stdout

    out = tmp_path / "out"
    played = subprocess.run([str(target / "bin" / "cq-ros"), "experiment", "--map", "tunnel_to_goal", "--algo", "cq",
                             "--runs", "1", "--episodes", "20", "--engine", "compiled", "--no-figures", "--out",
                             str(out)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=COMPILE_S)
    assert played.returncode == 0, played.stderr
    assert json.loads((out / "manifest.json").read_text())["engine"] == {"cq": "compiled"}
    assert len((out / "episodes.csv").read_text().splitlines()) == 1 + 20

    for node in ("world_node", "agent_node"):
        helped = subprocess.run([str(target / "bin" / node), "--help"], cwd=tmp_path, env=env, capture_output=True,
                                text=True, timeout=120)
        assert helped.returncode == 0, helped.stderr
        assert f"python -m {node}" in helped.stdout

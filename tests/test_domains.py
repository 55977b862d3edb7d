"""The ROS domain a user chose is the one used: `make demo DOMAIN=N` or ROS_DOMAIN_ID for the demo, ROS_DOMAIN_ID
for every tool (a value that is no domain id is one line naming the variable), and the suite's domains from
$CQ_ROS_TEST_DOMAIN_BASE. (`cq-ros launch` on the environment's domain: tests/test_launch.py.)"""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _make_demo(tmp_path: Path, *args: str) -> str:
    """The command `make demo ARGS` would run (make -n), in a copy of the Makefile beside a stand-in .venv."""
    shutil.copy(ROOT / "Makefile", tmp_path / "Makefile")
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    (tmp_path / ".venv").mkdir()
    (tmp_path / ".venv" / ".installed").touch()  # newer than pyproject.toml: make sets nothing up
    env = {k: v for k, v in os.environ.items() if k not in ("MAKELEVEL", "MAKEFLAGS", "MFLAGS")}
    done = subprocess.run(["make", "-n", "demo", *args], cwd=tmp_path, capture_output=True, text=True, timeout=60,
                          env=env)
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.mark.skipif(shutil.which("make") is None, reason="no make here")
def test_make_demo_runs_on_the_domain_given_else_leaves_it_to_the_launch(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    plain = _make_demo(tmp_path / "a")
    assert "cq-ros launch " in plain and "--domain-id" not in plain  # the launch takes ROS_DOMAIN_ID, or draws one
    assert "--domain-id 17" in _make_demo(tmp_path / "b", "DOMAIN=17")


@pytest.mark.parametrize("tool", [["topics"], ["nodes"], ["echo", "/x/world/stats"], ["collect", "--out", "X"],
                                  ["record", "--out", "X"]], ids=lambda t: t[0])
def test_a_tool_on_a_ros_domain_id_that_is_no_domain_is_one_line_naming_the_variable(tool, tmp_path):
    done = subprocess.run([sys.executable, "-m", "cq_ros.cli", *tool], capture_output=True, text=True, timeout=60,
                          cwd=tmp_path, env={**os.environ, "ROS_DOMAIN_ID": "not_a_number"})
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [f"cq-ros {tool[0]}: error: ROS_DOMAIN_ID='not_a_number' in the "
                                                "environment is not a domain id (an integer 0..232)"]
    assert not (tmp_path / "X").exists()


def test_the_suites_domains_come_from_the_base_a_user_sets(tmp_path):
    # A session of the suite's conftest alone, on one test that reports its domain; not an xdist worker's (this
    # test's own worker, gw1 say, would add 1 to the base)
    for name in ("conftest.py", "helpers.py"):
        shutil.copy(ROOT / "tests" / name, tmp_path / name)
    (tmp_path / "test_where.py").write_text("import os\n\ndef test_where(ros_domain_id):\n"
                                            "    print('DOMAIN', ros_domain_id, os.environ['ROS_DOMAIN_ID'])\n")
    for base, said in (("57", "DOMAIN 57 57"), ("abc", "CQ_ROS_TEST_DOMAIN_BASE='abc'")):
        done = subprocess.run([sys.executable, "-m", "pytest", "-s", "-p", "no:cacheprovider", "-n", "0", "-q",
                               "test_where.py"], cwd=tmp_path, capture_output=True, text=True, timeout=120,
                              env={**{k: v for k, v in os.environ.items() if not k.startswith("PYTEST_XDIST")},
                                   "CQ_ROS_TEST_DOMAIN_BASE": base,
                                   "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])})
        assert said in done.stdout + done.stderr, done.stdout + done.stderr
        assert (done.returncode == 0) == (base == "57")

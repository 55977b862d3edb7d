"""Shared fixtures, and the markers that sort the suite into tiers.

Before any test runs (so before any rclpy.init, in this process or in a node process a test starts, which
inherits the environment): a ROS_DOMAIN_ID for the session, $CQ_ROS_TEST_DOMAIN_BASE or a random one in
100..200 (the next ones for the other pytest-xdist workers; every test's ROS, launches included, runs there),
discovery kept to this host (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST), and ROS logs in a temporary directory
instead of ~/.ros.

Markers (registered in pyproject.toml): `ros` for a test that starts ROS nodes or contexts, `root` for one that
needs root (network namespaces), `slow` for one that takes more than about 10 s on 2 busy cores. A test that
asks for a ROS fixture below is marked `ros` here; a module marks the tests that start node processes
(`cq-ros launch`, `python -m world_node`, ...) itself. A test not marked `ros` that calls rclpy.init or starts
a node process fails saying so: `make check` (-m "not ros and not root") must start no ROS.
"""

from __future__ import annotations

import os
import random
import shutil
import subprocess
import sys
import tempfile
from typing import Callable

import pytest

import helpers

_LOG_DIR: str | None = None
_DOMAIN_BASE = "CQ_ROS_TEST_DOMAIN_BASE"
ROS_FIXTURES = {"ros_context", "ros_domain_id", "spin_until", "system_in"}
COMPILE_S = 900.0  # bounds the compiled engine's first compilation (39 s on 2 cores at load 3; minutes when busy)
NODE_MODULES = {"world_node", "agent_node", "ros_tools.compose"}  # python -m <one of these> starts a node


def pytest_configure(config: pytest.Config) -> None:
    global _LOG_DIR
    _LOG_DIR = tempfile.mkdtemp(prefix="cq_ros_test_ros_log_")
    os.environ["ROS_DOMAIN_ID"] = str(_domain_id())
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ["ROS_LOG_DIR"] = _LOG_DIR
    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        _compile_engine()


def _compile_engine() -> None:
    """Load the compiled engine once, before the workers start, so that a fresh clone's first compilation (numba's
    cache) is not paid inside a test: the tests that run `cq-ros` bound each process at 120 s, and in a suite run
    beside two busy loops a 5-episode `cq-ros experiment` timed out there, compiling while the other worker
    compiled too. Where numba cannot load, the engine says so in one line and the tests of the fallback run."""
    print("the suite's first step: loading the compiled engine (a fresh clone compiles it: about 40 s, more "
          "when busy)",
          file=sys.stderr, flush=True)
    subprocess.run([sys.executable, "-c", "from cq_ros.compiled import prepare; prepare()"], timeout=COMPILE_S,
                   check=False)


def _domain_id() -> int:
    """A domain of the session's own: the base is $CQ_ROS_TEST_DOMAIN_BASE where the user set it (a shared host's
    developers each take their own), else pytest-xdist's controller draws one in 100..200 (before it starts its
    workers, which inherit it); worker gw<i> takes base + i, so no two workers of one session share a graph.
    The suite never runs on the user's own ROS_DOMAIN_ID: that is where their live systems are."""
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker is None:
        given = os.environ.get(_DOMAIN_BASE, "").strip()
        os.environ[_DOMAIN_BASE] = given or str(random.SystemRandom().randint(100, 200))
    base = os.environ[_DOMAIN_BASE]
    domain = int(base) + (int(worker.removeprefix("gw")) if worker else 0) if base.isdigit() else 233
    if domain > 232:  # ROS domain ids end at 232 (Fast DDS's ports on Linux)
        raise pytest.UsageError(f"{_DOMAIN_BASE}={base!r}: the suite's workers take base + 0, 1, ... up to "
                                "domain 232; give a smaller integer")
    return domain


def pytest_unconfigure(config: pytest.Config) -> None:
    if _LOG_DIR:
        shutil.rmtree(_LOG_DIR, ignore_errors=True)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark `ros` every test that asks (directly or through another fixture) for a ROS fixture."""
    for item in items:
        if ROS_FIXTURES & set(getattr(item, "fixturenames", ())) and not item.get_closest_marker("ros"):
            item.add_marker(pytest.mark.ros)


@pytest.fixture(autouse=True)
def _no_ros_unless_marked(request, monkeypatch):
    """In a test not marked `ros`, rclpy.init and starting a node process fail, naming the marker."""
    if request.node.get_closest_marker("ros"):
        yield
        return
    import rclpy

    def refuse(*args, **kwargs):
        raise AssertionError(f"{request.node.nodeid} starts ROS: mark it @pytest.mark.ros")

    popen = subprocess.Popen

    class Popen(popen):
        def __init__(self, args, *rest, **kwargs):
            words = [args] if isinstance(args, (str, bytes)) else list(args)
            if any(str(a) in NODE_MODULES for a in words) and not {"-h", "--help"} & set(map(str, words)):
                refuse()
            super().__init__(args, *rest, **kwargs)

    monkeypatch.setattr(rclpy, "init", refuse)
    monkeypatch.setattr(subprocess, "Popen", Popen)
    yield


@pytest.fixture(scope="session")
def ros_domain_id() -> int:
    """The session's ROS_DOMAIN_ID (also in os.environ for node processes)."""
    return int(os.environ["ROS_DOMAIN_ID"])


@pytest.fixture
def ros_context(ros_domain_id: int):
    """A fresh, initialised rclpy Context on the session's domain, shut down after the test; give it to
    nodes (`context=`) and executors so a test's graph is its own even inside one process."""
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain_id)
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.fixture
def spin_until() -> Callable:
    """spin_until(executor, predicate, timeout_s): spin until predicate() holds; False at the timeout."""
    return helpers.spin_until


@pytest.fixture
def system_in(ros_context):
    """system_in(algo, map, seed, episodes, settings, ...): helpers.start_system in the test's own context;
    closed after the test."""
    systems = []

    def start(*args, **kwargs) -> helpers.System:
        systems.append(helpers.start_system(ros_context, *args, **kwargs))
        return systems[-1]

    yield start
    for s in systems:
        s.close()

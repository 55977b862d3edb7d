"""Shared fixtures: every test session talks on its own ROS 2 graph, on this host only.

Before any test runs (so before any rclpy.init, in this process or in a node process a test starts, which
inherits the environment): a random ROS_DOMAIN_ID in 100..200 for the session (the next ones for the other
pytest-xdist workers), discovery kept to this host (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST), and ROS logs in
a temporary directory instead of ~/.ros.
"""

from __future__ import annotations

import os
import random
import shutil
import tempfile
import time
from typing import Callable

import pytest

_LOG_DIR: str | None = None
_DOMAIN_BASE = "CQ_ROS_TEST_DOMAIN_BASE"


def pytest_configure(config: pytest.Config) -> None:
    global _LOG_DIR
    _LOG_DIR = tempfile.mkdtemp(prefix="cq_ros_test_ros_log_")
    os.environ["ROS_DOMAIN_ID"] = str(_domain_id())
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ["ROS_LOG_DIR"] = _LOG_DIR


def _domain_id() -> int:
    """A domain of the session's own: pytest-xdist's controller draws a base (before it starts its workers,
    which inherit it) and worker gw<i> takes base + i, so no two workers of one session share a graph."""
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker is None:
        os.environ[_DOMAIN_BASE] = str(random.SystemRandom().randint(100, 200))
        return int(os.environ[_DOMAIN_BASE])
    return int(os.environ[_DOMAIN_BASE]) + int(worker.removeprefix("gw"))


def pytest_unconfigure(config: pytest.Config) -> None:
    if _LOG_DIR:
        shutil.rmtree(_LOG_DIR, ignore_errors=True)


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

    def spin(executor, predicate: Callable[[], bool], timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > deadline:
                return False
            executor.spin_once(timeout_sec=0.05)
        return True

    return spin

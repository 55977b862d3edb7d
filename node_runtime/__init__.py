"""What the world node and the agent node share at run time, below both (neither node package imports the
other): the node both are (`node`), the process's run loop and executor (`run`), the parameter tables of both
node kinds and their strict declaration (`parameters`), the watch on the ROS graph (`graph`), the publisher that
holds messages until matched (`held`), and what works around rclpy from pip (`rclpy_workarounds`).

    cq_ros -> msgs_spec -> node_runtime -> world_node, agent_node -> ros_tools

Importing the package imports no rclpy; `run` and `node` do.
"""

from __future__ import annotations

import importlib
from typing import Any, Callable

__all__ = ["lazy_node"]


def lazy_node(package: str, name: str) -> Callable[[str], Any]:
    """A node package's module `__getattr__` giving its node class `name` from its `.node` module on first use:
    the node loads rclpy, and the package's core (world_node.lockstep, agent_node.driver) must not."""
    def __getattr__(attr: str) -> Any:
        if attr == name:
            return getattr(importlib.import_module(".node", package), name)
        raise AttributeError(f"module {package!r} has no attribute {attr!r}")
    return __getattr__

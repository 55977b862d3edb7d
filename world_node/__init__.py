"""ROS 2 world node: owns a cq_ros GridWorld and steps it in lockstep with the agent nodes.

`python -m world_node --ros-args -p map:=tunnel_to_goal -p episodes:=500 ...` runs it (see __main__);
`WorldNode(context=ctx, parameter_overrides=[...])` builds it in-process. The protocol itself lives in
`world_node.lockstep` (pure Python, unit-tested without ROS).
"""

from typing import Any

__all__ = ["WorldNode"]


def __getattr__(name: str) -> Any:
    """`WorldNode`, imported on first use: the node loads rclpy, and `import world_node.lockstep` (the core)
    must not."""
    if name == "WorldNode":
        from .node import WorldNode

        return WorldNode
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

"""ROS 2 agent node: one AGV's cq_ros learner (or the central JSA learner of all AGVs) on the wire.

`python -m agent_node --ros-args -p agent_id:=1 -p algo:=cq ...` runs it (see __main__);
`AgentNode(context=ctx, parameter_overrides=[...])` builds it in-process. The protocol itself lives in
`agent_node.driver` (pure Python, unit-tested without ROS).
"""

from typing import Any

__all__ = ["AgentNode"]


def __getattr__(name: str) -> Any:
    """`AgentNode`, imported on first use: the node loads rclpy, and `import agent_node.driver` (the core)
    must not."""
    if name == "AgentNode":
        from .node import AgentNode

        return AgentNode
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

"""ROS 2 world node: owns a cq_ros GridWorld and steps it in lockstep with the agent nodes.

`python -m world_node --ros-args -p map:=tunnel_to_goal -p episodes:=500 ...` runs it (see __main__);
`WorldNode(context=ctx, parameter_overrides=[...])` builds it in-process. The protocol itself lives in
`world_node.lockstep` (pure Python, unit-tested without ROS).
"""

from node_runtime import lazy_node

__all__ = ["WorldNode"]

__getattr__ = lazy_node(__name__, "WorldNode")

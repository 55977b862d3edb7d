"""ROS 2 agent node: one AGV's cq_ros learner (or the central JSA learner of all AGVs) on the wire.

`python -m agent_node --ros-args -p agent_id:=1 -p algo:=cq ...` runs it (see __main__);
`AgentNode(context=ctx, parameter_overrides=[...])` builds it in-process. The protocol itself lives in
`agent_node.driver` (pure Python, unit-tested without ROS).
"""

from node_runtime import lazy_node

__all__ = ["AgentNode"]

__getattr__ = lazy_node(__name__, "AgentNode")

"""A component container: the world node and agent nodes in ONE process, on one executor.

    python -m ros_tools.compose world agv1 agv2 --ros-args -r __ns:=/run1 --params-file params.yaml

As a ROS 2 component container holds several nodes, this process holds one `WorldNode` (the name `world`)
and one `AgentNode` per other name given (`agv<k>`, or `jsa` for the central node), each a node of its own
with its own subscriptions, parameters and statistics, exactly as in a process per node; only the
transport between them stays inside the process. Each node reads its parameters under its fully qualified
name in the params file (`/run1/agv1: {ros__parameters: {...}}`, or `/**` for all), as
`cq-ros launch --compose` writes it. They spin on one executor (`node_runtime.run.make_executor`: the
EventsExecutor unless $CQ_ROS_EXECUTOR says `single`) until every node is done; the exit code is the
largest of theirs (0 every node finished its last episode, 1 one gave up, 2 a bad parameter or node name,
130 Ctrl-C or SIGTERM). An exception in any node's callback ends the process with its traceback after the
executor, the nodes and the context are shut down in that order.
-h, --help: this text and every parameter of both node kinds; starts nothing.
"""

from __future__ import annotations

import sys

from rclpy.node import Node
from rclpy.utilities import remove_ros_args
from rclpy.validate_node_name import validate_node_name

from agent_node import AgentNode
from cq_ros.settings import SettingsError
from node_runtime.parameters import help_requested, print_help
from node_runtime.run import run_node
from world_node import WorldNode

__all__ = ["WORLD", "check_names", "make_nodes", "main"]

WORLD = "world"  # the node name that makes a WorldNode; every other name makes an AgentNode


def check_names(names: list[str]) -> None:
    """ValueError (one line) unless `names` are distinct valid node names, `world` at most once."""
    if not names:
        raise ValueError("no node names: give the nodes to run, e.g. `world agv1 agv2`")
    for name in names:
        try:
            validate_node_name(name)
        except Exception as e:  # rclpy's InvalidNodeNameException says why, on its first line
            raise ValueError(f"node name {name!r}: {str(e).splitlines()[0]}") from None
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise ValueError(f"node names must be distinct, repeated: {', '.join(repeated)}")


def make_nodes(names: list[str], **kwargs) -> list[Node]:
    """One node per name (`world`: the world node; any other: an agent node), in this order, with `kwargs`
    (e.g. context=, parameter_overrides=) for each. A node that cannot be made (bad parameter) destroys the
    ones made before it and raises."""
    nodes: list[Node] = []
    try:
        for name in names:
            nodes.append(WorldNode(name, **kwargs) if name == WORLD else AgentNode(name, **kwargs))
    except BaseException:
        for node in nodes:
            node.destroy_node()
        raise
    return nodes


def main() -> int:
    if help_requested(sys.argv):
        return print_help(__doc__, ("world", "agent"))
    names = remove_ros_args(sys.argv)[1:]
    try:
        check_names(names)
    except ValueError as e:
        print(f"ros_tools.compose: {e}", file=sys.stderr)
        return 2
    return run_node(lambda: make_nodes(names), "ros_tools.compose", (SettingsError,))


if __name__ == "__main__":
    sys.exit(main())

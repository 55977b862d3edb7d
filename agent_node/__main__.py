"""python -m agent_node --ros-args -p agent_id:=K -p algo:=cq -p map:=NAME [-p <parameter>:=VALUE ...]

Runs one agent node until its last episode. Parameters: node_runtime.parameters.AGENT_PARAMETERS (every field of
cq_ros.settings.Settings included; one not given is the map's default, as in cq-ros experiment); for algo jsa
leave agent_id out: one central node drives every AGV.
--params-file, -r __ns:=/name and -r __node:=agvK work as for any ROS 2 node.
Exit codes: 0 last episode played, 1 no valid message from the world for feedback_timeout, 2 a bad parameter
or checkpoint (one line on stderr), 130 interrupted (Ctrl-C, SIGTERM).
-h, --help: this text and every parameter with its type, default and description; starts nothing.
"""

import sys

from node_runtime.run import node_main

from .node import AgentNode


def main() -> int:
    return node_main(__doc__, "agent", AgentNode)


if __name__ == "__main__":
    sys.exit(main())

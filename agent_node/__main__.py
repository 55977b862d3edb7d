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

from cq_ros.settings import SettingsError
from node_runtime.parameters import help_requested, print_help
from node_runtime.run import run_node

from .node import AgentNode


def main() -> int:
    if help_requested(sys.argv):
        return print_help(__doc__, ("agent",))
    return run_node(AgentNode, "agent_node", (SettingsError,))


if __name__ == "__main__":
    sys.exit(main())

"""python -m world_node --ros-args -p map:=NAME -p episodes:=N [-p <parameter>:=VALUE ...]

Runs the world node until its last episode. Parameters: node_runtime.parameters.WORLD_PARAMETERS (every field of
cq_ros.settings.Settings included; one not given is the map's default, as in cq-ros experiment); --params-file
and -r __ns:=/name work as for any ROS 2 node.
Exit codes: 0 all episodes played, 1 the agents never all connected (startup_timeout), 2 a bad parameter
(one line on stderr) or another world in the same namespace and domain (world_node.twin), 3 two live nodes act
as one agent, 130 interrupted (Ctrl-C, SIGTERM).
-h, --help: this text and every parameter with its type, default and description; starts nothing.
"""

import sys

from node_runtime.run import node_main

from .node import WorldNode


def main() -> int:
    return node_main(__doc__, "world", WorldNode)


if __name__ == "__main__":
    sys.exit(main())

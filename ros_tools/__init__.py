"""The ROS tools a user runs from the `cq-ros` command (cq_ros/cli/main.py dispatches here lazily): the launcher
(`launch`: a world and its agents as processes, or all in one process with `compose`; `hosts`: network
namespaces as hosts) and the command-line tools on the ROS graph (`commands`: echo, topics, nodes, record,
reading a recorded bag). The top of the layering: it imports both node packages, and nothing but the CLI,
the tests and the benchmarks imports it.
"""

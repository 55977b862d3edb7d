"""The `cq-ros` command: the parser and dispatch (main.py), the commands' parsers (arguments.py, offline_parser.py,
ros_parser.py), the offline commands (offline.py), the planner's command (plan.py) and the ROS commands (ros.py),
which reach ros_tools, hence rclpy, only when one of them runs."""

"""What the world node and the agent node share at run time, below both (neither node package imports the
other): the process's run loop and executor (`run`), the parameter tables of both node kinds and their strict
declaration (`parameters`), and the watch on the ROS graph (`graph`).

    cq_ros -> msgs_spec -> node_runtime -> world_node, agent_node -> ros_tools

Importing the package imports no rclpy; `run` does.
"""

"""CQ-learning for multi-robot systems: the science (maps, world, learners, statistics, engine), no ROS."""
__version__ = "0.1.0"

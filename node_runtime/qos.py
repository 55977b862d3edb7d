"""The rclpy QoSProfile of a msgs_spec `Qos`: the contract keeps QoS as plain data (it loads no rclpy), and
whatever creates a publisher or a subscription passes `profile(spec.qos)`."""

from __future__ import annotations

from functools import lru_cache

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from msgs_spec import Qos

__all__ = ["profile"]


@lru_cache(maxsize=None)
def profile(qos: Qos) -> QoSProfile:
    """The QoSProfile `qos` names, made once per distinct `qos` (rclpy only reads it)."""
    return QoSProfile(reliability=ReliabilityPolicy[qos.reliability.upper()],
                      durability=DurabilityPolicy[qos.durability.upper()],
                      history=HistoryPolicy.KEEP_LAST, depth=qos.depth)

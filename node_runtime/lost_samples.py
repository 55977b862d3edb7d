"""Samples the middleware says a subscription lost (its message-lost event), counted per node as
`lost_samples` in its statistics.

The nodes' lockstep subscriptions (feedback, heartbeat, actions) listen to it. The pip Fast DDS of Jazzy reports
nothing for samples that a KEEP_LAST queue replaced, which is all a flood loses on one host
(benchmarks/lost_samples.py; its output in docs/data/faults/), so on this middleware the count stays 0 and
the nodes' sequence checks count what was really lost (docs/faults.md); a middleware that reports losses has
them counted here. Peer position subscriptions, made and dropped as CQ looks, do not listen: an event handler
more for each would be made and destroyed with them.
"""

from __future__ import annotations

from typing import Any

from rclpy.event_handler import SubscriptionEventCallbacks

__all__ = ["LOST", "count_lost"]

LOST = "lost_samples"


def count_lost(counters: dict[str, int]) -> SubscriptionEventCallbacks:
    """A subscription's event callbacks (rclpy's defaults kept) that add each message-lost report's new losses
    to counters[LOST]."""
    def lost(info: Any) -> None:
        if info.total_count_change > 0:
            counters[LOST] = counters.get(LOST, 0) + info.total_count_change
    return SubscriptionEventCallbacks(message_lost=lost)

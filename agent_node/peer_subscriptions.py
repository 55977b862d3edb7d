"""The peer position subscriptions of an agent node: made when its core starts waiting on a peer (a CQ agent in
a conflict state), dropped when it stops, made anew when one delivers nothing (agent_node.peer_view), and read
for a position the executor never announced (node_runtime.rclpy_workarounds.take_now says why).
"""

from __future__ import annotations

from functools import partial
from typing import Any, Callable

from rclpy.event_handler import SubscriptionEventCallbacks

from msgs_spec import POSITION, position_topic
from node_runtime.qos import profile
from node_runtime.rclpy_workarounds import take_now

from .effects import Renew, Subscribe, Unsubscribe

__all__ = ["PeerSubscriptions"]

# No event handlers: rclpy 7.1.6 gives a subscription two by default (incompatible QoS, incompatible type, each
# logging a warning), and an agent makes and drops one at every conflict state; the two cost 110-160 us of the
# 1.0-1.3 ms a subscription costs in CPU (docs/ros.md). A writer with an incompatible QoS or type on
# a position topic is not ours, and its own process still logs the mismatch.
_NO_EVENTS = SubscriptionEventCallbacks(use_default_callbacks=False)


class PeerSubscriptions:
    """`on_position(peer, raw)` takes each position; `counters` counts those taken unannounced."""

    def __init__(self, node: Any, on_position: Callable[[int, Any], None], counters: dict[str, int]):
        self.node, self.on_position, self.counters = node, on_position, counters
        self.subs: dict[int, Any] = {}  # peer -> its position subscription, while the core wants it
        self._stalled: set[tuple[int, int, int]] = set()  # positions waited for at the last check

    def subscribe(self, effect: Subscribe | Renew) -> None:
        peer = effect.peer
        # Raw: the serialized bytes are decoded (msgs_spec.codec) without a message object built for them.
        self.subs[peer] = self.node.create_subscription(POSITION.msg_type, position_topic(peer),
                                                        partial(self.on_position, peer), profile(POSITION.reader_qos),
                                                        raw=True, event_callbacks=_NO_EVENTS)

    def unsubscribe(self, effect: Unsubscribe | Renew) -> None:
        self.node.destroy_subscription(self.subs.pop(effect.peer))

    def renew(self, effect: Renew) -> None:
        # Which side lost the match, for whoever reads the log: the reader's view of the writers
        writers = self.subs[effect.peer].get_publisher_count()
        self.node.get_logger().warning(f"{position_topic(effect.peer)}: its reader had matched {writers} writer(s); "
                                       "made anew")
        self.unsubscribe(effect)
        self.subscribe(effect)

    def take_unannounced(self, waiting: Callable[[], set[tuple[int, int, int]]]) -> None:
        """Take each position in `waiting()` ((peer, episode, step) waited for) that was already waited for at the
        last call and sits in its reader unannounced, as the executor would have taken it; taking leaves nothing
        for a late announcement, so none is played twice."""
        for peer, _, _ in waiting() & self._stalled:
            sub = self.subs.get(peer)
            taken = take_now(sub) if sub is not None else None
            if taken is not None:
                self.counters["unannounced_positions"] = self.counters.get("unannounced_positions", 0) + 1
                self.on_position(peer, taken[0])
        self._stalled = waiting()

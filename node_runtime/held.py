"""A publisher that holds what it is given until its writer has matched its readers, then sends it in order:
the agents' actions and statistics go out through it.

Our action and statistics topics are volatile: a message published before the match is lost, and only the
writer's side of a match says it will arrive (a reader may see the match first, as the world's action reader
and the launcher's statistics readers do).
"""

from __future__ import annotations

from typing import Any, Callable

from .graph import Matched
from .qos import profile
from .rclpy_workarounds import raw_publisher

__all__ = ["HeldPublisher"]


class HeldPublisher:
    """`publish(payload)` sends `serialize(payload)` (serialized bytes, or a message) once the writer has
    matched `min_matched` readers; before, it holds the payloads (with `latest_only`, the newest alone: a stale
    action is worth nothing). Its matched events say when, at no cost per message; a payload held also asks
    the graph, which the events may lag."""

    def __init__(self, node: Any, spec: Any, topic: str, serialize: Callable[[Any], Any], *, min_matched: int = 1,
                 latest_only: bool = False):
        from rclpy.event_handler import PublisherEventCallbacks

        self.min_matched, self.latest_only = min_matched, latest_only
        self.serialize = serialize
        self.held: list = []  # payloads not sent yet
        self.matched = Matched(then=self.flush)
        self.pub = node.create_publisher(spec.msg_type, topic, profile(spec.qos),
                                         event_callbacks=PublisherEventCallbacks(matched=self.matched))
        # The node destroys its publishers only after it has stopped spinning (node_runtime.rclpy_workarounds).
        self._raw = raw_publisher(self.pub)

    def publish(self, payload: Any) -> None:
        if not self.held and self.matched.count >= self.min_matched:  # matched, nothing held: straight out
            self._send(payload)
            return
        if self.latest_only:
            self.held.clear()
        self.held.append(payload)
        self.flush()

    def flush(self) -> None:
        if self.held and (self.matched.count >= self.min_matched
                          or self.pub.get_subscription_count() >= self.min_matched):
            for payload in self.held:
                self._send(payload)
            self.held.clear()

    def _send(self, payload: Any) -> None:
        data = self.serialize(payload)
        if type(data) is bytes:
            self._raw(data)
        else:
            self.pub.publish(data)

"""The world's position topics, agv<k>/position: agent k's position goes out each step only while a reader
listens (a peer in a conflict state, a tool) or a viewer watches the scene. Most steps of a run nobody does
(independent learners never look, CQ only near a conflict), and then the core makes no Position at all
(`Lockstep.watched`). The topic is latched: a reader that comes is sent the newest position at once, so a late
subscriber still gets the step it waits for. The publishers' matched events say who listens, at no cost per step.
"""

from __future__ import annotations

from functools import partial
from typing import Any

from rclpy.event_handler import PublisherEventCallbacks

from msgs_spec import POSITION, POSITION_LAYOUT, Position, position_topic
from node_runtime.graph import Matched
from node_runtime.qos import profile
from node_runtime.rclpy_workarounds import raw_publisher

__all__ = ["PositionTopics"]


class PositionTopics:
    """One latched publisher per agent of `core` (a Lockstep), whose `watched` it keeps: the agents with a
    reader, or every agent while the viewers' scene (world_node.viz), which shows them all, has one (`scene`)."""

    def __init__(self, node: Any, core: Any, key: Any):
        self.core = core
        self.serialize = partial(POSITION_LAYOUT.serialize, key=key)
        self.sent: dict[int, Position] = {}  # agent -> the last position that went out
        self.scene = Matched(then=self.watch)
        self.readers = {k: Matched(then=self.watch) for k in range(1, core.world.n + 1)}
        # The node destroys its publishers only after it has stopped spinning (node_runtime.rclpy_workarounds).
        self._raw = {k: raw_publisher(node.create_publisher(POSITION.msg_type, position_topic(k), profile(POSITION.qos),
                                                            event_callbacks=PublisherEventCallbacks(matched=readers)))
                     for k, readers in self.readers.items()}
        self.watch()

    def publish(self, position: Position) -> None:
        self.sent[position.agent] = position
        self._raw[position.agent](self.serialize(position))

    def watch(self) -> None:
        """Tell the core whose positions to make, as the matched events say now. An agent it starts to make goes
        out at once where it is now, for the reader that came, unless that position went out before (the topic
        keeps it for a new reader: sent again, a reader would hear it twice)."""
        before = set(self.core.watched)
        everyone = self.scene.count > 0
        self.core.watched = tuple(k for k, readers in self.readers.items() if everyone or readers.count)
        for k in self.core.watched:
            newest = None if k in before else self.core.position(k)
            if newest is not None and newest != self.sent.get(k):
                self.publish(newest)

"""An agent node's publication for viewers (msgs_spec/viz.py): at each decision, a line from its AGV to every
peer it looked at to choose (the peers its learner named at that step, whose positions it waited for; the
central JSA node: every other acting AGV, for each AGV it moves), and none once its episode is over. Built
only while someone subscribes (as the publisher's matched events tell: an unwatched agent pays nothing)."""

from __future__ import annotations

from typing import Any

from rclpy.event_handler import PublisherEventCallbacks

from msgs_spec import Action, AgentStats
from msgs_spec.viz import LOOKS, Looks, looks_topic
from node_runtime.qos import profile
from node_runtime.graph import Matched

__all__ = ["AgentView"]


class AgentView:
    def __init__(self, node: Any, driver: Any):
        self.node, self.driver = node, driver
        self.watchers = {k: Matched() for k in driver.agents}
        self.pubs = {k: node.create_publisher(LOOKS.msg_type, looks_topic(k), profile(LOOKS.qos),
                                              event_callbacks=PublisherEventCallbacks(matched=self.watchers[k]))
                     for k in driver.agents}
        self.last: dict[int, Looks] = {}  # agent -> its last decision's looks, to clear when its episode ends

    def on_action(self, action: Action) -> None:
        """Call as the action goes out (the driver still holds what it decided on)."""
        if not self.watchers[action.agent].count:
            self.last.pop(action.agent, None)
            return
        self._publish(self._looks(action))

    def on_stats(self, stats: AgentStats) -> None:
        """The agent's episode is over: it looks at nobody (stamped with the step after its last decision)."""
        last = self.last.pop(stats.agent, None)
        if last is not None and last.episode == stats.episode and self.watchers[stats.agent].count:
            self._publish(Looks(last.agent, last.episode, last.step + 1, last.row, last.col))

    def _publish(self, looks: Looks) -> None:
        self.last[looks.agent] = looks
        self.pubs[looks.agent].publish(LOOKS.encode(looks, stamp=self.node.get_clock().now().to_msg()))

    def _looks(self, action: Action) -> Looks:
        driver = self.driver
        cells = driver.map.cells
        if driver.learner.central:  # its state is every agent's cell
            joint = [cells[c] for c in driver.learner.s]
            others = [j for j in driver.acting if j != action.agent]
            return Looks(action.agent, action.episode, action.step, *joint[action.agent - 1],
                         tuple((j, *joint[j - 1]) for j in others))
        # The peers needed at this decision are those PeerView has just (re)marked as needed (idle 0).
        peers = sorted(j for j, idle in driver.peers.idle.items() if idle == 0)
        seen = driver.peers.cells_at(action.episode, action.step, peers) or {}
        return Looks(action.agent, action.episode, action.step, *cells[driver.learner.s],
                     tuple((j, *cells[seen[j]]) for j in peers if j in seen))

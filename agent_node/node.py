"""The agent node: one cq_ros learner (or, for jsa, the central learner of every AGV) on the msgs_spec topics.

Thin on purpose, like the ros2/examples minimal nodes: it declares its parameters, creates the publishers and
subscriptions msgs_spec names with msgs_spec's QoS, decodes every message (agent_node.wire_reading) and hands its
payload to its core, the driver of `agent_node.driver` (made by `agent_node.config`), carrying out the effects it
returns: publish, subscribe to, drop or renew a peer's position topic (always from inside an executor callback,
as docs/design.md's field notes require), save a checkpoint, finish. Constructible in-process
(`AgentNode(context=ctx, parameter_overrides=[...])`); `done` is a Future holding the exit code.
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial
from typing import Any, Callable

from msgs_spec import (
    ACTION, ACTION_LAYOUT, AGENT_STATS, FEEDBACK, HEARTBEAT, HEARTBEAT_TOPIC, Action, action_topic,
    agent_namespace, agent_stats_topic, feedback_topic, position_topic, serialize,
)
from node_runtime.held import HeldPublisher
from node_runtime.node import RunNode
from node_runtime.patience import Patience
from node_runtime.qos import profile
from node_runtime.run import when, when_acked

from .checkpoint import CheckpointWriter
from .config import agent_config, make_driver
from .effects import Finish, Renew, SaveCheckpoint, Send, Subscribe, Unsubscribe
from .peer_subscriptions import PeerSubscriptions
from .viz import AgentView
from .wire_reading import feedback_in, heartbeat_in, position_in

__all__ = ["AgentNode"]

# How often a node waiting for peer positions looks into its position readers for one the executor was never
# told of (node_runtime.rclpy_workarounds.take_now); a position waited for over one such period is taken there.
UNANNOUNCED_CHECK_S = 0.05
# At the end, how long statistics held for min_stats_subscribers may wait for the match (discovery takes
# 0.05-2.8 s here, docs/design.md, field notes).
STATS_MATCH_TIMEOUT_S = 10.0


def _config_and_core(values: dict, log: Callable[[str], Any]) -> tuple[Any, Any]:
    config = agent_config(values)
    return config, make_driver(config, log=log)


class AgentNode(RunNode):
    """Parameters: node_runtime.parameters.AGENT_PARAMETERS (a bad one: node_runtime.node.RunNode). Named
    `agent` unless given another name; a launcher starting several gives each its own (`-r __node:=agv1`),
    since the name is fixed before the agent_id parameter can be read."""

    def __init__(self, node_name: str = "agent", **kwargs: Any):
        super().__init__(node_name, "agent", _config_and_core, **kwargs)
        cfg, core, agents, clock = self.config, self.core, self.core.agents, self.get_clock()
        # Feedback proves the world's action reader exists, not that our writer has matched it yet.
        self._actions = {k: HeldPublisher(self, ACTION, action_topic(k), partial(ACTION_LAYOUT.serialize, key=cfg.key),
                                          latest_only=True) for k in agents}
        self._stats = {k: HeldPublisher(self, AGENT_STATS, agent_stats_topic(k),
                                        lambda s: serialize(s, key=cfg.key, stamp=clock.now().to_msg()),
                                        min_matched=cfg.min_stats_subscribers) for k in agents}
        # Raw: the serialized bytes are decoded (msgs_spec.codec) without a message object built for them.
        self._feedback = [self.create_subscription(FEEDBACK.msg_type, feedback_topic(k), partial(self._on_feedback, k),
                                                   profile(FEEDBACK.reader_qos), raw=True)
                          for k in agents]
        self._heartbeat = self.create_subscription(HEARTBEAT.msg_type, HEARTBEAT_TOPIC,
                                                   lambda m: self._apply(heartbeat_in(core, m)),
                                                   profile(HEARTBEAT.reader_qos), raw=True)
        self._peers = PeerSubscriptions(self, self._on_position, core.extra_counters)
        self._checkpoints = CheckpointWriter(cfg.checkpoint, f"{self.get_name()}_checkpoint", core.extra_counters,
                                             self.get_logger().error)
        # What each effect the core returns does, looked up by its type (no chain of patterns per effect)
        self._carry_out = {Send: self._send, Subscribe: self._peers.subscribe, Unsubscribe: self._peers.unsubscribe,
                           Renew: self._peers.renew, Finish: lambda _e: self.finish(0),
                           SaveCheckpoint: lambda e: self._checkpoints.save(e.episode, e.learner)}
        self._view = AgentView(self, core) if self.get_parameter("markers").value else None
        self.gave_up: str | None = None  # the line the node gave up on the world with
        watch_period = min(cfg.feedback_timeout / 10, 1.0)
        core.link.patience = Patience(cfg.feedback_timeout, watch_period)
        self.every(watch_period, self._check_world)
        self.watch([HEARTBEAT_TOPIC] + [position_topic(k) for k in range(1, cfg.gridmap.n_agents + 1)]
                   + [name(k) for k in agents for name in (feedback_topic, action_topic, agent_stats_topic)])
        self.every(UNANNOUNCED_CHECK_S, self._take_unannounced)
        self.get_logger().info(f"{cfg.algo} learner for {', '.join(map(agent_namespace, agents))} on map "
                               f"{cfg.gridmap.name}, {cfg.episodes} episodes, then {cfg.settings.eval_episodes} greedy")

    def _on_feedback(self, agent: int, msg: Any) -> None:
        self._apply(feedback_in(self.core, agent, msg))

    def _on_position(self, peer: int, msg: Any) -> None:
        self._apply(position_in(self.core, peer, msg))

    def _apply(self, effects: list) -> None:
        carry_out = self._carry_out
        for effect in effects:
            carry_out[type(effect)](effect)

    def _send(self, effect: Send) -> None:
        payload = effect.payload
        if type(payload) is Action:
            self._actions[payload.agent].publish(payload)
            if self._view is not None:
                self._view.on_action(payload)
            return
        # Statistics count every failed checkpoint write before them, as when the writes were made in place: they
        # wait for the writes in flight (seldom: a write takes milliseconds, an episode longer).
        if self._checkpoints.writes and self._checkpoints.count(wait=True):
            payload = replace(payload, counters=self.core.counters())
        self._stats[payload.agent].publish(payload)
        if self._view is not None:
            self._view.on_stats(payload)

    def _check_world(self) -> None:
        if self._checkpoints.writes:
            self._checkpoints.count()
        if self.core.link.patience.expired() and not self.done.done():
            self.gave_up = self.core.link.giving_up(self.config.feedback_timeout)
            self.get_logger().error(self.gave_up)
            self.finish(1)

    def _take_unannounced(self) -> None:
        self._peers.take_unannounced(self.core.waiting_for)
        self._apply(self.core.renew_quiet())  # the peer subscriptions that deliver nothing: made anew

    def close(self, code: int) -> None:
        # A short run can end before our statistics writer has matched its subscribers: wait for them, bounded.
        when(self, lambda: not any(pub.held for pub in self._stats.values()), STATS_MATCH_TIMEOUT_S,
             partial(self._closed, code))

    def _closed(self, code: int, sent: bool) -> None:
        if not sent:
            held = sum(len(pub.held) for pub in self._stats.values())
            self.get_logger().warning(f"{held} statistics message(s) never sent: fewer than min_stats_subscribers="
                                      f"{self.config.min_stats_subscribers} subscribers in {STATS_MATCH_TIMEOUT_S} s")
        # The last checkpoint's write, then the statistics' acknowledgements, both bounded; a write still going
        # on is waited for when the node is destroyed.
        when(self, self._checkpoints.written, STATS_MATCH_TIMEOUT_S,
             lambda _written: (self._checkpoints.count(),
                               when_acked(self, [pub.pub for pub in self._stats.values()],
                                          lambda: self.done.set_result(code))))

    def destroy_node(self) -> None:
        checkpoints = getattr(self, "_checkpoints", None)  # none yet: a bad parameter destroys the node in __init__
        if checkpoints is not None:
            checkpoints.close()
        super().destroy_node()

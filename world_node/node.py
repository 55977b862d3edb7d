"""The world node: a cq_ros GridWorld stepped in lockstep with the agent nodes over the msgs_spec topics.

Thin on purpose, like the ros2/examples minimal nodes: it declares its parameters, creates the publishers
and subscriptions msgs_spec names with msgs_spec's QoS, decodes every action (world_node.wire_reading) and
hands it, and every timer tick, to its core, `world_node.lockstep.Lockstep`, publishing what it returns.
Constructible in-process (`WorldNode(context=ctx, parameter_overrides=[...])`); `done` is a Future holding the
exit code.
"""

from __future__ import annotations

import time
from functools import partial
from typing import Any

from msgs_spec import (
    ACTION, FEEDBACK, FEEDBACK_LAYOUT, HEARTBEAT, HEARTBEAT_LAYOUT, HEARTBEAT_TOPIC, WORLD_STATS, WORLD_STATS_TOPIC,
    Feedback, Heartbeat, Position, WorldStats, action_topic, agent_namespace, feedback_topic, position_topic,
    serialize,
)
from node_runtime.graph import writers_and_namesakes
from node_runtime.node import RunNode
from node_runtime.qos import profile
from node_runtime.rclpy_workarounds import raw_publisher
from node_runtime.run import when_acked

from .lockstep import TWIN_EXIT, world_core
from .positions import PositionTopics
from .twin import Identity, Twins
from .viz import WorldView
from .wire_reading import action_in, heartbeat_in

__all__ = ["WorldNode"]

STARTUP_POLL_S = 0.05  # how often to look whether every agent is connected, before the first step


class WorldNode(RunNode):
    """Parameters: node_runtime.parameters.WORLD_PARAMETERS (a bad one: node_runtime.node.RunNode). `identity`:
    who this world is to a twin (world_node.twin), drawn at start unless a test gives it. `done`: 0 all episodes
    played, 1 agents never connected or none acts any more, 2 a second system here, TWIN_EXIT a twin agent."""

    def __init__(self, node_name: str = "world", identity: Identity | None = None, **kwargs: Any):
        identity = identity or Identity.draw()
        super().__init__(node_name, "world", partial(world_core, identity=identity), **kwargs)
        cfg, core, key = self.config, self.core, self.config.key
        self.twins = Twins(identity, self.get_name(), self.get_namespace(), cfg.heartbeat_period)
        agents = range(1, core.world.n + 1)
        self.positions = positions = PositionTopics(self, core, key)  # made only while someone reads them
        self._feedback = {k: self.create_publisher(FEEDBACK.msg_type, feedback_topic(k), profile(FEEDBACK.qos))
                          for k in agents}
        feedback = {k: raw_publisher(pub) for k, pub in self._feedback.items()}
        self._stats = self.create_publisher(WORLD_STATS.msg_type, WORLD_STATS_TOPIC, profile(WORLD_STATS.qos))
        self._heartbeat = self.create_publisher(HEARTBEAT.msg_type, HEARTBEAT_TOPIC, profile(HEARTBEAT.qos))
        # The core's outbox by payload type, each by its layout's own serializer (no lookup of it per message)
        self._senders = {
            Position: positions.publish,
            Feedback: lambda f: feedback[f.agent](FEEDBACK_LAYOUT.serialize(f, key)),
            Heartbeat: lambda h: self._heartbeat.publish(HEARTBEAT_LAYOUT.serialize(h, key)),
            WorldStats: lambda w: self._stats.publish(serialize(w, key=key, stamp=self.get_clock().now().to_msg())),
        }
        self._view = WorldView(self, cfg.gridmap, positions.scene) if self.get_parameter("markers").value else None
        # Raw: the serialized bytes are decoded (msgs_spec.codec) without a message object built for them.
        self._actions = {k: self.create_subscription(ACTION.msg_type, action_topic(k),
                                                     lambda m, k=k: self._publish(action_in(core, k, m)),
                                                     profile(ACTION.reader_qos), raw=True)
                         for k in agents}
        # Every world's heartbeat, ours included: what a twin says of itself (world_node.twin)
        self._heartbeats = self.create_subscription(HEARTBEAT.msg_type, HEARTBEAT_TOPIC,
                                                    lambda m: heartbeat_in(self.twins, core.drops, m),
                                                    profile(HEARTBEAT.reader_qos), raw=True)
        self.every(cfg.heartbeat_period, lambda: self._send([core.heartbeat()]))
        self.watch([HEARTBEAT_TOPIC, WORLD_STATS_TOPIC]
                   + [name(k) for k in agents for name in (position_topic, feedback_topic, action_topic)])
        self._waits_logged = False
        self._deadline = time.monotonic() + cfg.startup_timeout
        self._startup = self.every(STARTUP_POLL_S, self._wait_for_agents)
        self.get_logger().info(f"map {cfg.gridmap.name}, {core.world.n} agents, {cfg.episodes} episodes and "
                               f"{cfg.settings.eval_episodes} greedy: waiting for the agents")

    def _wait_for_agents(self) -> None:
        # The first step waits for every agent's action and feedback topics to match (a feedback sent before its
        # subscription matched would be lost) and for world/stats subscribers; then for the twin rule, read on the
        # graph as it is now, before any message of ours reaches the agents (they may be a second system's).
        cfg = self.config
        missing = [agent_namespace(k) for k, sub in self._actions.items()
                   if sub.get_publisher_count() == 0 or self._feedback[k].get_subscription_count() == 0]
        if self._stats.get_subscription_count() < cfg.min_stats_subscribers:
            missing.append(f"{cfg.min_stats_subscribers} {WORLD_STATS_TOPIC} subscriber(s)")
        if not missing:
            seen = writers_and_namesakes(self, HEARTBEAT_TOPIC)
            if self._refused(seen):
                return
            waits_for = self.twins.waits_for(*seen)
            if waits_for is None:
                self._startup.cancel()
                self.every(self.core.tick_period, self._tick)
                self.get_logger().info("every agent is connected: stepping")
                self._send([self.core.heartbeat()])  # a twin hears at once that this world steps
                self._publish(self.core.begin())
                return
            if not self._waits_logged:
                self._waits_logged = True
                self.get_logger().warning(f"every agent is connected; waiting for {waits_for}")
            missing = [waits_for]
        if time.monotonic() > self._deadline:
            self.get_logger().error(f"no start after startup_timeout={cfg.startup_timeout} s: still waiting for "
                                    f"{', '.join(missing)}")
            self.finish(1)

    def _tick(self) -> None:
        self._publish(self.core.on_tick())
        why = self.core.twin or self.core.no_progress
        if why is not None and not self.closing:
            self.get_logger().error(f"{why}: ending the run")
            self.finish(TWIN_EXIT if self.core.twin is not None else 1)

    def _refused(self, seen: tuple[list, int]) -> bool:
        """Whether the twin rule ends this world (exit 2), said in one line."""
        refusal = self.twins.refusal(self.core.episode >= 0, *seen)
        if refusal and not self.closing:
            self.get_logger().error(refusal)
            self.finish(2)
        return bool(refusal)

    def check_graph(self) -> None:
        super().check_graph()
        self._refused(writers_and_namesakes(self, HEARTBEAT_TOPIC))

    def _send(self, out: list) -> None:
        senders = self._senders
        for payload in out:
            senders[type(payload)](payload)

    def _publish(self, out: list) -> None:
        self._send(out)
        if self._view is not None:
            self._view.publish(out)
        if self.core.finished and not self.done.done():
            self.get_logger().info(f"all {self.config.total_episodes} episodes played ({self.config.episodes} "
                                   f"learning, {self.config.settings.eval_episodes} greedy)")
            self.finish(0)

    def close(self, code: int) -> None:
        # Reliable messages still in flight go with the process: give the readers a bounded moment to
        # acknowledge the last feedback and statistics (an exited agent's reader is no longer waited for).
        when_acked(self, [self._stats, *self._feedback.values()], lambda: self.done.set_result(code))

"""The world node: a cq_ros GridWorld stepped in lockstep with the agent nodes over the msgs_spec topics.

Thin on purpose, like the ros2/examples minimal nodes: it declares its parameters, creates the publishers
and subscriptions msgs_spec names with msgs_spec's QoS, and hands every message and timer tick to
`world_node.lockstep.Lockstep`, publishing what it returns. Constructible in-process
(`WorldNode(context=ctx, parameter_overrides=[...])`); `done` is a Future holding the exit code.
"""

from __future__ import annotations

import time
from functools import partial
from typing import Any

from rclpy.event_handler import PublisherEventCallbacks
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.task import Future

from cq_ros.engine import world_seed
from cq_ros.settings import SettingsError
from cq_ros.world import GridWorld
from msgs_spec import (
    ACTION, FEEDBACK, FEEDBACK_LAYOUT, HEARTBEAT, HEARTBEAT_LAYOUT, HEARTBEAT_TOPIC, POSITION, POSITION_LAYOUT,
    WORLD_STATS, WORLD_STATS_TOPIC, Feedback, Heartbeat, Position, WorldStats, action_topic, agent_namespace,
    decode_heartbeat, feedback_topic, position_topic, serialize,
)
from node_runtime.qos import profile
from node_runtime.rclpy_workarounds import raw_publisher
from node_runtime.graph import CHECK_PERIOD_S, GraphWatch, Matched, watch_graph, writers
from node_runtime.lost import count_lost
from node_runtime.parameters import declare_node_parameters
from node_runtime.report import node_report
from node_runtime.run import when_acked

from .lockstep import TWIN_EXIT, Lockstep, world_config
from .twin import Identity, Twins
from .viz import WorldView

__all__ = ["WorldNode"]

STARTUP_POLL_S = 0.05  # how often to look whether every agent is connected, before the first step


class _ListenedPosition:
    """An AGV's position topic, sent only while someone listens, as its matched events tell: most steps of a
    run nobody does (CQ listens to a peer only in a conflict state, independent learners never), and a writer
    with no reader still pays for each publish. The newest position not sent is held and sent when a reader
    matches, so a late subscriber still gets the position of the step it waits for (the topic is latched:
    before a reader matched, the writer's history may hold an older one, which the reader drops as stale)."""

    __slots__ = ("matched", "publish", "key", "held")

    def __init__(self, node: Node, topic: str, key: Any):
        self.key = key
        self.held: Position | None = None  # serialized only if it goes out
        self.matched = Matched(then=self._on_match)
        pub = node.create_publisher(POSITION.msg_type, topic, profile(POSITION.qos),
                                    event_callbacks=PublisherEventCallbacks(matched=self.matched))
        self.publish = raw_publisher(pub)

    def send(self, position: Position) -> None:
        if self.matched.count:
            self.publish(POSITION_LAYOUT.serialize(position, self.key))
            self.held = None
        else:
            self.held = position

    def _on_match(self) -> None:
        if self.matched.count and self.held is not None:
            self.publish(POSITION_LAYOUT.serialize(self.held, self.key))
            self.held = None


class WorldNode(Node):
    """Parameters: node_runtime.parameters.WORLD_PARAMETERS. A bad value raises cq_ros.settings.SettingsError, or
    rclpy's ParameterException for a value of the wrong type (either: one line naming the parameter).
    `identity`: who this world is to a twin (world_node.twin), drawn at start unless a test gives it."""

    def __init__(self, node_name: str = "world", identity: Identity | None = None, **kwargs: Any):
        super().__init__(node_name, **kwargs)
        try:
            values = declare_node_parameters(self, "world")
            self.config = cfg = world_config(values)
        except (SettingsError, ParameterException):
            self.destroy_node()
            raise
        world = GridWorld(cfg.gridmap, cfg.settings, seed=world_seed(cfg.seed, cfg.run))
        identity = identity or Identity.draw()
        self.core = Lockstep(world, cfg.total_episodes, cfg.step_timeout, log=self.get_logger().warning,
                             key=cfg.key, rejoin_time=cfg.startup_timeout, identity=identity)
        self.twins = Twins(identity, self.get_name(), self.get_namespace(), cfg.heartbeat_period)
        agents = range(1, world.n + 1)
        key = cfg.key
        self._positions = {k: _ListenedPosition(self, position_topic(k), key) for k in agents}
        self._feedback = {k: self.create_publisher(FEEDBACK.msg_type, feedback_topic(k), profile(FEEDBACK.qos))
                          for k in agents}
        # What each payload of the core's outbox goes out as, looked up by its type alone (no isinstance chain).
        positions = {k: pub.send for k, pub in self._positions.items()}
        feedback = {k: raw_publisher(pub) for k, pub in self._feedback.items()}
        # Each payload's own serializer: msgs_spec.serialize's bytes, without its lookup of the payload's layout.
        self._senders = {
            Position: lambda p: positions[p.agent](p),
            Feedback: lambda f: feedback[f.agent](FEEDBACK_LAYOUT.serialize(f, key)),
        }
        self._stats = self.create_publisher(WORLD_STATS.msg_type, WORLD_STATS_TOPIC, profile(WORLD_STATS.qos))
        self._view = WorldView(self, cfg.gridmap) if self.get_parameter("markers").value else None
        # Raw: the core decodes the serialized bytes (msgs_spec.codec), no message object is built for it.
        lost = count_lost(self.core.extra_counters)
        self._actions = {k: self.create_subscription(ACTION.msg_type, action_topic(k), partial(self._on_action, k),
                                                     profile(ACTION.reader_qos), raw=True, event_callbacks=lost)
                         for k in agents}
        self._heartbeat = self.create_publisher(HEARTBEAT.msg_type, HEARTBEAT_TOPIC, profile(HEARTBEAT.qos))
        # Every world's heartbeat, ours included: what a twin says of itself (world_node.twin)
        self._heartbeats = self.create_subscription(HEARTBEAT.msg_type, HEARTBEAT_TOPIC, self._on_heartbeat,
                                                    profile(HEARTBEAT.reader_qos), raw=True)
        self._senders[Heartbeat] = lambda h: self._heartbeat.publish(HEARTBEAT_LAYOUT.serialize(h, key))
        self._senders[WorldStats] = lambda w: self._stats.publish(
            serialize(w, key=key, stamp=self.get_clock().now().to_msg()))
        self._heartbeat_timer = self.create_timer(cfg.heartbeat_period, lambda: self._send([self.core.heartbeat()]))
        self._graph = GraphWatch(self.get_name(), self.get_namespace(), self.get_logger().warning)
        self._waits_logged = False
        self._graph_topics = [HEARTBEAT_TOPIC, WORLD_STATS_TOPIC] + [
            name(k) for k in agents for name in (position_topic, feedback_topic, action_topic)]
        self._graph_timer = self.create_timer(CHECK_PERIOD_S, self._check_graph)
        # result: the exit code (0 all episodes played, 1 agents never connected or no agent acts any more,
        # 2 refused at start: a second system here, TWIN_EXIT two nodes act as one agent)
        self.done = Future()
        self._closing = False  # finishing: flushing the last messages before `done`
        self._deadline = time.monotonic() + cfg.startup_timeout
        self._timer = self.create_timer(STARTUP_POLL_S, self._wait_for_agents)
        self.get_logger().info(f"map {cfg.gridmap.name}, {world.n} agents, {cfg.episodes} episodes and "
                               f"{cfg.settings.eval_episodes} greedy: waiting for the agents")

    def report(self) -> dict:
        """What it counted so far, by kind and by topic (node_runtime.report)."""
        return node_report(self.get_name(), self.core.counters(), self.core.drops)

    def _missing(self) -> list[str]:
        """What the first step still waits for: agents whose action or feedback topic is not matched yet
        (a feedback sent before its subscription matched would be lost), and world/stats subscribers."""
        missing = [agent_namespace(k) for k, sub in self._actions.items()
                   if sub.get_publisher_count() == 0 or self._feedback[k].get_subscription_count() == 0]
        if self._stats.get_subscription_count() < self.config.min_stats_subscribers:
            missing.append(f"{self.config.min_stats_subscribers} {WORLD_STATS_TOPIC} subscriber(s)")
        return missing

    def _wait_for_agents(self) -> None:
        missing = self._missing()
        if not missing:
            # The agents connected may be a second system's, in our namespace: the twin rule first, on the graph
            # as it is now, before any message of ours reaches them.
            seen = self._seen()
            if self._refused(seen):
                return
            waits_for = self.twins.waits_for(*seen)
            if waits_for is None:
                self._replace_timer(self.core.tick_period, self._tick)
                self.get_logger().info("every agent is connected: stepping")
                self._send([self.core.heartbeat()])  # a twin hears at once that this world steps
                self._publish(self.core.begin())
                return
            if not self._waits_logged:
                self._waits_logged = True
                self.get_logger().warning(f"every agent is connected; waiting for {waits_for}")
            missing = [waits_for]
        if time.monotonic() > self._deadline:
            self.get_logger().error(f"no start after startup_timeout={self.config.startup_timeout} s: still "
                                    f"waiting for {', '.join(missing)}")
            self._finish(1)

    def _on_action(self, agent: int, msg: Any) -> None:
        self._publish(self.core.on_action(agent, msg))

    def _tick(self) -> None:
        self._publish(self.core.on_tick())
        if self.core.twin is not None and not self._closing:
            self.get_logger().error(f"{self.core.twin}: ending the run")
            self._finish(TWIN_EXIT)
        elif self.core.no_progress is not None and not self._closing:
            self.get_logger().error(f"{self.core.no_progress}: ending the run")
            self._finish(1)

    def _on_heartbeat(self, msg: Any) -> None:
        # read without the key: a twin of another launch has a key of its own (world_node.twin)
        hb = self.core.drops.guard(decode_heartbeat, msg, source=HEARTBEAT_TOPIC)
        if hb is not None:
            self.twins.heard(hb)

    def _seen(self) -> tuple[list, int]:
        """What world_node.twin reads of the graph: the writers of world/heartbeat (when there is more than
        ours), and how many nodes bear our name and namespace."""
        beating = writers(self, HEARTBEAT_TOPIC) if self.count_publishers(HEARTBEAT_TOPIC) > 1 else []
        me = (self.get_name(), self.get_namespace())
        return beating, sum(1 for n in self.get_node_names_and_namespaces() if tuple(n) == me)

    def _refused(self, seen: tuple[list, int]) -> bool:
        """Whether the twin rule ends this world (exit 2), said in one line."""
        refusal = self.twins.refusal(self.core.episode >= 0, *seen)
        if refusal and not self._closing:
            self.get_logger().error(refusal)
            self._finish(2)
        return bool(refusal)

    def _check_graph(self) -> None:
        watch_graph(self, self._graph, self._graph_topics)
        self.core.extra_counters.update(self._graph.counters())
        self._refused(self._seen())

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
            self._finish(0)

    def _replace_timer(self, period: float, callback) -> None:
        self._timer.cancel()
        self.destroy_timer(self._timer)
        self._timer = self.create_timer(period, callback)

    def _finish(self, code: int) -> None:
        if self._closing:
            return
        self._closing = True
        self._timer.cancel()
        self._heartbeat_timer.cancel()
        self._graph_timer.cancel()
        # Reliable messages still in flight go with the process: give the readers a bounded moment to
        # acknowledge the last feedback and statistics (an exited agent's reader is no longer waited for).
        when_acked(self, [self._stats, *self._feedback.values()], lambda: self.done.set_result(code))

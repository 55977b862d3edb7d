"""The agent node: one cq_ros learner (or, for jsa, the central learner of every AGV) on the msgs_spec topics.

Thin on purpose, like the ros2/examples minimal nodes: it declares its parameters, creates the publishers
and subscriptions msgs_spec names with msgs_spec's QoS, and hands every message to the driver of
`agent_node.driver` (made by `agent_node.config`), carrying out the effects it returns: publish, subscribe
to, drop or renew a peer's position topic (always from inside an executor callback, as docs/design.md's field
notes require), save a checkpoint, finish. While the driver waits for peer positions, it also takes one that its
reader holds but the executor never announced (`_take_unannounced`: a middleware race, see there), and lets the
driver renew a subscription that delivers nothing (agent_node.peer_view, RENEW_AFTER_S).
Constructible in-process (`AgentNode(context=ctx, parameter_overrides=[...])`); `done` is a Future holding
the exit code.
"""

from __future__ import annotations

import errno
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from functools import partial
from typing import Any

from rclpy.event_handler import PublisherEventCallbacks
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.task import Future

from cq_ros.lab.output import os_reason
from cq_ros.settings import SettingsError
from msgs_spec import (
    ACTION, ACTION_LAYOUT, AGENT_STATS, FEEDBACK, HEARTBEAT, HEARTBEAT_TOPIC, POSITION, Action, action_topic,
    agent_namespace, agent_stats_topic, feedback_topic, position_topic, serialize,
)
from node_runtime.qos import profile
from node_runtime.rclpy_workarounds import raw_publisher, take_now
from node_runtime.graph import CHECK_PERIOD_S, GraphWatch, Matched, watch_graph
from node_runtime.lost import count_lost
from node_runtime.parameters import declare_node_parameters
from node_runtime.patience import Patience
from node_runtime.report import node_report
from node_runtime.run import when, when_acked

from .checkpoint import checkpoint_bytes, write_checkpoint
from .config import agent_config, make_driver
from .effects import Finish, Renew, SaveCheckpoint, Send, Subscribe, Unsubscribe
from .viz import AgentView

__all__ = ["AgentNode"]

# How often a node waiting for peer positions looks into its position readers for one the executor was never
# told of (see AgentNode._take_unannounced); a position waited for over one such period is taken there.
UNANNOUNCED_CHECK_S = 0.05
# At the end, how long statistics held for min_stats_subscribers may wait for the match (discovery takes
# 0.05-2.8 s here, docs/design.md, field notes).
STATS_MATCH_TIMEOUT_S = 10.0




class _HeldPublisher:
    """A publisher that holds what it is given until its writer has matched `min_matched` subscriptions, then
    sends it in order. Our topics here are volatile: a message published before the match is lost, and only
    the writer's side of a match says it will arrive (a reader may see the match first, as the world's
    action reader and the launcher's statistics readers do). With `latest_only` it holds the newest message
    alone (a stale action is worth nothing)."""

    def __init__(self, node: Node, spec: Any, topic: str, min_matched: int, latest_only: bool = False,
                 key: bytes | None = None):
        self.clock = node.get_clock()
        self.min_matched, self.latest_only, self.key = min_matched, latest_only, key
        self.held: list = []  # payloads not sent yet
        self.matched = Matched(then=self.flush)
        self.pub = node.create_publisher(spec.msg_type, topic, profile(spec.qos),
                                         event_callbacks=PublisherEventCallbacks(matched=self.matched))
        # Serialized bytes go straight to the writer (node_runtime.rclpy_workarounds; the node destroys its
        # publishers only after it has stopped spinning). Statistics are messages, published as such.
        self._raw = raw_publisher(self.pub)
        # An action's own serializer (msgs_spec.serialize's bytes, without its lookup of the payload's layout);
        # statistics stamped with the node's clock as they go out
        self._serialize = ACTION_LAYOUT.serialize if spec is ACTION else self._stamped

    def _stamped(self, payload: Any, key: Any) -> Any:
        return serialize(payload, key=key, stamp=self.clock.now().to_msg())

    def publish(self, payload: Any) -> None:
        if not self.held and self.matched.count >= self.min_matched:  # matched, nothing held: straight out
            data = self._serialize(payload, self.key)
            if type(data) is bytes:
                self._raw(data)
            else:
                self.pub.publish(data)
            return
        if self.latest_only:
            self.held.clear()
        self.held.append(payload)
        self.flush()

    def flush(self) -> None:
        # The matched events say so at no cost once matched; before, ask the graph (the event may lag it).
        if self.held and (self.matched.count >= self.min_matched
                          or self.pub.get_subscription_count() >= self.min_matched):
            for payload in self.held:
                self.pub.publish(self._serialize(payload, self.key))
            self.held.clear()


class AgentNode(Node):
    """Parameters: node_runtime.parameters.AGENT_PARAMETERS. A bad value raises cq_ros.settings.SettingsError, or
    rclpy's ParameterException for a value of the wrong type (either: one line naming the parameter).

    The node is named `agent` unless given another name; a launcher starting several gives each its own
    (`-r __node:=agv1`), since the name is fixed before the agent_id parameter can be read.
    """

    def __init__(self, node_name: str = "agent", **kwargs: Any):
        super().__init__(node_name, **kwargs)
        try:
            values = declare_node_parameters(self, "agent")
            self.config = cfg = agent_config(values)
            self.driver = make_driver(cfg, log=self.get_logger().warning)
        except (SettingsError, ParameterException):
            self.destroy_node()
            raise
        agents = self.driver.agents
        # Feedback proves the world's action reader exists, not that our writer has matched it yet.
        self._actions = {k: _HeldPublisher(self, ACTION, action_topic(k), 1, latest_only=True, key=cfg.key)
                         for k in agents}
        self._stats = {k: _HeldPublisher(self, AGENT_STATS, agent_stats_topic(k), cfg.min_stats_subscribers,
                                         key=cfg.key) for k in agents}
        # Raw: the driver decodes the serialized bytes (msgs_spec.codec), no message object is built for it.
        lost = count_lost(self.driver.link.extra_counters)
        self._feedback = [self.create_subscription(FEEDBACK.msg_type, feedback_topic(k),
                                                   partial(self._on_feedback, k), profile(FEEDBACK.reader_qos),
                                                   raw=True, event_callbacks=lost)
                          for k in agents]
        self._heartbeat = self.create_subscription(HEARTBEAT.msg_type, HEARTBEAT_TOPIC,
                                                   lambda m: self._apply(self.driver.on_heartbeat(m)),
                                                   profile(HEARTBEAT.reader_qos), raw=True, event_callbacks=lost)
        self._positions = {}  # peer -> its position subscription, while the driver wants it
        self._writer: ThreadPoolExecutor | None = None  # writes the checkpoints, in order, off the executor
        self._writes: list = []  # (episode, concurrent Future) of the checkpoint writes not counted yet
        # What each effect a driver returns does, looked up by its type (no chain of patterns per effect)
        self._carry_out = {Send: self._send, Subscribe: self._subscribe, Unsubscribe: self._unsubscribe,
                           Renew: self._renew, SaveCheckpoint: lambda e: self._save_checkpoint(e.episode, e.learner),
                           Finish: lambda _e: self._finish(0)}
        self._view = AgentView(self, self.driver) if self.get_parameter("markers").value else None
        self.done = Future()  # result: the exit code (0 last (greedy) episode played, 1 the world went silent)
        self._closing = False  # finishing: flushing the last statistics before `done`
        self.gave_up: str | None = None  # the line the node gave up on the world with
        watch_period = min(cfg.feedback_timeout / 10, 1.0)
        self.driver.link.patience = Patience(cfg.feedback_timeout, watch_period)
        self._watchdog = self.create_timer(watch_period, self._check_world)
        self._graph = GraphWatch(self.get_name(), self.get_namespace(), self.get_logger().warning)
        self._graph_topics = [HEARTBEAT_TOPIC] + [position_topic(k) for k in range(1, cfg.gridmap.n_agents + 1)] + [
            name(k) for k in agents for name in (feedback_topic, action_topic, agent_stats_topic)]
        self._graph_timer = self.create_timer(CHECK_PERIOD_S, self._check_graph)
        self._stalled: set[tuple[int, int, int]] = set()  # positions waited for at the last check
        self._unannounced_timer = self.create_timer(UNANNOUNCED_CHECK_S, self._take_unannounced)
        self.get_logger().info(f"{cfg.algo} learner for {', '.join(map(agent_namespace, agents))} on map "
                               f"{cfg.gridmap.name}, {cfg.episodes} episodes, then "
                               f"{cfg.settings.eval_episodes} greedy")

    def report(self) -> dict:
        """What it counted so far, by kind and by topic (node_runtime.report)."""
        return node_report(self.get_name(), self.driver.counters(), self.driver.drops)

    def _on_feedback(self, agent: int, msg: Any) -> None:
        self._apply(self.driver.on_feedback(agent, msg))

    def _on_position(self, peer: int, msg: Any) -> None:
        self._apply(self.driver.on_position(peer, msg))

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
        else:
            if self._writes:
                payload = self._settled(payload)
            self._stats[payload.agent].publish(payload)
            if self._view is not None:
                self._view.on_stats(payload)

    def _subscribe(self, effect: Subscribe) -> None:
        peer = effect.peer
        self._positions[peer] = self.create_subscription(POSITION.msg_type, position_topic(peer),
                                                         partial(self._on_position, peer), profile(POSITION.reader_qos),
                                                         raw=True)

    def _unsubscribe(self, effect: Unsubscribe) -> None:
        self.destroy_subscription(self._positions.pop(effect.peer))

    def _renew(self, effect: Renew) -> None:
        # Which side lost the match, for whoever reads the log: the reader's view of the writers
        writers = self._positions[effect.peer].get_publisher_count()
        self.get_logger().warning(f"{position_topic(effect.peer)}: its reader had matched {writers} writer(s); "
                                  "made anew")
        self._unsubscribe(effect)
        self._subscribe(effect)

    def _save_checkpoint(self, episode: int, learner: Any) -> None:
        """Take the learner's state now (it goes on learning) and write it on the node's writer thread: the
        file's fsync took longer than taking the state, on the path every other node of a composed process waits on.
        A write that fails is logged and counted (`checkpoint_failed.<errno>`) once it is known: a full or
        read-only disk costs the checkpoint, never the learning, which goes on in memory (the next save
        tries again). Statistics wait for the writes in flight before them (`_settled`), so they count every
        failure of a save before them, as when the writes were made in place."""
        if self._writer is None:
            self._writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"{self.get_name()}_checkpoint")
        data = checkpoint_bytes(learner, episode)
        self._writes.append((episode, self._writer.submit(write_checkpoint, self.config.checkpoint, data)))

    def _count_written(self, wait: bool = False) -> bool:
        """Count and log the failures of the writes done (with `wait`: of every write, waiting for them);
        True if any. Run on the executor's thread, which alone touches the counters."""
        failed = False
        while self._writes and (wait or self._writes[0][1].done()):
            episode, write = self._writes.pop(0)
            error = write.exception()
            if error is None:
                continue
            if not isinstance(error, OSError):  # a bug, not the disk: raised here as it was when written in place
                raise error
            failed = True
            name = f"checkpoint_failed.{errno.errorcode.get(error.errno, 'other').lower()}"
            counters = self.driver.link.extra_counters
            counters[name] = counters.get(name, 0) + 1
            self.get_logger().error(f"checkpoint {self.config.checkpoint} of episode {episode} not written: "
                                    f"{os_reason(error)}; learning goes on (counted as {name})")
        return failed

    def _settled(self, stats: Any) -> Any:
        """`stats` counting every checkpoint write before it: waits for the writes still in flight (seldom: a
        write takes milliseconds, an episode longer) and, if one failed, rebuilds the counters."""
        if self._count_written(wait=True):
            stats = replace(stats, counters=self.driver.counters())
        return stats

    def destroy_node(self) -> None:
        writer = getattr(self, "_writer", None)  # none yet: a bad parameter destroys the node in __init__
        if writer is not None:  # a destroyed node's checkpoints are on disk, as when written in place
            writer.shutdown(wait=True)
        super().destroy_node()

    def _check_world(self) -> None:
        if self._writes:
            self._count_written()
        link = self.driver.link
        if link.patience.expired() and not self.done.done():
            # A world restarted mid-run is another incarnation, of another run unless it was given this one's
            # nonce: its messages are refused, never taken for the world this agent played with, so the run
            # ends here, saying so.
            other = self.driver.drops["other_incarnation"] + self.driver.drops["other_run"]
            why = (f"; {other} messages came from another world incarnation or run (other_incarnation, "
                   "other_run): the world restarted (or another run's messages were replayed), and this run "
                   "cannot go on with it") if other else ""
            if link.behind is not None and not other:  # the world beats on, and steps without us
                (world_e, world_s), (e, s) = link.behind
                self.gave_up = (f"no feedback taken for {link.patience.waited:.1f} s awake, {link.silent_for():.1f} s "
                                f"of wall time (feedback_timeout={self.config.feedback_timeout}), while the world's "
                                f"heartbeats say it is at episode {world_e} step {world_s} and this agent waits for "
                                f"episode {e} step {s}: it takes no feedback (its reader or executor stopped): "
                                "giving up")
            else:
                self.gave_up = (f"no valid message from the world (feedback or heartbeat) for "
                                f"{link.patience.waited:.1f} s awake, {link.silent_for():.1f} s of wall time "
                                f"(feedback_timeout={self.config.feedback_timeout}){why}: giving up")
            self.get_logger().error(self.gave_up)
            self._finish(1)

    def _take_unannounced(self) -> None:
        """Take a waited-for peer position that sits in its reader unannounced since the last check.

        rclpy's EventsExecutor learns of a message through the middleware's new-message callback, which it
        sets on a subscription after the node made it. rmw_fastrtps (Jazzy) reads the reader's unread count
        first and only then switches its data-available listener on: a latched sample that lands between the
        two is never announced, and sits in the reader until the peer's next position, which the world sends
        only once it has stepped, i.e. after step_timeout. Within one process the latched sample follows the
        match within a millisecond or two, often inside that window (benchmarks/latched_race.py counts it).
        A position still missing after a whole check period is taken from the reader here, as the executor
        would have taken it; taking leaves nothing for a late announcement, so none is played twice."""
        waiting = self.driver.waiting_for()
        for peer, _, _ in waiting & self._stalled:
            sub = self._positions.get(peer)
            if sub is None:
                continue
            taken = take_now(sub)
            if taken is not None:
                counters = self.driver.link.extra_counters
                counters["unannounced_positions"] = counters.get("unannounced_positions", 0) + 1
                self._on_position(peer, taken[0])
        self._apply(self.driver.renew_quiet())
        self._stalled = self.driver.waiting_for()

    def _check_graph(self) -> None:
        watch_graph(self, self._graph, self._graph_topics)
        self.driver.link.extra_counters.update(self._graph.counters())

    def _finish(self, code: int) -> None:
        if self._closing:
            return
        self._closing = True
        self._watchdog.cancel()
        self._graph_timer.cancel()
        self._unannounced_timer.cancel()
        # A short run can end before our statistics writer has matched its subscribers: wait for them, bounded.
        when(self, lambda: not any(pub.held for pub in self._stats.values()), STATS_MATCH_TIMEOUT_S,
             lambda sent: self._close(code, sent))

    def _close(self, code: int, sent: bool) -> None:
        if not sent:
            held = sum(len(pub.held) for pub in self._stats.values())
            self.get_logger().warning(f"{held} statistics message(s) never sent: fewer than min_stats_subscribers="
                                      f"{self.config.min_stats_subscribers} subscribers within "
                                      f"{STATS_MATCH_TIMEOUT_S} s")
        # The last checkpoint's write, then the statistics' acknowledgements, both bounded; a write still going
        # on is waited for when the node is destroyed.
        when(self, lambda: all(write.done() for _, write in self._writes), STATS_MATCH_TIMEOUT_S,
             lambda _written: (self._count_written(),
                               when_acked(self, [stats.pub for stats in self._stats.values()],
                                          lambda: self.done.set_result(code))))

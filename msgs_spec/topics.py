"""The one place naming every topic: name, ROS type, QoS, payload, publisher and subscribers.

QoS is plain data here (`Qos`): the contract loads no rclpy, and node_runtime.qos.profile() makes the rclpy
QoSProfile a node passes to create_publisher/create_subscription.

Names are relative ("agv1/position"), so a node started with `-r __ns:=/run7` puts the whole system under
/run7/ and parallel systems never mix. Agent k's topics live under `agv<k>/`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any, Callable

from diagnostic_msgs.msg import DiagnosticArray

from . import codec
from .errors import WireError
from .payloads import ID_DIGITS, Action, AgentStats, Feedback, Heartbeat, Position, WorldStats

__all__ = [
    "AGENT_PREFIX", "Qos", "QOS_FEEDBACK", "QOS_ACTION", "QOS_POSITION", "QOS_STATS",
    "TopicSpec", "FEEDBACK", "POSITION", "ACTION", "HEARTBEAT", "AGENT_STATS", "WORLD_STATS", "TOPICS",
    "WORLD_STATS_TOPIC", "HEARTBEAT_TOPIC", "READER_DEPTH", "agent_namespace", "feedback_topic", "position_topic",
    "action_topic", "agent_stats_topic", "agent_topics", "parse_topic", "qos_summary", "type_name",
]

AGENT_PREFIX = "agv"

RELIABILITIES = ("reliable", "best_effort")
DURABILITIES = ("volatile", "transient_local")


@dataclass(frozen=True)
class Qos:
    """A topic's QoS profile as plain data, history always keep last `depth` (rclpy's names, lower case)."""

    reliability: str
    durability: str
    depth: int

    def __post_init__(self) -> None:
        if self.reliability not in RELIABILITIES or self.durability not in DURABILITIES or self.depth < 1:
            raise ValueError(f"not a QoS of this contract: {self}")


# Lockstep sends at most a couple of messages per topic between two waits (at an episode boundary the world
# sends the last feedback and the next episode's step-0 feedback back to back), so depth 10 is headroom; a
# reliable reader that fell 10 behind would be a bug elsewhere.
QOS_FEEDBACK = Qos("reliable", "volatile", 10)
QOS_ACTION = Qos("reliable", "volatile", 10)
# Latched: publisher AND subscriber must both use this profile (a volatile subscriber gets no history; a
# transient-local subscriber to a volatile publisher gets nothing).
QOS_POSITION = Qos("reliable", "transient_local", 1)
# Statistics must all arrive: a launch's rows and a collect's need every episode's. Transient local: a
# volatile reader is owed only what is sent once both sides have matched, and with both cores busy a launcher
# never got agv2's episodes 0-7, sent after agv2's writer had matched it (its reader matched later); a
# transient-local reader is sent the writer's history on matching. Depth 1000: a reliable keep-last writer
# drops its oldest sample, acknowledged or not, once it holds `depth`, and a reader keeps `depth` until its
# executor takes them, so a listener may fall this many episodes behind a fast map on a busy machine.
QOS_STATS = Qos("reliable", "transient_local", 1000)
QOS_HEARTBEAT = Qos("reliable", "volatile", 1)
# A reader's history is shared by every writer of its topic (DDS keeps it per instance; our topics have
# one): at depth 10 a burst of a dozen messages from anyone else evicts the world's before the callback
# takes it. The nodes read the lockstep topics at this depth, so a burst of a few hundred cannot.
READER_DEPTH = 1000


def type_name(msg_type: type) -> str:
    """'std_msgs/msg/Int32MultiArray', the name `ros2 topic list -t` and rosbag2 use."""
    pkg = msg_type.__module__.split(".")[0]
    return f"{pkg}/msg/{msg_type.__name__}"


def qos_summary(qos: Qos) -> str:
    """'reliable, transient local, keep last 1'."""
    return f"{qos.reliability.replace('_', ' ')}, {qos.durability.replace('_', ' ')}, keep last {qos.depth}"


@dataclass(frozen=True, eq=False)
class TopicSpec:
    """One topic of the system. `pattern` holds '{agent}' for per-agent topics. `decoder` takes a message and the
    four expectations (bounds, agent, episode, step), ignoring those that do not apply to the payload."""

    key: str
    pattern: str
    msg_type: type
    qos: Qos
    payload: type
    publisher: str
    subscribers: str
    fields: str  # the field mapping, one line (the README gives the details; an array's fields come from its layout)
    reader_depth: int | None = None  # the nodes' subscriptions keep this many (None: as qos)
    decoder: Callable[..., Any] = field(kw_only=True)
    encoder: Callable[..., Any] = field(default=codec.encode, kw_only=True)

    @property
    def reader_qos(self) -> Qos:
        """The profile the nodes subscribe with: qos, deeper where `reader_depth` says (compatible: a reader's
        depth is its own)."""
        return self.qos if self.reader_depth is None else replace_depth(self.qos, self.reader_depth)

    @property
    def per_agent(self) -> bool:
        return "{agent}" in self.pattern

    @property
    def type_name(self) -> str:
        return type_name(self.msg_type)

    def name(self, agent: int | None = None) -> str:
        """The relative topic name (for agent `agent` if the topic is per agent)."""
        if not self.per_agent:
            if agent is not None:
                raise ValueError(f"{self.pattern} is not a per-agent topic")
            return self.pattern
        return self.pattern.format(agent=_agent_id(agent))

    def encode(self, payload: Any, **kwargs: Any) -> Any:
        if type(payload) is not self.payload:
            raise WireError("wrong_type", f"{self.pattern} carries {self.payload.__name__}, "
                                          f"got {type(payload).__name__}")
        return self.encoder(payload, **kwargs)

    def decode(self, msg: Any, *, bounds: Any = None, agent: int | None = None, episode: int | None = None,
               step: int | None = None) -> Any:
        """The payload of a message received on this topic; the expectations as `decoder` takes them."""
        if type(msg) is not self.msg_type:
            raise WireError("wrong_type", f"{self.pattern} carries {self.type_name}, got {type(msg).__name__}")
        return self.decoder(msg, bounds=bounds, agent=agent, episode=episode, step=step)


def replace_depth(qos: Qos, depth: int) -> Qos:
    return replace(qos, depth=depth)


def taking(decode: Callable[..., Any], *expects: str) -> Callable[..., Any]:
    """A TopicSpec's decoder: `decode` given only the expectations it takes (statistics have no step, world
    statistics and the heartbeat belong to no agent), as in codec.decode()."""
    return lambda msg, **given: decode(msg, **{k: given[k] for k in expects})


def _agent_id(agent: Any) -> int:
    if isinstance(agent, bool) or not isinstance(agent, int) or agent < 1:
        raise WireError("unknown_agent", f"agent id {agent!r}, must be an int >= 1")
    return agent


_NS = AGENT_PREFIX + "{agent}/"


def _lockstep(key: str, pattern: str, qos: Qos, payload: type, publisher: str, subscribers: str, fields: str,
              decoder: Callable[..., Any] | None = None) -> TopicSpec:
    """A topic of the lockstep: an array payload on its layout's ROS type, decoded by its layout (unless
    `decoder`), read READER_DEPTH deep."""
    layout = codec.LAYOUT_BY_PAYLOAD[payload]
    return TopicSpec(key, pattern, layout.ros_type, qos, payload, publisher, subscribers, fields, READER_DEPTH,
                     decoder=decoder or layout.decode)


FEEDBACK = _lockstep("feedback", _NS + "feedback", QOS_FEEDBACK, Feedback, "world",
                     "agent k (the JSA central node: every agent's)", "(float64; flags 0/1; applied -1: none)")
POSITION = _lockstep(
    "position", _NS + "position", QOS_POSITION, Position,
    "world (every agent, every step, before any feedback of that step; while a reader is matched, the newest "
    "on a match)",
    "peers of k while they need k (CQ: in a conflict state; JS: always; LoC: on COORDINATE); tools", "(int32)")
ACTION = _lockstep("action", _NS + "action", QOS_ACTION, Action, "agent k (the JSA central node: every agent's)",
                   "world", "(int32; action 0..3 = N, E, S, W)")
HEARTBEAT = _lockstep(
    "heartbeat", "world/heartbeat", QOS_HEARTBEAT, Heartbeat,
    "world, every heartbeat_period from its start, whether or not anyone acts",
    "agents (the world is alive; where it is, to catch up without a key); tools", "(int32)",
    decoder=taking(codec.decode_heartbeat))  # whatever a receiver expects: a heartbeat says where the world is
AGENT_STATS = TopicSpec(
    "agent_stats", _NS + "stats", DiagnosticArray, QOS_STATS, AgentStats,
    "agent k, once per episode (the JSA central node: every agent's)", "tools (echo, record, launcher)",
    "one DiagnosticStatus, name 'agv<k>/stats', values: KeyValue pairs (see below)",
    decoder=taking(codec.decode_agent_stats, "bounds", "agent", "episode"),
)
WORLD_STATS = TopicSpec(
    "world_stats", "world/stats", DiagnosticArray, QOS_STATS, WorldStats,
    "world, once per episode", "tools (echo, record, launcher)",
    "one DiagnosticStatus, name 'world/stats', values: KeyValue pairs (see below)",
    decoder=taking(codec.decode_world_stats, "bounds", "episode"),
)

TOPICS: tuple[TopicSpec, ...] = (FEEDBACK, POSITION, ACTION, HEARTBEAT, AGENT_STATS, WORLD_STATS)
WORLD_STATS_TOPIC = WORLD_STATS.pattern
HEARTBEAT_TOPIC = HEARTBEAT.pattern

# The per-agent names are asked for every message a node takes (as its drop counter's source): made once each.
_once = lru_cache(maxsize=None, typed=True)  # typed: True is no agent id, though it hashes as 1


@_once
def agent_namespace(agent: int) -> str:
    """'agv<k>': the relative namespace of agent k's topics (and a good node name for agent k)."""
    return f"{AGENT_PREFIX}{_agent_id(agent)}"


feedback_topic, position_topic = _once(FEEDBACK.name), _once(POSITION.name)
action_topic, agent_stats_topic = _once(ACTION.name), _once(AGENT_STATS.name)


def agent_topics(n_agents: int) -> list[tuple[str, TopicSpec, int | None]]:
    """Every topic of a system of `n_agents` agents, as (relative name, spec, agent or None)."""
    return [(spec.name(k), spec, k) for spec in TOPICS
            for k in (range(1, n_agents + 1) if spec.per_agent else (None,))]


@lru_cache(maxsize=None)
def _pattern_re(pattern: str) -> re.Pattern:
    """A topic pattern as a regex of its name, relative or under any namespace; agent ids from 1, no leading 0."""
    return re.compile("(?:^|/)" + re.escape(pattern).replace(r"\{agent\}", "(" + ID_DIGITS + ")") + "$")


def parse_name(name: str, specs: tuple[TopicSpec, ...], what: str) -> tuple[TopicSpec, int | None]:
    """(spec, agent) for a topic name of one of `specs`; ValueError for any other name."""
    for spec in specs:
        m = _pattern_re(spec.pattern).search(name)
        if m:
            return spec, int(m.group(1)) if spec.per_agent else None
    raise ValueError(f"{name!r} is not a {what}")


def parse_topic(name: str) -> tuple[TopicSpec, int | None]:
    """(spec, agent) for a project topic name, relative or fully qualified under any namespace
    ('/run7/agv2/position' -> (POSITION, 2)); ValueError for any other name."""
    return parse_name(name, TOPICS, "cq_ros topic")

"""Command-line tools that read the ROS graph through the wire contract: echo, topics, nodes, record.

Thin equivalents of `ros2 topic echo`, `ros2 topic list -t`, `ros2 node list` and `ros2 bag record` (none of
which is on pip), built on rclpy; `cq-ros echo|topics|nodes|record` calls them (cq_ros/cli/main.py). They work on
any topic of standard type; on a project topic (`parse_topic` knows it) echo also checks every message
against the contract and says on stderr when one breaks it, and record picks the project topics by default.
`read_view_bag` reads back what a viewer would have seen of a recorded run (`cq-ros render --bag`).

Every wait is bounded or ends on Ctrl-C/SIGTERM, and every tool runs in its own rclpy Context
(ros_tools/session.py). Failures raise `ToolError`, one line for the user.
"""

from __future__ import annotations

import importlib
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any, Callable, TextIO

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from msgs_spec import DropCounter, TopicSpec, WireError, parse_topic
from msgs_spec.spec_doc import to_yaml
from msgs_spec.viz import LOOKS, MAP, SCENE, parse_view_topic
from node_runtime.qos import profile

from .session import SETTLE_S, StopSignals, ToolError, environment_domain, ros_session, settle, spin_until

__all__ = [
    "DISCOVERY_S", "STORAGES", "compatible_qos", "message_class", "echo", "topics", "nodes", "record", "read_view_bag",
]

# A new process shows up in the graph 0.05-2.8 s after it starts (docs/design.md, field notes): how long echo
# waits for its topic to appear by default (it ends as soon as the topic is there).
DISCOVERY_S = 3.0
GRAPH_POLL_S = 0.25  # how often record looks for new topics, and echo for its topic
STORAGES = ("mcap", "sqlite3")
# Deep enough that a burst (an episode boundary, every topic of a step at once) never overwrites a message
# the recorder has not taken yet.
RECORD_DEPTH = 1000
LOOKS_MARGIN_NS = 1_000_000_000  # read_view_bag: how far outside an episode's scenes its looks are read


def compatible_qos(publishers: list[Any], fallback: QoSProfile, depth: int = 10) -> QoSProfile:
    """A subscription profile every publisher of a topic can serve, as `ros2 topic echo` chooses it: reliable
    if every publisher is, transient local if every publisher is (so latched topics deliver their history).
    Built fresh: a profile read from the graph has history UNKNOWN, which rclpy refuses (field notes).
    `fallback` decides while the topic has no publisher."""
    if not publishers:
        reliability, durability = fallback.reliability, fallback.durability
    else:
        profiles = [p.qos_profile for p in publishers]
        reliability = (ReliabilityPolicy.RELIABLE if all(q.reliability == ReliabilityPolicy.RELIABLE for q in profiles)
                       else ReliabilityPolicy.BEST_EFFORT)
        durability = (DurabilityPolicy.TRANSIENT_LOCAL
                      if all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in profiles)
                      else DurabilityPolicy.VOLATILE)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability, durability=durability)


def message_class(type_name: str) -> type:
    """The Python class of 'pkg/msg/Type'; ToolError if its package is not installed."""
    pkg, _, cls = type_name.partition("/msg/")
    try:
        return getattr(importlib.import_module(f"{pkg}.msg"), cls)
    except (ImportError, AttributeError, ValueError):
        raise ToolError(f"message type {type_name} is not installed here (no Python module {pkg}.msg.{cls})") from None


def _project_spec(name: str) -> tuple[TopicSpec, int | None] | None:
    """The spec of a project topic, the lockstep's or a viewer's (msgs_spec.viz), or None."""
    for parse in (parse_topic, parse_view_topic):
        try:
            return parse(name)
        except ValueError:
            pass
    return None


def _resolve(node: Any, topic: str) -> str:
    """`topic` as a full name (a relative one under the node's namespace); ValueError, one line naming it, when it
    is no topic name (rcl's reason, without its source location)."""
    from rclpy._rclpy_pybind11 import RCLError

    try:
        return node.resolve_topic_name(topic)
    except RCLError as e:
        reason = str(e).removeprefix("failed to resolve name: ").split(", at ")[0]
        raise ValueError(f"{topic!r} is not a topic name: {reason}") from None


def _namespace(given: str) -> str:
    """'/name' for `given` ('name' or '/name'); ValueError, one line, when it is no ROS namespace."""
    from rclpy.exceptions import InvalidNamespaceException
    from rclpy.validate_namespace import validate_namespace

    namespace = "/" + given.strip("/")
    try:
        validate_namespace(namespace)
    except InvalidNamespaceException as e:
        reason = str(e).splitlines()[0].removeprefix("Invalid namespace: ")
        raise ValueError(f"namespace {given!r} is not a ROS namespace: {reason}") from None
    return namespace


def _graph_types(node: Any, name: str) -> list[str]:
    return dict(node.get_topic_names_and_types()).get(name, [])


def _seconds(value: float) -> str:
    return f"{value:g} s"


# --------------------------------------------------------------------------------------------------------
# echo


def echo(topic: str, *, count: int | None = None, timeout_s: float | None = None, domain_id: int | None = None,
         out: TextIO = sys.stdout, err: TextIO = sys.stderr) -> int:
    """Print the messages of `topic` as `ros2 topic echo` does (YAML, then '---'); return the number printed.

    The type comes from the graph (waiting at most `timeout_s`, or DISCOVERY_S without a timeout); a project
    topic that is not in the graph yet is subscribed with the contract's type and QoS and waited for. Ends
    after `count` messages, at `timeout_s` (ToolError if nothing came) or on Ctrl-C/SIGTERM."""
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    with StopSignals() as stop, ros_session("cq_ros_echo", domain_id=domain_id) as (node, executor):
        name = _resolve(node, topic)
        project = _project_spec(name)
        wait = DISCOVERY_S if timeout_s is None else timeout_s
        spin_until(executor, lambda: bool(_graph_types(node, name)), wait, stop)
        types = _graph_types(node, name)
        if stop:
            return 0
        if types:
            msg_type = message_class(types[0])
        elif project is not None:
            msg_type = project[0].msg_type  # not up yet: the contract knows what it will carry
        else:
            raise ToolError(f"no topic {name} in the graph after {_seconds(wait)} (is the system running, on "
                            f"this ROS_DOMAIN_ID? `cq-ros topics` lists what is there)")
        spec, agent = project if project is not None else (None, None)
        if spec is not None and msg_type is not spec.msg_type:
            err.write(f"cq-ros echo: {name} carries {types[0]}, not the contract's {spec.type_name}: "
                      "echoing it unchecked\n")
            spec = None
        fallback = profile(spec.qos) if spec is not None else QoSProfile(depth=10)
        # Publishers seen a moment after the topic (a subscriber-only topic) still decide the QoS: wait briefly.
        spin_until(executor, lambda: bool(node.get_publishers_info_by_topic(name)),
                   min(GRAPH_POLL_S, wait), stop)
        qos = compatible_qos(node.get_publishers_info_by_topic(name), fallback)
        printed = 0

        def show(msg: Any) -> None:
            nonlocal printed
            if count is not None and printed >= count:
                return
            printed += 1
            if spec is not None:
                try:
                    spec.decode(msg, agent=agent)
                except WireError as e:
                    err.write(f"cq-ros echo: message {printed} on {name} breaks the contract: {e}\n")
            out.write(to_yaml(msg) + "---\n")
            out.flush()

        node.create_subscription(msg_type, name, show, qos)
        left = None if deadline is None else max(0.0, deadline - time.monotonic())
        spin_until(executor, lambda: count is not None and printed >= count, left, stop)
        if printed == 0 and not stop:
            raise ToolError(f"no message on {name} within {_seconds(timeout_s)}")
        return printed


# --------------------------------------------------------------------------------------------------------
# topics, nodes


def _look(wait_s: float | None, domain_id: int | None, what: Callable[[Any], list[str]]) -> list[str]:
    """Ask the graph once discovery has settled (session.settle: no change for QUIET_S), waiting at most `wait_s`
    (None: SETTLE_S; Ctrl-C cuts it short)."""
    with StopSignals() as stop, ros_session("cq_ros_graph", domain_id=domain_id) as (node, executor):
        settle(node, executor, stop, SETTLE_S if wait_s is None else wait_s)
        return what(node)


def topics(*, show_types: bool = False, wait_s: float | None = None, domain_id: int | None = None,
           out: TextIO = sys.stdout) -> list[str]:
    """Print the live topics, sorted, with their types as `ros2 topic list -t` does ('/a/b [pkg/msg/T]')."""
    lines = _look(wait_s, domain_id, lambda node: [
        f"{name} [{', '.join(types)}]" if show_types else name
        for name, types in sorted(node.get_topic_names_and_types())])
    out.write("".join(line + "\n" for line in lines))
    return lines


def nodes(*, all_nodes: bool = False, wait_s: float | None = None, domain_id: int | None = None,
          out: TextIO = sys.stdout) -> list[str]:
    """Print the live nodes' full names ('/namespace/name'), sorted; hidden ones ('_name') only with all_nodes."""
    lines = _look(wait_s, domain_id, lambda node: sorted(
        f"{ns.rstrip('/')}/{name}" for name, ns in node.get_node_names_and_namespaces()
        if all_nodes or not name.startswith("_")))
    out.write("".join(line + "\n" for line in lines))
    return lines


# --------------------------------------------------------------------------------------------------------
# record


def _bag_qos(profile: QoSProfile) -> Any:
    """rclpy's view of a publisher's QoS as rosbags' Qos, for the bag's offered_qos_profiles (what
    `ros2 bag play` republishes with: a latched topic replays latched)."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    def span(duration: Any) -> QosTime:
        return QosTime(*divmod(duration.nanoseconds, 10**9))

    return Qos(history=QosHistory[profile.history.name], depth=profile.depth,
               reliability=QosReliability[profile.reliability.name],
               durability=QosDurability[profile.durability.name], deadline=span(profile.deadline),
               lifespan=span(profile.lifespan), liveliness=QosLiveliness[profile.liveliness.name],
               liveliness_lease_duration=span(profile.liveliness_lease_duration),
               avoid_ros_namespace_conventions=profile.avoid_ros_namespace_conventions)


def record(bag: str | os.PathLike, *, topics: list[str] | None = None, duration_s: float | None = None,
           count: int | None = None, storage: str = "mcap", domain_id: int | None = None,
           namespace: str | None = None, out: TextIO = sys.stdout, err: TextIO = sys.stderr) -> int:
    """Record to a new rosbag2 directory `bag`; return the number of messages written.

    `topics` None: every project topic (`parse_topic`) under `namespace` (None: under any), found as they
    appear; else these names (relative names resolve against `namespace`, else '/'). Messages are written as
    they came off the wire (raw CDR, never decoded), stamped with their receive time, with each topic's type,
    definition, type hash and the publishers' offered QoS, so `ros2 bag play` replays it. Ends after
    `duration_s`, after `count` messages, or on Ctrl-C/SIGTERM (with neither limit, only then); the bag is
    closed properly in every case."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    if storage not in STORAGES:
        raise ToolError(f"unknown storage {storage!r}; choose from {', '.join(STORAGES)}")
    bag = Path(bag)
    if bag.exists():
        raise FileExistsError(f"{bag} exists; a bag is a new directory: choose another --out")
    typestore = get_typestore(Stores.ROS2_JAZZY)
    writer = Writer(bag, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin[storage.upper()])
    deadline = None if duration_s is None else time.monotonic() + duration_s
    written = 0
    skipped: set[str] = set()
    subscriptions = []

    namespace = None if namespace is None else _namespace(namespace)
    with StopSignals() as stop, ros_session("cq_ros_record", domain_id=domain_id, namespace=namespace) as (
            node, executor):
        wanted = None if topics is None else {_resolve(node, t) for t in topics}
        connections: dict[str, Any] = {}

        def selected(name: str) -> bool:
            if wanted is not None:
                return name in wanted
            return _project_spec(name) is not None and (namespace is None or name.startswith(f"{namespace}/"))

        def write(connection: Any, data: bytes) -> None:
            nonlocal written
            if count is None or written < count:
                writer.write(connection, time.time_ns(), data)
                written += 1

        def subscribe_new_topics() -> None:
            for name, types in node.get_topic_names_and_types():
                if name in connections or name in skipped or not selected(name):
                    continue
                publishers = node.get_publishers_info_by_topic(name)
                if not publishers:
                    continue  # only subscribers so far: no type hash or QoS to store yet, nothing to record
                type_name = types[0]
                if type_name not in typestore.fielddefs:
                    skipped.add(name)
                    err.write(f"cq-ros record: skipping {name}: type {type_name} is not in rosbags' ROS 2 "
                              "Jazzy type store\n")
                    continue
                connections[name] = connection = writer.add_connection(
                    name, type_name, typestore=typestore,
                    offered_qos_profiles=[_bag_qos(p.qos_profile) for p in publishers])
                subscriptions.append(node.create_subscription(
                    message_class(type_name), name, lambda data, c=connection: write(c, data),
                    compatible_qos(publishers, QoSProfile(depth=RECORD_DEPTH), depth=RECORD_DEPTH), raw=True))

        writer.open()
        try:
            next_look = 0.0
            while not stop and (count is None or written < count):
                now = time.monotonic()
                if deadline is not None and now >= deadline:
                    break
                if now >= next_look:
                    subscribe_new_topics()
                    next_look = now + GRAPH_POLL_S
                executor.spin_once(timeout_sec=0.05)
        finally:
            for sub in subscriptions:  # no callback may write once the bag is closed
                node.destroy_subscription(sub)
            writer.close()
    missing = sorted(wanted - connections.keys() - skipped) if wanted is not None else []
    if not written:  # an empty bag would only be blamed later (`render --bag` finds no map in it)
        shutil.rmtree(bag, ignore_errors=True)
        domain = domain_id if domain_id is not None else environment_domain() or 0
        on = f" on {', '.join(missing)}" if missing else ""
        raise ToolError(f"heard no message{on} on ROS_DOMAIN_ID {domain}, so no bag was written: is a system "
                        f"running there? (`cq-ros topics --domain-id {domain}` lists what is)")
    if missing:
        err.write(f"cq-ros record: never saw a publisher on {', '.join(missing)}\n")
    out.write(f"recorded {written} messages on {len(connections)} topics to {bag} ({storage})\n")
    return written


def read_view_bag(bag: str | os.PathLike, *, episode_of: Callable[[list[Any]], int] | None = None,
                  err: TextIO = sys.stderr) -> tuple[Any, list[Any], list[Any]]:
    """What a viewer would have seen of a recorded run: (the map's Occupancy or None, every Scene and every
    Looks, in the bag's order), decoded through the contract from the bag's world/map, world/markers and
    agv<k>/looks topics (under any namespace). With `episode_of` (the scenes -> the episode to draw), only that
    episode's looks are decoded: the looks are most of a bag's view messages and of the time to read it. A
    message that breaks the contract is skipped and counted on `err`; ToolError if the bag cannot be read."""
    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Reader

    occupancy, scenes, looks, stamps = None, [], [], []
    drops = DropCounter(lambda line: err.write(f"cq-ros render: {line}\n"))
    try:
        reader = Reader(Path(bag))
        reader.open()
    except Exception as e:  # rosbags raises its own errors for a missing or broken bag
        raise ToolError(f"cannot read the bag {bag}: {e}") from None

    def read(specs: tuple[TopicSpec, ...], start: int | None = None, stop: int | None = None) -> None:
        nonlocal occupancy
        wanted = [c for c in reader.connections if (_project_spec(c.topic) or (None,))[0] in specs]
        for connection, stamp, raw in reader.messages(connections=wanted, start=start, stop=stop):
            spec, agent = _project_spec(connection.topic)
            payload = drops.guard(spec.decode, deserialize_message(raw, spec.msg_type), agent=agent,
                                  source=connection.topic)
            if payload is None:
                continue
            if spec is MAP:
                occupancy = payload
            elif spec is SCENE:
                scenes.append(payload)
                stamps.append(stamp)
            else:
                looks.append(payload)

    try:
        if episode_of is None:
            read((MAP, SCENE, LOOKS))
        else:
            read((MAP, SCENE))
            if scenes:
                # from the episode's first scene to the next episode's, a second of the recorder's receive
                # order either side: frames_from keeps only the looks stamped with one of its steps
                episode = episode_of(scenes)
                mine = [k for k, scene in enumerate(scenes) if scene.episode == episode]
                if mine:
                    after = mine[-1] + 1
                    read((LOOKS,), stamps[mine[0]] - LOOKS_MARGIN_NS,
                         stamps[after] + LOOKS_MARGIN_NS if after < len(stamps) else None)
    finally:
        reader.close()
    return occupancy, scenes, looks

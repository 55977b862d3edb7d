"""`cq-ros view`: a live view of a running system in Foxglove, without RViz or foxglove_bridge (a C++ package pip
does not have): a Foxglove WebSocket server (foxglove-sdk, the optional extra `view`) relaying every topic of the
system as it is on the wire.

Each topic under the system's namespace is subscribed raw (the CDR bytes, no decoding) with a profile its
publishers can serve, and each message is logged unchanged on a Foxglove channel of the same name, encoding
`cdr`, with its `ros2msg` schema (the message definition rosbags generates), so Foxglove decodes it as it
would a ROS 2 bridge's. A latched topic (the map's OccupancyGrid, the positions) reaches a client that
subscribes late only if its last sample is sent again: the relay keeps it and logs it again when a client
subscribes. New topics (an agent's looks, once it publishes) are picked up every RESCAN_S. Open
docs/foxglove/layout.json in Foxglove (Layouts, Import) for a 3D panel on frame `map` with the grid and the
markers and a plot of collisions per episode.
"""

from __future__ import annotations

import functools
import sys
import threading
import time
from typing import Any

from rclpy.qos import DurabilityPolicy, QoSProfile

from node_runtime.qos import profile

from .commands import compatible_qos, message_class
from .session import StopSignals, ToolError, find_system, ros_session, spin_until

__all__ = ["RESCAN_S", "Relay", "serve", "view", "schema_text"]

RESCAN_S = 1.0  # how often the graph is looked at again for topics that appeared


def schema_text(type_name: str) -> bytes:
    """The `ros2msg` schema of ROS type 'pkg/msg/Type': its definition with every nested one, as rosbag2 and
    Foxglove read it."""
    text, _ = _jazzy_types().generate_msgdef(type_name)
    return text.encode()


@functools.cache
def _jazzy_types() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


class Relay:
    """Every topic of namespace `ns` seen by `node`, relayed onto Foxglove channels (see the module docstring)."""

    def __init__(self, node: Any, ns: str):
        import foxglove

        self.foxglove = foxglove
        self.node, self.prefix = node, ns.rstrip("/") + "/"
        self.channels: dict[str, Any] = {}
        self.latched: dict[str, bytes] = {}  # topic -> last sample of a transient-local topic
        self.resend: set[str] = set()  # latched topics a client subscribed to since the last spin
        self.lock = threading.Lock()  # on_subscribe runs on the server's thread
        self.subscriptions: list[Any] = []
        self.relayed = 0

    def on_subscribe(self, client: Any, channel: Any) -> None:
        with self.lock:
            self.resend.add(channel.topic)

    def rescan(self) -> None:
        """Subscribe to every topic of the namespace on the graph not relayed yet."""
        for topic, types in self.node.get_topic_names_and_types():
            if not topic.startswith(self.prefix) or topic in self.channels or len(types) != 1:
                continue
            publishers = self.node.get_publishers_info_by_topic(topic)
            if publishers:
                self.add(topic, types[0], compatible_qos(publishers, QoSProfile(depth=10)))

    def add_system(self, n_agents: int) -> None:
        """Subscribe to every topic of a system of `n_agents` by the contract (msgs_spec), as a launch knows them:
        a launcher's node sees on the graph only the topics it matches."""
        from msgs_spec import TOPICS
        from msgs_spec.viz import VIEW_TOPICS

        for spec in (*TOPICS, *VIEW_TOPICS):
            for agent in (range(1, n_agents + 1) if spec.per_agent else [None]):
                topic = self.prefix + spec.name(agent)
                if topic not in self.channels:
                    self.add(topic, spec.type_name, compatible_qos([], profile(spec.qos)))

    def add(self, topic: str, type_name: str, qos: QoSProfile) -> None:
        """Relay `topic` (of ROS type `type_name`), subscribed with `qos`; a type we cannot describe is skipped."""
        try:
            msg_type = message_class(type_name)
            schema = self.foxglove.Schema(name=type_name, encoding="ros2msg", data=schema_text(type_name))
        except (ToolError, KeyError, ValueError):
            return
        self.channels[topic] = self.foxglove.Channel(topic, schema=schema, message_encoding="cdr")
        latched = qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
        self.subscriptions.append(self.node.create_subscription(
            msg_type, topic, lambda raw, t=topic, keep=latched: self._relay(t, raw, keep), qos, raw=True))

    def _relay(self, topic: str, raw: bytes, keep: bool) -> None:
        if keep:
            self.latched[topic] = raw
        self.channels[topic].log(raw, log_time=time.time_ns())
        self.relayed += 1

    def send_latched(self) -> None:
        """The last sample of each latched topic a client subscribed to since the last call, again."""
        with self.lock:
            topics, self.resend = self.resend, set()
        for topic in topics:
            if topic in self.latched:
                self.channels[topic].log(self.latched[topic], log_time=time.time_ns())


def serve(node: Any, ns: str, host: str = "127.0.0.1", port: int = 8765,
          n_agents: int | None = None) -> tuple[Any, Relay]:
    """A Foxglove server at host:port relaying namespace `ns` through `node`, rescanned on a timer of `node` (so
    whoever spins it, `cq-ros view` or a launch's listener, relays); with `n_agents`, every topic of such a
    system by the contract as well. Stop it with server.stop()."""
    try:
        import foxglove
    except ImportError:
        raise ToolError("the view needs foxglove-sdk: pip install '.[view]'") from None
    relay = Relay(node, ns)

    class Listener(foxglove.ServerListener):
        def on_subscribe(self, client: Any, channel: Any) -> None:
            relay.on_subscribe(client, channel)

    # The SDK's server negotiates only its own subprotocols (foxglove.sdk.v1, foxglove.sdk.v1.1) and has no option
    # for the older foxglove.websocket.v1: a client offering only that gets HTTP 400 (docs/ros.md, which clients).
    try:
        server = foxglove.start_server(name=f"cq_ros {ns}", host=host, port=port, server_listener=Listener())
    except Exception as e:  # the SDK raises its own error for a port in use
        raise ToolError(f"cannot serve on {host}:{port}: {e}") from None
    if n_agents is not None:
        relay.add_system(n_agents)
    relay.rescan()
    node.create_timer(RESCAN_S, relay.rescan)
    node.create_timer(0.1, relay.send_latched)
    return server, relay


def view(*, domain_id: int | None = None, namespace: str | None = None, host: str = "127.0.0.1", port: int = 8765,
         wait_s: float = 60.0, duration_s: float | None = None) -> int:
    """Serve the system on the domain (its namespace found as cq-ros collect finds it, unless given) to Foxglove
    at ws://host:port until Ctrl-C (or `duration_s`); the number of messages relayed."""
    namespace = None if namespace is None else "/" + namespace.strip("/")
    with StopSignals() as stop, ros_session("view", domain_id=domain_id) as (node, executor):
        print(f"cq-ros view: looking for a system on {f'namespace {namespace}' if namespace else 'the domain'} "
              f"(at most {wait_s:g} s)", file=sys.stderr, flush=True)
        ns, _agents = find_system(node, executor, namespace, stop, wait_s)
        server, relay = serve(node, ns, host, port)
        try:
            print(f"cq-ros view: relaying {ns} on ws://{host}:{server.port} (open it in Foxglove; Ctrl-C stops)",
                  file=sys.stderr, flush=True)
            spin_until(executor, lambda: False, duration_s, stop)
        finally:
            server.stop()
    return relay.relayed

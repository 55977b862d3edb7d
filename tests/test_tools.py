"""The ROS tools on the `cq-ros` command, run as processes against a live publisher in this process:
echo prints what `ros2 topic echo` would (and flags contract violations), topics and nodes list the live
graph, record writes a rosbag2 that rosbags reads back with the right types, QoS and messages."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass, field

import pytest
import rclpy
import yaml
from rclpy.executors import SingleThreadedExecutor

from msgs_spec import (
    POSITION, WORLD_STATS, WORLD_STATS_TOPIC, Position, WorldStats, decode_position, decode_world_stats, encode,
    position_topic,
)
from node_runtime.qos import profile
from msgs_spec.spec_doc import to_yaml
from helpers import alive_with, wait_until

TOOL_TIMEOUT_S = 60.0  # bound on any one tool process; each takes a few seconds
PERIOD_S = 0.05  # the talker publishes every 50 ms


@dataclass
class Talker:
    namespace: str  # '/tools_<hex>', unique to the test
    publishers: tuple = ()  # the talker's, for a test to see what a subscriber has been sent
    ticks: list = field(default_factory=lambda: [0])  # [ticks published so far], counted by the talker's thread

    def topic(self, relative: str) -> str:
        return f"{self.namespace}/{relative}"

    def heard(self, timeout_s: float) -> bool:
        """Wait (bounded) until every topic has a subscriber that has acknowledged two ticks published after
        it matched: a recorder started beside the talker has then recorded every topic."""
        from rclpy.duration import Duration

        deadline = time.monotonic() + timeout_s
        if not wait_until(lambda: all(p.get_subscription_count() for p in self.publishers), timeout_s, "matched",
                          fail=False):
            return False
        matched_at = self.ticks[0]
        if not wait_until(lambda: self.ticks[0] >= matched_at + 2, deadline - time.monotonic(), "ticks", fail=False):
            return False
        left = max(0.0, deadline - time.monotonic())
        return all(p.wait_for_all_acked(Duration(seconds=left)) for p in self.publishers)


@pytest.fixture
def talker(ros_context):
    """A node `talker` in a namespace of the test's own, publishing from a thread every PERIOD_S: agv2's
    latched position (agent 2, episode 0, step i, cell (1, 3)), a WorldStats for episode i, and on
    agv1/position a position that breaks the contract (it claims to be agent 2's)."""
    namespace = f"/tools_{uuid.uuid4().hex[:8]}"
    node = rclpy.create_node("talker", namespace=namespace, context=ros_context)
    position = node.create_publisher(POSITION.msg_type, position_topic(2), profile(POSITION.qos))
    wrong = node.create_publisher(POSITION.msg_type, position_topic(1), profile(POSITION.qos))
    stats = node.create_publisher(WORLD_STATS.msg_type, WORLD_STATS_TOPIC, profile(WORLD_STATS.qos))
    talker = Talker(namespace, (position, wrong, stats))

    def tick() -> None:
        step = talker.ticks[0]
        position.publish(encode(Position(agent=2, episode=0, step=step, row=1, col=3)))
        wrong.publish(encode(Position(agent=2, episode=0, step=step, row=1, col=3)))
        stats.publish(encode(WorldStats(episode=step, steps=5, truncated=False, collisions=1, missed_actions=0,
                                        returns=(-1.0, 2.5))))
        talker.ticks[0] = step + 1

    node.create_timer(PERIOD_S, tick)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)

    thread = threading.Thread(target=spin)
    thread.start()
    try:
        yield talker
    finally:
        # Jazzy order (docs/design.md, field notes): the spinning thread, the executor, the node; the fixture
        # ros_context shuts the context down after.
        stop.set()
        thread.join(timeout=5)
        executor.shutdown()
        node.destroy_node()
    assert not alive_with(namespace), "a tool process outlived its test"


def cq_ros(*args: str, timeout: float = TOOL_TIMEOUT_S) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cq_ros.cli", *args], capture_output=True, text=True,
                          timeout=timeout)


def test_echo_prints_the_latched_position_as_ros2_topic_echo_does_and_stops_after_count(talker):
    done = cq_ros("echo", talker.topic("agv2/position"), "--count", "3", "--timeout", "20")
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""
    docs = done.stdout.split("---\n")
    assert docs[-1] == "" and len(docs) == 4  # three messages, each followed by '---'
    steps = []
    for doc in docs[:3]:
        step = yaml.safe_load(doc)["data"][2]
        assert doc == to_yaml(encode(Position(agent=2, episode=0, step=step, row=1, col=3)))
        steps.append(step)
    assert steps == sorted(steps) and len(set(steps)) == 3


def test_echo_says_on_stderr_when_a_message_breaks_the_contract(talker):
    done = cq_ros("echo", talker.topic("agv1/position"), "--count", "1", "--timeout", "20")
    assert done.returncode == 0
    assert "agent,episode,step,row,col" in done.stdout
    assert f"message 1 on {talker.topic('agv1/position')} breaks the contract: wrong_agent" in done.stderr


def test_echo_of_statistics_prints_the_key_value_pairs(talker):
    done = cq_ros("echo", talker.topic("world/stats"), "--count", "1", "--timeout", "20")
    assert done.returncode == 0 and done.stderr == ""
    status = yaml.safe_load(done.stdout.split("---\n")[0])["status"][0]
    values = {kv["key"]: kv["value"] for kv in status["values"]}
    assert status["name"] == "world/stats" and values["collisions"] == "1" and values["return.agv2"] == "2.5"


@pytest.mark.parametrize("relative, message", [
    ("agv9/position", "no message on {topic} within 1.5 s"),  # a project topic: waited for, with its type
    ("chatter", "no topic {topic} in the graph after 1.5 s"),
])
def test_echo_without_a_message_exits_1_with_one_line(talker, relative, message):
    topic = talker.topic(relative)
    done = cq_ros("echo", topic, "--timeout", "1.5")
    assert done.returncode == 1 and done.stdout == ""
    assert done.stderr.strip() == f"cq-ros echo: error: {message.format(topic=topic)}" + (
        " (is the system running, on this ROS_DOMAIN_ID? `cq-ros topics` lists what is there)"
        if relative == "chatter" else "")


def test_topics_and_nodes_list_the_live_graph(talker):
    topics = cq_ros("topics", "-t", "--wait", "4")
    assert topics.returncode == 0, topics.stderr
    lines = topics.stdout.splitlines()
    assert f"{talker.topic('agv2/position')} [std_msgs/msg/Int32MultiArray]" in lines
    assert f"{talker.topic('world/stats')} [diagnostic_msgs/msg/DiagnosticArray]" in lines
    assert lines == sorted(lines)
    names = cq_ros("topics", "--wait", "4").stdout.splitlines()
    assert talker.topic("agv2/position") in names and "[" not in "".join(names)

    nodes = cq_ros("nodes", "--wait", "4")
    assert nodes.returncode == 0, nodes.stderr
    assert talker.topic("talker") in nodes.stdout.splitlines()
    assert "/_cq_ros" not in nodes.stdout  # the tool's own node is hidden


def test_topics_waits_for_discovery_to_settle_and_lists_topics_that_come_one_after_another(ros_context):
    """Topics that appear one every 0.3 s for 4.5 s after the tool has joined the graph, as a launch's nodes
    come up one after another: every one is listed (a fixed 3 s listed 9 of a fresh launch's 16 topics), and
    the tool ends once the graph is quiet, well before its bound."""
    namespace = f"/settle_{uuid.uuid4().hex[:8]}"
    node = rclpy.create_node("late", namespace=namespace, context=ros_context)
    tool = subprocess.Popen([sys.executable, "-m", "cq_ros.cli", "topics", "--wait", "40"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        def joined() -> bool:  # the tool's own (hidden) node, once it has begun looking
            return any(name.startswith(f"_cq_ros_graph_{tool.pid}") for name, _ in node.get_node_names_and_namespaces())

        wait_until(joined, TOOL_TIMEOUT_S, "the tool's node in the graph", ended=lambda: tool.poll() is not None)
        started = time.monotonic()
        made = []
        for i in range(15):
            made.append(node.create_publisher(POSITION.msg_type, f"late_{i}", profile(POSITION.qos)))
            time.sleep(0.3)  # the pace at which topics come: the stimulus, not a wait for anything
        out, err = tool.communicate(timeout=TOOL_TIMEOUT_S)
        took = time.monotonic() - started
    finally:
        if tool.poll() is None:
            tool.kill()
            tool.wait()
        node.destroy_node()
    assert tool.returncode == 0, err
    listed = out.splitlines()
    assert [f"{namespace}/late_{i}" for i in range(15) if f"{namespace}/late_{i}" not in listed] == []
    assert took < 30, took  # settled, not the 40 s bound


def _read_bag(path):
    """{topic: (type, offered QoS profiles, [raw messages])} through rosbags' reader."""
    from rosbags.rosbag2 import Reader

    with Reader(path) as reader:
        out = {c.topic: (c.msgtype, c.ext.offered_qos_profiles, []) for c in reader.connections}
        for connection, _stamp, raw in reader.messages():
            out[connection.topic][2].append(raw)
    return out


def record_until_heard(talker: Talker, *args: str) -> subprocess.CompletedProcess:
    """`cq-ros record ARGS` stopped (Ctrl-C) once it has heard every topic of the talker, however long that took."""
    recorder = subprocess.Popen([sys.executable, "-m", "cq_ros.cli", "record", *args, "--duration",
                                 str(TOOL_TIMEOUT_S)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert talker.heard(TOOL_TIMEOUT_S), "the recorder never subscribed to every topic"
        recorder.send_signal(signal.SIGINT)
        stdout, stderr = recorder.communicate(timeout=TOOL_TIMEOUT_S)
    finally:
        if recorder.poll() is None:
            recorder.kill()
            recorder.wait()
    return subprocess.CompletedProcess(recorder.args, recorder.returncode, stdout, stderr)


@pytest.mark.parametrize("storage, explicit", [("mcap", True), ("sqlite3", False)])
def test_record_writes_a_bag_that_rosbags_reads_back(talker, tmp_path, storage, explicit):
    from rclpy.serialization import deserialize_message
    from rosbags.interfaces import QosDurability
    from rosbags.typesys import Stores, get_typestore

    bag = tmp_path / "bag"
    position, stats = talker.topic("agv2/position"), talker.topic("world/stats")
    if explicit:
        done = cq_ros("record", "--out", str(bag), "--storage", storage, "--topics", position, stats, "--count", "30",
                      "--duration", str(TOOL_TIMEOUT_S / 2))
    else:
        done = record_until_heard(talker, "--out", str(bag), "--storage", storage)
    assert done.returncode == 0, done.stderr
    recorded = _read_bag(bag)
    if explicit:
        assert set(recorded) == {position, stats}
        assert sum(len(m) for _, _, m in recorded.values()) == 30
        assert f"recorded 30 messages on 2 topics to {bag} ({storage})" in done.stdout
    else:  # every project topic there is (the recorder stores, it does not judge: agv1's bad one too)
        assert {position, stats, talker.topic("agv1/position")} <= set(recorded)

    typestore = get_typestore(Stores.ROS2_JAZZY)
    msgtype, qos, raw = recorded[position]
    assert msgtype == "std_msgs/msg/Int32MultiArray" and raw
    assert qos[0].durability == QosDurability.TRANSIENT_LOCAL  # replays latched, as published
    steps = []
    for data in raw:
        assert list(typestore.deserialize_cdr(data, msgtype).data)[:2] == [2, 0]
        pos = decode_position(deserialize_message(data, POSITION.msg_type), agent=2)
        assert (pos.row, pos.col) == (1, 3)
        steps.append(pos.step)
    assert steps == sorted(steps)

    msgtype, qos, raw = recorded[stats]
    assert msgtype == "diagnostic_msgs/msg/DiagnosticArray" and raw
    assert typestore.deserialize_cdr(raw[0], msgtype).status[0].name == "world/stats"
    assert decode_world_stats(deserialize_message(raw[0], WORLD_STATS.msg_type)).returns == (-1.0, 2.5)


def test_record_refuses_an_existing_output(tmp_path):
    done = cq_ros("record", "--out", str(tmp_path), "--duration", "1")
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1
    assert "exists" in done.stderr


def test_record_that_heard_nothing_exits_1_with_one_line_and_leaves_no_bag(tmp_path):
    bag, topic = tmp_path / "bag", f"/nobody_{uuid.uuid4().hex[:8]}/world/heartbeat"
    done = cq_ros("record", "--out", str(bag), "--topics", topic, "--duration", "2")
    assert done.returncode == 1, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and f"heard no message on {topic}" in lines[0], done.stderr
    assert not bag.exists() and "recorded" not in done.stdout


@pytest.mark.ros
@pytest.mark.parametrize("tool", ["echo", "record"])
def test_a_name_that_is_no_topic_is_one_line_naming_it_and_exit_2(tool, tmp_path):
    args = ["echo", "not a topic"] if tool == "echo" else ["record", "--out", str(tmp_path / "bag"), "--topics",
                                                           "not a topic", "--duration", "1"]
    done = cq_ros(*args)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.strip().splitlines() == [
        f"cq-ros {tool}: error: 'not a topic' is not a topic name: topic name must not contain characters other "
        "than alphanumerics, '_', '~', '{', or '}'"]
    assert not (tmp_path / "bag").exists()


def test_record_with_a_namespace_records_that_systems_topics_and_resolves_relative_ones_there(talker, ros_context,
                                                                                             tmp_path):
    # Another system's project topic on the same domain, latched: a recorder of every namespace would get it.
    other = rclpy.create_node("other", namespace=f"/other_{uuid.uuid4().hex[:8]}", context=ros_context)
    try:
        other.create_publisher(POSITION.msg_type, position_topic(1), profile(POSITION.qos)).publish(
            encode(Position(agent=1, episode=0, step=0, row=0, col=0)))
        namespace = talker.namespace.removeprefix("/")
        every = record_until_heard(talker, "--out", str(tmp_path / "every"), "--namespace", namespace)
        relative = cq_ros("record", "--out", str(tmp_path / "one"), "--namespace", f"/{namespace}", "--topics",
                          "agv2/position", "--count", "5", "--duration", str(TOOL_TIMEOUT_S / 2))
    finally:
        other.destroy_node()
    assert every.returncode == 0, every.stderr
    assert set(_read_bag(tmp_path / "every")) == {talker.topic(t) for t in ("agv1/position", "agv2/position",
                                                                            "world/stats")}
    assert relative.returncode == 0, relative.stderr
    assert set(_read_bag(tmp_path / "one")) == {talker.topic("agv2/position")}


def test_record_refuses_a_namespace_that_is_no_ros_name_in_one_line(tmp_path):
    done = cq_ros("record", "--out", str(tmp_path / "bag"), "--namespace", "9lives", "--duration", "1")
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1
    assert "namespace '9lives' is not a ROS namespace" in done.stderr and not (tmp_path / "bag").exists()

"""`cq-ros view` (ros_tools.view): a Foxglove WebSocket server relaying a system's topics. A client of the test's
own speaking the Foxglove WebSocket protocol (the `websockets` package) finds the map's OccupancyGrid and the
MarkerArray advertised with their ros2msg schemas, and decodes what it receives back into ROS messages; the
latched map, published once before the client came, is sent again when it subscribes. Each subprotocol a
current client offers is tried; the one older clients offer alone is refused (docs/ros.md says so)."""

from __future__ import annotations

import json
import signal
import socket
import struct
import subprocess
import sys
import threading
import uuid

import pytest
import rclpy

pytest.importorskip("foxglove", reason="the `view` extra (make test installs it)")
from websockets.sync.client import connect  # noqa: E402

from nav_msgs.msg import OccupancyGrid  # noqa: E402
from rclpy.serialization import deserialize_message  # noqa: E402
from visualization_msgs.msg import MarkerArray  # noqa: E402

from cq_ros.gridmap import load_map  # noqa: E402
from cq_ros.gridmap import lattice  # noqa: E402
from msgs_spec.viz import MAP, MAP_TOPIC, SCENE, SCENE_TOPIC, Occupancy, Scene  # noqa: E402
from node_runtime.qos import profile  # noqa: E402
from helpers import launch_command, unique, wait_for_line, wait_until  # noqa: E402

START_S = 90.0  # bound on the view process starting and finding the system on 2 busy cores
RECV_S = 30.0

# The Sec-WebSocket-Protocol offers of Foxglove clients and the subprotocol foxglove-sdk's server picks from each. The
# server (0.30.3) knows only its own names, sdk.v1 and sdk.v1.1 (whose advertise sends each schema once, by id), picks
# one of them whatever the client's order, and has no option to add another name.
ACCEPTED_OFFERS = {
    ("foxglove.websocket.v1", "foxglove.sdk.v1"): "foxglove.sdk.v1",  # Lichtblick 1.22 and later, in its order
    ("foxglove.sdk.v1",): "foxglove.sdk.v1",
    ("foxglove.sdk.v1.1",): "foxglove.sdk.v1.1",
}
# Foxglove Studio, older Foxglove app releases and Lichtblick before 1.22 offer only the ws-protocol's name: the server
# answers HTTP 400. Pinned, so that a foxglove-sdk which accepts it shows up here and docs/ros.md can say so.
REFUSED_OFFER = ("foxglove.websocket.v1",)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def relayed(port: int, wanted: dict[str, type], timeout_s: float = RECV_S,
            offer: tuple[str, ...] = ("foxglove.sdk.v1",)) -> dict[str, object]:
    """Connect to the Foxglove server at `port` as a Foxglove client does, offering the subprotocols `offer`, and
    check the server picks the one ACCEPTED_OFFERS says; subscribe to the `wanted` topics (topic -> ROS type) once
    advertised, each with its ros2msg schema and cdr encoding, and return the first message of each, deserialized
    (each wait bounded by timeout_s)."""
    with connect(f"ws://127.0.0.1:{port}", subprotocols=list(offer), open_timeout=timeout_s) as ws:
        assert ws.subprotocol == ACCEPTED_OFFERS[offer]
        channels: dict[int, dict] = {}
        schemas: dict[int, dict] = {}  # sdk.v1.1 advertises each schema once, by id; sdk.v1 inlines it in the channel

        def advertised() -> bool:  # every wanted topic, or else the next frame read
            if {c["topic"] for c in channels.values()} >= set(wanted):
                return True
            frame = ws.recv(timeout=timeout_s)
            if isinstance(frame, str) and json.loads(frame)["op"] == "advertise":
                advertisement = json.loads(frame)
                schemas.update({sc["id"]: sc for sc in advertisement.get("schemas", [])})
                for c in advertisement["channels"]:
                    if "schemaId" in c:
                        schema = schemas[c["schemaId"]]
                        c |= {"schemaName": schema["name"], "schemaEncoding": schema["encoding"]}
                    channels[c["id"]] = c
            return False

        wait_until(advertised, timeout_s, "not every wanted topic advertised", poll_s=0,
                   detail=lambda: f"advertised only {channels}")
        ours = {cid: c for cid, c in channels.items() if c["topic"] in wanted}
        for c in ours.values():
            assert c["encoding"] == "cdr" and c["schemaEncoding"] == "ros2msg"
            assert c["schemaName"] == {OccupancyGrid: "nav_msgs/msg/OccupancyGrid",
                                       MarkerArray: "visualization_msgs/msg/MarkerArray"}[wanted[c["topic"]]]
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": i, "channelId": cid}
                                                                for i, cid in enumerate(ours)]}))
        topic_of = {i: ours[cid]["topic"] for i, cid in enumerate(ours)}
        got: dict[str, object] = {}

        def received() -> bool:  # a message of every wanted topic, or else the next frame read
            if set(got) >= set(wanted):
                return True
            frame = ws.recv(timeout=timeout_s)
            if isinstance(frame, bytes) and frame[0] == 0x01:  # message data: subscription id, log time, payload
                subscription, _log_time = struct.unpack_from("<IQ", frame, 1)
                topic = topic_of[subscription]
                got[topic] = deserialize_message(frame[13:], wanted[topic])
            return False

        wait_until(received, timeout_s, "not a message of every wanted topic", poll_s=0,
                   detail=lambda: f"received only {list(got)}")
    return got


def test_view_relays_the_map_and_the_markers_to_a_foxglove_client(ros_context, ros_domain_id, tmp_path):
    from rclpy.executors import SingleThreadedExecutor

    gridmap = load_map("grid_game_2")
    ns = f"view_{uuid.uuid4().hex[:6]}"
    world = rclpy.create_node("world", namespace=ns, context=ros_context)  # the system's world, as the relay finds it
    map_pub = world.create_publisher(MAP.msg_type, MAP_TOPIC, profile(MAP.qos))
    map_pub.publish(MAP.encode(Occupancy(lattice(gridmap)), stamp=world.get_clock().now().to_msg()))
    scene_pub = world.create_publisher(SCENE.msg_type, SCENE_TOPIC, profile(SCENE.qos))
    goals = tuple(gridmap.cells[g] for g in gridmap.goals)
    starts = tuple(gridmap.cells[s] for s in gridmap.starts)
    world.create_timer(0.2, lambda: scene_pub.publish(SCENE.encode(Scene(0, 0, starts, goals),
                                                                   stamp=world.get_clock().now().to_msg())))
    agent = rclpy.create_node("agv1", namespace=ns, context=ros_context)  # a system is a world and its agents
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(world)
    stopping = threading.Event()

    def spin() -> None:
        while not stopping.is_set():
            executor.spin_once(timeout_sec=0.05)

    spinner = threading.Thread(target=spin)
    spinner.start()

    port = free_port()
    err = tmp_path / "view.stderr"
    with open(err, "wb") as f:
        viewer = subprocess.Popen([sys.executable, "-m", "cq_ros.cli", "view", "--domain-id", str(ros_domain_id),
                                   "--port", str(port)], stdout=subprocess.DEVNULL, stderr=f)
    try:
        assert f"relaying /{ns} on ws://127.0.0.1:{port}" in wait_for_line(err, "relaying", START_S, viewer)
        # The map was published once, long before the clients: each gets it only if the relay sends it again.
        for offer in ACCEPTED_OFFERS:
            got = relayed(port, {f"/{ns}/world/map": OccupancyGrid, f"/{ns}/world/markers": MarkerArray}, offer=offer)
            grid = got[f"/{ns}/world/map"]
            assert MAP.decode(grid).lattice == lattice(gridmap), offer
            markers = got[f"/{ns}/world/markers"]
            assert SCENE.decode(markers) == Scene(0, 0, starts, goals), offer
        viewer.send_signal(signal.SIGINT)
        assert viewer.wait(timeout=30) == 0
    finally:
        if viewer.poll() is None:
            viewer.kill()
        viewer.wait(timeout=30)
        stopping.set()
        spinner.join(timeout=10)
        executor.shutdown()
        world.destroy_node()
        agent.destroy_node()


@pytest.mark.ros
@pytest.mark.slow
def test_a_launch_with_view_serves_its_run_to_a_foxglove_client(tmp_path):
    ns, port, err = unique("lview"), free_port(), tmp_path / "launch.stderr"
    with open(err, "wb") as f:
        launch = subprocess.Popen(launch_command(tmp_path / "r", ns, "tunnel_to_goal", "cq", 100_000, (), "--compose",
                                                 "--view", str(port), "--no-figures"),
                                  stdout=subprocess.DEVNULL, stderr=f)
    try:
        assert f"ws://127.0.0.1:{port}" in wait_for_line(err, "Foxglove view on", START_S, launch)
        # The client comes before the nodes have started (their processes take seconds on 2 busy cores).
        got = relayed(port, {f"/{ns}/world/map": OccupancyGrid, f"/{ns}/world/markers": MarkerArray}, START_S)
        assert MAP.decode(got[f"/{ns}/world/map"]).lattice == lattice(load_map("tunnel_to_goal"))
        assert len(SCENE.decode(got[f"/{ns}/world/markers"]).cells) == 2
        launch.send_signal(signal.SIGINT)
        assert launch.wait(timeout=60) == 130
    finally:
        if launch.poll() is None:
            launch.kill()
        launch.wait(timeout=30)


def test_a_client_offering_only_foxglove_websocket_v1_is_refused(ros_context):
    """What foxglove-sdk's server does today with the offer of older clients (Foxglove Studio, Lichtblick before
    1.22): HTTP 400, where the same server (our serve()) accepts each offer of a current client."""
    from websockets.exceptions import InvalidStatus

    from ros_tools.view import serve

    node = rclpy.create_node("viewer", context=ros_context)
    server, _relay = serve(node, f"/subproto_{uuid.uuid4().hex[:6]}", port=0)
    try:
        with pytest.raises(InvalidStatus) as refused, connect(f"ws://127.0.0.1:{server.port}",
                                                              subprotocols=list(REFUSED_OFFER), open_timeout=RECV_S):
            pass
        assert refused.value.response.status_code == 400
        for offer, picked in ACCEPTED_OFFERS.items():
            with connect(f"ws://127.0.0.1:{server.port}", subprotocols=list(offer), open_timeout=RECV_S) as ws:
                assert ws.subprotocol == picked
    finally:
        server.stop()
        node.destroy_node()


def test_a_launch_whose_view_port_is_busy_fails_in_one_line_and_leaves_no_folder(tmp_path):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        done = subprocess.run([sys.executable, "-m", "cq_ros.cli", "launch", "--map", "tunnel_to_goal", "--algo", "cq",
                               "--episodes", "5", "--view", str(port), "--no-figures", "--out",
                               str(tmp_path / "made" / "r")], capture_output=True, text=True, timeout=START_S)
    assert done.returncode == 1, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and str(port) in lines[0], done.stderr
    assert not (tmp_path / "made").exists()  # a rerun is not refused as "not empty"


def test_the_shipped_foxglove_layout_is_make_layouts_and_names_the_systems_topics():
    """docs/foxglove/layout.json is what docs/foxglove/make_layout.py writes (2 agents), and every topic it shows
    is one the system publishes: the viewers' topics under /demo and the world's stats key `collisions`."""
    import importlib.util
    from pathlib import Path

    from msgs_spec.stats import WORLD_STATS_KEYS
    from msgs_spec.topics import WORLD_STATS_TOPIC
    from msgs_spec.viz import looks_topic

    folder = Path(__file__).resolve().parent.parent / "docs" / "foxglove"
    spec = importlib.util.spec_from_file_location("make_layout", folder / "make_layout.py")
    make_layout = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make_layout)
    shipped = (folder / "layout.json").read_text()
    assert shipped == make_layout.layout(2) + "\n", "run .venv/bin/python docs/foxglove/make_layout.py"
    panels = {item["content"]["panelType"]: item["content"]["config"]
              for item in json.loads(shipped)["content"]["items"]}
    scene = panels["ThreeDee"]
    assert scene["fixedFrame"] == "map"
    ns = make_layout.NAMESPACE
    assert set(scene["topics"]) == {f"{ns}/{MAP_TOPIC}", f"{ns}/{SCENE_TOPIC}", f"{ns}/{looks_topic(1)}",
                                    f"{ns}/{looks_topic(2)}"}
    (series,) = panels["Plot"]["paths"]
    assert series["value"].startswith(f"{ns}/{WORLD_STATS_TOPIC}.") and '{key=="collisions"}' in series["value"]
    assert "collisions" in WORLD_STATS_KEYS

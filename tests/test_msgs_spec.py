"""The wire contract: topics, types, QoS, README in sync, encode/decode round trips and every rejection."""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata
import math
import re
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import msgs_spec as ms
from msgs_spec import spec_doc as doc
from msgs_spec.auth import WORLD, RunKey
from node_runtime.qos import profile

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Float64MultiArray, Int32MultiArray, MultiArrayDimension, String

ROOT = Path(__file__).resolve().parents[1]
B = ms.Bounds(n_agents=3, rows=5, cols=11)

# --------------------------------------------------------------------------------------------------------
# The spec itself


def _common_interfaces_packages() -> set[str]:
    """The ROS packages of common_interfaces, read from the installed meta-package's requirements."""
    pkgs = {"std_msgs", "geometry_msgs", "sensor_msgs", "nav_msgs", "diagnostic_msgs", "shape_msgs",
            "stereo_msgs", "trajectory_msgs", "visualization_msgs", "actionlib_msgs", "std_srvs"}
    try:
        reqs = importlib.metadata.requires("ros-common-interfaces") or []
    except importlib.metadata.PackageNotFoundError:
        return pkgs
    found = {re.split(r"[ ~=<>!;\[]", r, maxsplit=1)[0] for r in reqs}
    found = {r.removeprefix("ros-").replace("-", "_") for r in found}
    return found - {"builtin_interfaces"} or pkgs


def test_every_topic_type_is_a_common_interfaces_type():
    allowed = _common_interfaces_packages()
    assert {"std_msgs", "diagnostic_msgs"} <= allowed
    for spec in ms.TOPICS:
        pkg = spec.msg_type.__module__.split(".")[0]
        assert pkg in allowed, f"{spec.pattern}: {spec.msg_type} is not from common_interfaces"
        # importable under its public name, exactly as a ROS user would name it
        assert getattr(importlib.import_module(f"{pkg}.msg"), spec.msg_type.__name__) is spec.msg_type
        assert spec.type_name == f"{pkg}/msg/{spec.msg_type.__name__}"
        # and the encoder really produces that type (payload -> the topic's type)
        assert type(ms.encode(doc.EXAMPLES[spec.key])) is spec.msg_type
    for lay in ms.ARRAY_LAYOUTS:
        assert lay.ros_type.__module__.split(".")[0] in allowed


def test_topics_cover_every_payload_and_names_are_unique_and_relative():
    assert {t.payload for t in ms.TOPICS} == {ms.Feedback, ms.Position, ms.Action, ms.Heartbeat,
                                              ms.AgentStats, ms.WorldStats}
    names = [name for name, _, _ in ms.agent_topics(8)]
    assert len(names) == len(set(names)) == 4 * 8 + 2
    assert all(not n.startswith("/") and not n.startswith("~") for n in names)
    assert ms.feedback_topic(1) == "agv1/feedback"
    assert ms.position_topic(2) == "agv2/position"
    assert ms.action_topic(3) == "agv3/action"
    assert ms.agent_stats_topic(4) == "agv4/stats"
    assert ms.WORLD_STATS_TOPIC == "world/stats" == ms.WORLD_STATS.name()
    assert ms.HEARTBEAT_TOPIC == "world/heartbeat" == ms.HEARTBEAT.name()
    assert ms.agent_namespace(5) == "agv5"
    for bad in (0, -1, 1.0, True, "1", None):
        with pytest.raises(ms.WireError) as e:
            ms.position_topic(bad)
        assert e.value.kind == "unknown_agent"
    with pytest.raises(ValueError):
        ms.WORLD_STATS.name(1)


def test_parse_topic_inverts_the_names_under_any_namespace():
    for name, spec, agent in ms.agent_topics(12):
        for full in (name, "/" + name, "/run7/" + name, "run7/sub/" + name):
            assert ms.parse_topic(full) == (spec, agent)
    for bad in ("agv0/position", "agv1/pose", "agv/position", "world/stat", "/rosout", "xagv1/position",
                "agv01/action", f"agv{'1' * 5000}/action"):
        with pytest.raises(ValueError):
            ms.parse_topic(bad)


def test_viewer_decoders_refuse_numbers_longer_than_an_int32_as_wire_errors():
    from msgs_spec import viz

    huge = "1" * 5000  # longer than Python's int() reads: a ValueError, had it reached int()
    looks = viz.encode_looks(viz.Looks(1, 0, 3, 0, 0, ((2, 0, 1),)))
    scene = viz.encode_scene(viz.Scene(0, 3, ((0, 0), (0, 1)), ((1, 0), (1, 1))))
    assert viz.decode_looks(looks) == viz.Looks(1, 0, 3, 0, 0, ((2, 0, 1),))
    assert viz.decode_scene(scene) == viz.Scene(0, 3, ((0, 0), (0, 1)), ((1, 0), (1, 1)))
    step = next(m for m in scene.markers if m.ns == "step")
    for marker, field, text in ((looks.markers[0], "ns", f"agv{huge}/looks"),
                                (looks.markers[0], "text", f"episode {huge} step 3: agv2"),
                                (looks.markers[0], "text", f"episode 0 step 3: agv{huge}"),
                                (step, "text", f"episode 0 step {huge}")):
        kept = getattr(marker, field)
        setattr(marker, field, text)
        with pytest.raises(ms.WireError):
            viz.decode_looks(looks) if marker is looks.markers[0] else viz.decode_scene(scene)
        setattr(marker, field, kept)


def test_qos_profiles_are_explicit_and_as_documented():
    for spec in ms.TOPICS:
        q = profile(spec.qos)  # as the nodes make it of the contract's plain data
        assert q.reliability == ReliabilityPolicy.RELIABLE
        assert q.history == HistoryPolicy.KEEP_LAST
        assert q.depth >= 1
    pos = profile(ms.POSITION.qos)
    assert (pos.durability, pos.depth) == (DurabilityPolicy.TRANSIENT_LOCAL, 1)  # latched
    for spec in (ms.FEEDBACK, ms.ACTION):
        assert profile(spec.qos).durability == DurabilityPolicy.VOLATILE
        assert profile(spec.qos).depth >= 2  # an episode boundary sends two feedbacks back to back
    for spec in (ms.AGENT_STATS, ms.WORLD_STATS):  # kept for a reader that matches late or falls behind
        assert (profile(spec.qos).durability, profile(spec.qos).depth) == (DurabilityPolicy.TRANSIENT_LOCAL, 1000)
    assert ms.qos_summary(ms.POSITION.qos) == "reliable, transient local, keep last 1"
    assert profile(ms.FEEDBACK.reader_qos).depth == ms.READER_DEPTH


def test_readme_generated_block_matches_the_code():
    text = (ROOT / "msgs_spec" / "README.md").read_text(encoding="utf-8")
    assert doc.readme_generated_block(text) == doc.render_spec(), \
        "msgs_spec/README.md is stale: run `python -m msgs_spec --write`"
    assert subprocess.run([sys.executable, "-m", "msgs_spec", "--check"], cwd=ROOT,
                          capture_output=True, timeout=60).returncode == 0


def test_readme_topic_table_parsed_independently_matches_the_spec():
    """Parse the README's topic table itself (not via render_spec), so a renderer bug cannot hide drift."""
    text = (ROOT / "msgs_spec" / "README.md").read_text(encoding="utf-8")
    block = text[text.index("### Topics"):]
    rows = [line for line in block.splitlines()[2:] if line.startswith("| `")]
    rows = rows[:len(ms.TOPICS) + 1]
    parsed = {}
    for line in rows:
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]
        if not cells[0].startswith("`") or "/" not in cells[0]:
            break
        parsed[cells[0].strip("`")] = cells
    assert set(parsed) == {t.pattern.replace("{agent}", "<k>") for t in ms.TOPICS}
    for t in ms.TOPICS:
        name, typ, qos, pub, sub, payload, fields = parsed[t.pattern.replace("{agent}", "<k>")]
        assert typ == f"`{t.type_name}`"
        assert qos == ms.qos_summary(t.qos)
        assert payload == f"`{t.payload.__name__}`"
        assert pub and sub and fields
    # every array field appears, in order, in the topic's mapping column
    for lay, t in ((ms.FEEDBACK_LAYOUT, ms.FEEDBACK), (ms.POSITION_LAYOUT, ms.POSITION),
                   (ms.ACTION_LAYOUT, ms.ACTION)):
        assert f"[{', '.join(lay.fields)}]" in parsed[t.pattern.replace("{agent}", "<k>")][6]


def test_msgs_spec_imports_no_project_science_or_node_code():
    code = ("import sys, msgs_spec, msgs_spec.spec_doc, msgs_spec.__main__\n"
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('cq_ros', 'world_node', 'agent_node'))\n"
            "assert not bad, bad\n"
            "assert 'rclpy.node' not in sys.modules\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    for path in (ROOT / "msgs_spec").glob("*.py"):
        src = path.read_text(encoding="utf-8")
        assert not re.search(r"^\s*(from|import)\s+(cq_ros|world_node|agent_node)\b", src, re.M), path


# --------------------------------------------------------------------------------------------------------
# Round trips (through the real CDR serialisation, as on the wire)

int32s = st.integers(0, ms.INT32_MAX)
agents = st.integers(1, B.n_agents)
rows = st.integers(0, B.rows - 1)
cols = st.integers(0, B.cols - 1)
finite = st.floats(allow_nan=False, allow_infinity=False)


@st.composite
def feedbacks(draw):
    done = draw(st.booleans())
    truncated = False if done else draw(st.booleans())
    return ms.Feedback(draw(agents), draw(int32s), draw(int32s), draw(rows), draw(cols), draw(finite),
                       done, truncated, draw(st.integers(ms.NO_ACTION, 3)))


positions = st.builds(ms.Position, agents, int32s, int32s, rows, cols)
actions_ = st.builds(ms.Action, agents, int32s, int32s, st.integers(0, 3))
counter_names = st.from_regex(r"[a-z0-9_][a-z0-9_.]{0,20}", fullmatch=True)
counters = st.dictionaries(counter_names, int32s, max_size=4)


@st.composite
def marked(draw, agent):
    peer = draw(agents.filter(lambda p: p != agent))
    return ms.MarkedJointState(draw(rows), draw(cols), peer, draw(rows), draw(cols), draw(finite))


@st.composite
def agent_stats(draw):
    agent = draw(agents)
    return ms.AgentStats(agent=agent, episode=draw(int32s), algorithm=draw(st.sampled_from(
        ["cq", "indep", "js", "jsa", "loc", "near"])), joint_plays=draw(int32s), local_states=draw(int32s),
        joint_states=draw(int32s), subscriptions_created=draw(int32s), subscriptions_active=draw(int32s),
        peer_messages=draw(int32s), marked=tuple(draw(st.lists(marked(agent), max_size=5))),
        counters=draw(counters))


world_stats = st.builds(
    ms.WorldStats, episode=int32s, steps=int32s, truncated=st.booleans(), collisions=int32s,
    missed_actions=int32s, returns=st.lists(finite, min_size=B.n_agents, max_size=B.n_agents).map(tuple),
    duration_s=st.floats(0, 1e9), counters=counters)


def _wire(msg):
    return deserialize_message(serialize_message(msg), type(msg))


def _expect(p):
    """Exactly what a receiver waiting for `p` would pass."""
    kw = {"bounds": B, "episode": p.episode}
    if hasattr(p, "agent"):
        kw["agent"] = p.agent
    if hasattr(p, "step"):
        kw["step"] = p.step
    return kw


@pytest.mark.parametrize("strategy, spec", [
    (feedbacks(), ms.FEEDBACK), (positions, ms.POSITION), (actions_, ms.ACTION),
    (agent_stats(), ms.AGENT_STATS), (world_stats, ms.WORLD_STATS)],
    ids=["feedback", "position", "action", "agent_stats", "world_stats"])
def test_round_trip(strategy, spec):
    @settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(strategy)
    def check(p):
        msg = _wire(ms.encode(p))
        assert type(msg) is spec.msg_type
        typed = {ms.Feedback: ms.decode_feedback, ms.Position: ms.decode_position, ms.Action: ms.decode_action,
                 ms.AgentStats: ms.decode_agent_stats, ms.WorldStats: ms.decode_world_stats}[type(p)]
        assert typed(msg, **_expect(p)) == p
        assert ms.decode(msg, **_expect(p)) == p  # the generic decoder recognises the payload
        assert ms.decode(msg) == p  # no expectations: no context checks
        assert spec.decode(msg, **_expect(p)) == p
        assert spec.decode(msg, bounds=B, agent=getattr(p, "agent", None), episode=p.episode,
                           step=getattr(p, "step", 0)) == p  # uniform call for every topic
        assert type(spec.encode(p)) is spec.msg_type
    check()


@pytest.mark.parametrize("layout", ms.ARRAY_LAYOUTS, ids=lambda layout: layout.payload.__name__)
def test_a_layouts_constructor_makes_what_the_dataclass_makes_and_takes_its_defaults(layout):
    """`layout.new`, the codec's and the cores' constructor: a field with a default may be left out, as the
    dataclass allows, so that a new field with a default changes no caller (msgs_spec/README.md)."""
    values = tuple(range(1, layout.size + 1))
    assert layout.new(*values) == layout.payload(*values)
    required = [f for f in dataclasses.fields(layout.payload) if f.default is dataclasses.MISSING]
    assert layout.new(*values[:len(required)]) == layout.payload(*values[:len(required)])


@pytest.mark.parametrize("keyed", [False, True], ids=["plain", "keyed"])
@pytest.mark.parametrize("layout", ms.ARRAY_LAYOUTS, ids=lambda layout: layout.payload.__name__)
def test_each_frame_written_from_cdr_is_rclpys(layout, keyed):
    """The codec writes its frames out without rclpy: each is rclpy's serialization of a message of its form,
    but for the alignment bytes (rclpy leaves there what memory held; the frame has zeros)."""
    form = layout.forms[keyed]
    label, size = layout.dimension(keyed)
    msg = layout.ros_type()
    msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=size)]
    msg.data = sample = [(i + 1) * 7 for i in range(size)]  # distinct values, to see where they lie
    theirs = bytearray(serialize_message(msg))
    a, b = form.gap
    theirs[a:b] = bytes(b - a)
    pad = b + len(form.after_gap)  # the alignment before the values
    theirs[pad:form.start] = bytes(form.start - pad)
    assert bytes(theirs) == form.head + form.data.pack(*sample)
    assert len(theirs) == form.length and form.holds(bytes(theirs)) and form.holds(serialize_message(msg))


# What the wire carries after the frame (tested above) for the README's examples, sealed with a RunKey of run 7
# and incarnation 5 under KEY: the values, the seal and the MAC, byte for byte as the codec wrote them when it
# was two (msgs_spec.fast and the reference, which agreed on every input); a change to any is a new wire format.
WIRE = {
    "feedback": "000000000000f03f00000000000008400000000000001c4000000000000000400000000000001040000000000000f0bf0000"
                "0000000000000000000000000000000000000000f0bf00000000000000000000000000001c4000000000000014400000e0ff"
                "0361e1410000a06f6739e641000060058a22ef410000c0ef3f4fd141",
    "position": "020000000300000007000000020000000500000000000000070000000500000099441ce721db020b910d7b3ebaa35fb5",
    "action": "01000000030000000700000001000000000000000700000005000000d7edf0e78194f482f856536cf91681ed",
    "heartbeat": "2a00000003000000070000000100000080e3126b15cd5b07000000000700000005000000fef8b779249a9d2e0680"
                 "6568e740a0f3",
}


@pytest.mark.parametrize("name", WIRE)
def test_the_wire_bytes_of_each_payload_are_pinned(name):
    payload = doc.EXAMPLES[name]
    layout = ms.arrays.LAYOUT_BY_PAYLOAD[type(payload)]
    raw = ms.serialize(payload, key=RunKey(KEY, run=7, incarnation=5))
    assert raw == layout.forms[1].head + bytes.fromhex(WIRE[name])
    receiver = RunKey(KEY)
    decode = {ms.Feedback: dfb, ms.Position: dpos, ms.Action: dact}.get(type(payload))
    got = ms.decode_heartbeat(raw, key=receiver) if decode is None else decode(raw, key=receiver)
    sender = payload.agent if type(payload) is ms.Action else WORLD
    assert got == payload and receiver.run == 7 and receiver.held == {sender: 5}  # bound by the first heard
    plain = ms.serialize(payload)
    assert plain == layout.forms[0].head + bytes.fromhex(WIRE[name])[:layout.size * (8 if layout.code == "d" else 4)]


@pytest.mark.parametrize("strategy", [feedbacks(), positions, actions_], ids=["feedback", "position", "action"])
def test_serialize_gives_rclpys_bytes_and_decoders_read_them(strategy):
    @settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(strategy, st.sampled_from([None, KEY]))
    def check(p, key):
        raw, msg = ms.serialize(p, key=key), ms.encode(p, key=key)
        assert deserialize_message(raw, type(msg)) == msg
        # The same bytes but for alignment (after a dimension's label, before the values), where rclpy leaves
        # whatever memory held and serialize writes zeros: every byte that differs is one of ours at zero, and
        # none lies among the values at the end.
        theirs = serialize_message(msg)
        differ = [i for i, (a, b) in enumerate(zip(raw, theirs)) if a != b]
        values_start = (len(raw) - len(msg.data) * (8 if isinstance(msg.data[0], float) else 4) if len(msg.data)
                        else len(raw))
        assert len(raw) == len(theirs) and all(raw[i] == 0 and i < values_start for i in differ)
        decode = {ms.Feedback: dfb, ms.Position: dpos, ms.Action: dact}[type(p)]
        assert decode(raw, **_expect(p), key=key) == p
        assert decode(theirs, **_expect(p), key=key) == p  # rclpy's own bytes, whatever their alignment holds
    check()
    for junk in (b"", b"\x00\x01\x00\x00", b"\x00\x01\x00\x00" + bytes(range(40))):
        with pytest.raises(ms.WireError, match="malformed"):
            dfb(junk)
    stats = doc.EXAMPLES["world_stats"]
    assert ms.serialize(stats) == ms.encode(stats)  # statistics go as messages


def test_round_trip_keeps_the_exact_float_and_reads_like_echo():
    fb = ms.Feedback(1, 2, 3, 4, 5, reward=0.1 + 0.2, done=True)
    assert ms.decode_feedback(_wire(ms.encode(fb))).reward == 0.1 + 0.2
    ws = ms.WorldStats(0, 1, False, 0, 0, returns=(1 / 3, -5e-324), duration_s=1e-9)
    assert ms.decode_world_stats(_wire(ms.encode(ws))).returns == (1 / 3, -5e-324)
    text = doc.to_yaml(ms.encode(ms.Position(2, 3, 7, 2, 5)))
    assert "label: agent,episode,step,row,col" in text and text.rstrip().endswith("- 5")


def test_state_counts_of_any_size_cross_the_wire_exactly():
    # A JS agent on warehouse_16 conditions on 98**16 (about 4.7e36) joint states: its statistics carry the
    # count as the text it is, as the offline engine counts it, where an int32 field would end the agent.
    s = ms.AgentStats(agent=2, episode=0, algorithm="js", local_states=0, joint_states=98**16)
    back = das(_wire(ms.encode(s)), bounds=B, agent=2)
    assert back.joint_states == 98**16 and type(back.joint_states) is int and back == s


@pytest.mark.parametrize("example", ["world_stats", "agent_stats"])
def test_keyed_statistics_are_checked_by_a_receiver_with_the_key_and_read_by_one_without(example):
    key, other = bytes(range(32)), bytes(range(1, 33))
    s = doc.EXAMPLES[example]
    keyed = _wire(ms.encode(s, key=key))
    assert keyed.status[0].values[-1].key == "mac"
    assert ms.decode(keyed, key=key) == s == ms.decode(keyed)  # the tools, holding no key, read both forms
    for bad in (ms.encode(s), ms.encode(s, key=other)):  # a second system's statistics, or a writer with no key
        with pytest.raises(ms.WireError) as e:
            ms.decode(_wire(bad), key=key)
        assert e.value.kind == "unauthenticated"
    forged = _wire(ms.encode(s, key=key))
    forged.status[0].values[1].value = "7"  # a value changed after the MAC was made
    with pytest.raises(ms.WireError) as e:
        ms.decode(forged, key=key)
    assert e.value.kind == "unauthenticated"


@pytest.mark.parametrize("example", ["world_stats", "agent_stats"])
def test_statistics_sealed_to_a_run_are_refused_by_a_receiver_of_another(example):
    """A node seals its statistics with its RunKey (`run`, `inc` before the `mac`, which covers them): a receiver
    told the run refuses another run's, or unsealed ones, as `other_run`; the seal cannot be changed after the
    MAC; the tools read the sealed form."""
    from msgs_spec.auth import RunKey

    key = bytes(range(32))
    s = doc.EXAMPLES[example]
    decode = ms.decode_world_stats if example == "world_stats" else ms.decode_agent_stats
    sealed = _wire(ms.encode(s, key=RunKey(key, run=0xABC, incarnation=7)))
    assert [kv.key for kv in sealed.status[0].values][-3:] == ["run", "inc", "mac"]
    assert sealed.status[0].values[-3].value == "0000000000000abc" and sealed.status[0].values[-2].value == "00000007"
    assert decode(sealed) == decode(sealed, key=key) == decode(sealed, key=RunKey(key, run=0xABC)) == s
    for bad, receiver in ((sealed, dict(key=RunKey(key, run=0xABD))), (sealed, dict(key=key, run=0xABD)),
                          (sealed, dict(run=0xABD)), (_wire(ms.encode(s, key=key)), dict(key=key, run=0xABC)),
                          (_wire(ms.encode(s)), dict(run=0xABC))):
        with pytest.raises(ms.WireError) as e:
            decode(bad, **receiver)
        assert e.value.kind == "other_run", receiver
    moved = _wire(ms.encode(s, key=RunKey(key, run=0xABC)))
    moved.status[0].values[-3].value = "0000000000000abd"  # resealed to another run without the key
    with pytest.raises(ms.WireError) as e:
        decode(moved, key=key, run=0xABD)
    assert e.value.kind == "unauthenticated"
    moved.status[0].values[-3].value = "abd"
    with pytest.raises(ms.WireError) as e:
        decode(moved)
    assert e.value.kind == "malformed"


def test_stats_stamp_and_summary():
    from builtin_interfaces.msg import Time
    msg = ms.encode_world_stats(doc.EXAMPLES["world_stats"], stamp=Time(sec=12, nanosec=5))
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (12, 5)
    assert msg.status[0].level == DiagnosticStatus.OK and "24 steps" in msg.status[0].message
    a = ms.encode(doc.EXAMPLES["agent_stats"])
    assert a.status[0].name == "agv1/stats" and a.status[0].hardware_id == "agv1"


# --------------------------------------------------------------------------------------------------------
# Rejections: every kind, on every decoder where it applies


def _arr(layout, data, label=None, dims=1, size=None, stride=None, offset=0):
    msg = layout.ros_type()
    n = layout.size
    msg.layout.dim = [MultiArrayDimension(label=layout.label if label is None else label,
                                          size=n if size is None else size,
                                          stride=n if stride is None else stride)] * dims
    msg.layout.data_offset = offset
    msg.data = data
    return msg


FB = ms.FEEDBACK_LAYOUT
POS = ms.POSITION_LAYOUT
ACT = ms.ACTION_LAYOUT
GOOD_FB = [1.0, 2.0, 3.0, 4.0, 5.0, -1.0, 0.0, 0.0, 2.0]
GOOD_POS = [2, 2, 3, 4, 10]
GOOD_ACT = [3, 2, 3, 1]


def _fb(**changes):
    d = list(GOOD_FB)
    for k, v in changes.items():
        d[FB.fields.index(k)] = v
    return _arr(FB, d)


def _pos(**changes):
    d = list(GOOD_POS)
    for k, v in changes.items():
        d[POS.fields.index(k)] = v
    return _arr(POS, d)


def _act(**changes):
    d = list(GOOD_ACT)
    for k, v in changes.items():
        d[ACT.fields.index(k)] = v
    return _arr(ACT, d)


KEY = bytes(range(32))


def with_data(msg, index, value):
    msg.data[index] = value
    return msg


def _stats(values, name="world/stats", hw="world", n_status=1):
    st_ = DiagnosticStatus(name=name, hardware_id=hw, values=[KeyValue(key=k, value=v) for k, v in values])
    return DiagnosticArray(status=[st_] * n_status)


def _ws_values(**changes):
    base = [(kv.key, kv.value) for kv in ms.encode(doc.EXAMPLES["world_stats"]).status[0].values]
    out = [(k, changes.pop(k) if k in changes else v) for k, v in base]
    return [(k, v) for k, v in out if v is not None] + list(changes.items())


def _as_values(**changes):
    base = [(kv.key, kv.value) for kv in ms.encode(doc.EXAMPLES["agent_stats"]).status[0].values]
    out = [(k, changes.pop(k) if k in changes else v) for k, v in base]
    return [(k, v) for k, v in out if v is not None] + list(changes.items())


dfb = ms.decode_feedback
dpos = ms.decode_position
dact = ms.decode_action
dws = ms.decode_world_stats
das = ms.decode_agent_stats
E = dict(bounds=B)  # context only
FBX = dict(bounds=B, agent=1, episode=2, step=3)
POSX = dict(bounds=B, agent=2, episode=2, step=3)
ACTX = dict(bounds=B, agent=3, episode=2, step=3)

REJECTIONS = [
    # (id, thunk, kind)
    ("fb-wrong-type", lambda: dfb(Int32MultiArray(), **E), "wrong_type"),
    ("act-wrong-type", lambda: dact(Float64MultiArray(), **E), "wrong_type"),
    ("generic-wrong-type", lambda: ms.decode(String(data="x")), "wrong_type"),
    ("ws-wrong-type", lambda: dws(Int32MultiArray(), **E), "wrong_type"),
    ("spec-wrong-type", lambda: ms.POSITION.decode(Float64MultiArray()), "wrong_type"),
    ("encode-wrong-type", lambda: ms.encode(object()), "wrong_type"),
    ("spec-encode-wrong-type", lambda: ms.ACTION.encode(ms.Position(1, 0, 0, 0, 0)), "wrong_type"),
    ("fb-label", lambda: dfb(_arr(FB, GOOD_FB, label="agent,episode,step,row,col,reward,done"), **E),
     "wrong_layout"),
    ("pos-label-is-action", lambda: dpos(_arr(POS, GOOD_POS, label=ACT.label), **E), "wrong_layout"),
    ("pos-two-dims", lambda: dpos(_arr(POS, GOOD_POS, dims=2), **E), "wrong_layout"),
    ("pos-no-dims", lambda: dpos(_arr(POS, GOOD_POS, dims=0), **E), "wrong_layout"),
    ("act-size", lambda: dact(_arr(ACT, GOOD_ACT, size=5), **E), "wrong_layout"),
    ("act-stride", lambda: dact(_arr(ACT, GOOD_ACT, stride=1), **E), "wrong_layout"),
    ("act-offset", lambda: dact(_arr(ACT, GOOD_ACT, offset=1), **E), "wrong_layout"),
    ("generic-unknown-label", lambda: ms.decode(_arr(ACT, GOOD_ACT, label="x,y,z,w")), "wrong_layout"),
    ("ws-two-statuses", lambda: dws(_stats(_ws_values(), n_status=2)), "wrong_layout"),
    ("ws-no-status", lambda: dws(_stats(_ws_values(), n_status=0)), "wrong_layout"),
    ("ws-name", lambda: dws(_stats(_ws_values(), name="world/stat")), "wrong_layout"),
    ("ws-hardware-id", lambda: dws(_stats(_ws_values(), hw="agv1")), "wrong_layout"),
    ("as-name", lambda: das(_stats(_as_values(), name="agent1/stats", hw="agv1")), "wrong_layout"),
    ("fb-too-long", lambda: dfb(_arr(FB, GOOD_FB + [0.0]), **E), "wrong_length"),
    ("pos-too-short", lambda: dpos(_arr(POS, GOOD_POS[:-1]), **E), "wrong_length"),
    ("fb-nan-reward", lambda: dfb(_fb(reward=math.nan), **FBX), "not_finite"),
    ("fb-inf-reward", lambda: dfb(_fb(reward=-math.inf), **FBX), "not_finite"),
    ("fb-nan-step", lambda: dfb(_fb(step=math.nan), **FBX), "not_finite"),
    ("fb-nan-done", lambda: dfb(_fb(done=math.nan), **FBX), "not_finite"),
    ("ws-nan-return", lambda: dws(_stats(_ws_values(**{"return.agv1": "nan"}))), "not_finite"),
    ("ws-inf-duration", lambda: dws(_stats(_ws_values(duration_s="inf"))), "not_finite"),
    ("as-nan-confidence", lambda: das(_stats(_as_values(**{
        "marked.0": "cell=2,3 peer=agv2 peer_cell=2,4 confidence=nan"}), "agv1/stats", "agv1")),
     "not_finite"),
    ("encode-nan-reward", lambda: ms.encode(ms.Feedback(1, 0, 0, 0, 0, math.nan)), "not_finite"),
    ("fb-fraction-step", lambda: dfb(_fb(step=2.5), **FBX), "not_integer"),
    ("fb-fraction-agent", lambda: dfb(_fb(agent=1.0000001), **FBX), "not_integer"),
    ("ws-fraction-steps", lambda: dws(_stats(_ws_values(steps="3.5"))), "not_integer"),
    ("encode-float-action", lambda: ms.encode(ms.Action(1, 0, 0, 1.5)), "not_integer"),
    ("encode-str-action", lambda: ms.encode(ms.Action(1, 0, 0, "1")), "not_integer"),
    ("fb-huge-step", lambda: dfb(_fb(step=1e12), **E), "out_of_range"),
    ("pos-negative-episode", lambda: dpos(_pos(episode=-1), **E), "out_of_range"),
    ("act-negative-step", lambda: dact(_act(step=-3), **E), "out_of_range"),
    ("ws-negative-count", lambda: dws(_stats(_ws_values(**{"count.x": "-1"}))), "out_of_range"),
    ("ws-negative-duration", lambda: dws(_stats(_ws_values(duration_s="-1.0"))), "out_of_range"),
    ("encode-huge-episode", lambda: ms.encode(ms.Position(1, 2**31, 0, 0, 0)), "out_of_range"),
    ("as-huge-joint-plays", lambda: das(_stats(_as_values(joint_plays=str(2**31)), "agv1/stats", "agv1")),
     "out_of_range"),  # only the state counts are wide
    ("as-too-many-digits", lambda: das(_stats(_as_values(joint_states="9" * 201), "agv1/stats", "agv1")),
     "out_of_range"),
    # longer than Python's int() reads (4,300 digits): refused as any number too long, not a ValueError
    ("ws-int-of-5000-digits", lambda: dws(_stats(_ws_values(steps="9" * 5000))), "out_of_range"),
    ("as-marked-cell-of-5000-digits", lambda: das(_stats(_as_values(**{
        "marked.0": f"cell={'1' * 5000},3 peer=agv2 peer_cell=2,4 confidence=0.5"}), "agv1/stats", "agv1")),
     "malformed"),
    ("as-name-of-5000-digits", lambda: das(_stats(_as_values(), f"agv{'1' * 5000}/stats", f"agv{'1' * 5000}")),
     "wrong_layout"),
    ("as-negative-states", lambda: das(_stats(_as_values(local_states=str(-2**40)), "agv1/stats", "agv1")),
     "out_of_range"),
    ("encode-too-many-digits", lambda: ms.encode(ms.AgentStats(agent=1, episode=0, algorithm="js",
                                                               joint_states=10**200)), "out_of_range"),
    ("fb-flag-half", lambda: dfb(_fb(done=0.5), **FBX), "malformed"),
    ("fb-flag-two", lambda: dfb(_fb(truncated=2.0), **FBX), "malformed"),
    ("fb-done-and-truncated", lambda: dfb(_fb(done=1.0, truncated=1.0), **FBX), "malformed"),
    ("ws-missing-key", lambda: dws(_stats(_ws_values(steps=None))), "malformed"),
    ("ws-repeated-key", lambda: dws(_stats(_ws_values() + [("steps", "1")])), "malformed"),
    ("ws-unknown-key", lambda: dws(_stats(_ws_values(colisions="1"))), "malformed"),
    ("ws-bad-bool", lambda: dws(_stats(_ws_values(truncated="True"))), "malformed"),
    ("ws-garbage-int", lambda: dws(_stats(_ws_values(steps="twelve"))), "malformed"),
    ("ws-returns-gap", lambda: dws(_stats(_ws_values(**{"return.agv4": "1.0"}))), "malformed"),
    ("ws-returns-too-few", lambda: dws(_stats(_ws_values()), bounds=B), "malformed"),
    ("as-marked-format", lambda: das(_stats(_as_values(**{"marked.0": "2,3 with agv2 at 2,4"}),
                                            "agv1/stats", "agv1")), "malformed"),
    ("as-marked-gap", lambda: das(_stats(_as_values(**{"marked.2": "cell=0,0 peer=agv2 peer_cell=0,1 "
                                                                   "confidence=1.0"}), "agv1/stats", "agv1")),
     "malformed"),
    ("as-marked-self", lambda: das(_stats(_as_values(**{
        "marked.0": "cell=2,3 peer=agv1 peer_cell=2,4 confidence=0.5"}), "agv1/stats", "agv1")), "malformed"),
    ("as-bad-algorithm", lambda: das(_stats(_as_values(algorithm="C Q"), "agv1/stats", "agv1")), "malformed"),
    ("encode-done-and-truncated", lambda: ms.encode(ms.Feedback(1, 0, 0, 0, 0, 0.0, True, True)), "malformed"),
    ("encode-bad-counter-name", lambda: ms.encode(ms.WorldStats(0, 0, False, 0, 0, (0.0,),
                                                                counters={"Bad Name": 1})), "malformed"),
    ("encode-no-returns", lambda: ms.encode(ms.WorldStats(0, 0, False, 0, 0, ())), "malformed"),
    ("fb-agent-zero", lambda: dfb(_fb(agent=0.0), **E), "unknown_agent"),
    ("pos-agent-too-big", lambda: dpos(_pos(agent=4), **E), "unknown_agent"),
    ("act-agent-negative", lambda: dact(_act(agent=-1), **E), "unknown_agent"),
    ("act-agent-negative-no-bounds", lambda: dact(_act(agent=-1)), "unknown_agent"),
    ("ws-too-many-returns", lambda: dws(_stats(_ws_values(**{"return.agv3": "0.0", "return.agv4": "0.0"})),
                                        bounds=B), "unknown_agent"),
    ("as-agent-too-big", lambda: das(_stats(_as_values(agent="9"), "agv9/stats", "agv9"), bounds=B),
     "unknown_agent"),
    ("as-marked-peer-unknown", lambda: das(_stats(_as_values(**{
        "marked.0": "cell=2,3 peer=agv7 peer_cell=2,4 confidence=0.5"}), "agv1/stats", "agv1"), bounds=B),
     "unknown_agent"),
    ("encode-agent-zero", lambda: ms.encode(ms.Action(0, 0, 0, 0)), "unknown_agent"),
    ("fb-wrong-agent", lambda: dfb(_fb(agent=2.0), **FBX), "wrong_agent"),
    ("pos-wrong-agent", lambda: dpos(_pos(), **{**POSX, "agent": 1}), "wrong_agent"),
    ("act-wrong-agent", lambda: dact(_act(agent=1), **ACTX), "wrong_agent"),
    ("as-wrong-agent", lambda: das(_stats(_as_values(), "agv1/stats", "agv1"), agent=2), "wrong_agent"),
    ("as-name-agent-mismatch", lambda: das(_stats(_as_values(), "agv2/stats", "agv2")), "wrong_agent"),
    ("act-4", lambda: dact(_act(action=4), **ACTX), "action_out_of_range"),
    ("fb-applied-4", lambda: dfb(_fb(applied=4.0), **FBX), "action_out_of_range"),
    ("fb-applied-minus-2", lambda: dfb(_fb(applied=-2.0), **FBX), "action_out_of_range"),
    ("fb-applied-fraction", lambda: dfb(_fb(applied=0.5), **FBX), "not_integer"),
    ("act-minus-1", lambda: dact(_act(action=-1), **ACTX), "action_out_of_range"),
    ("act-huge", lambda: dact(_act(action=2**31 - 1), **ACTX), "action_out_of_range"),
    ("encode-action-4", lambda: ms.encode(ms.Action(1, 0, 0, 4)), "action_out_of_range"),
    ("fb-row-H", lambda: dfb(_fb(row=5.0), **FBX), "cell_out_of_range"),
    ("pos-col-W", lambda: dpos(_pos(col=11), **POSX), "cell_out_of_range"),
    ("pos-col-negative", lambda: dpos(_pos(col=-1)), "cell_out_of_range"),
    ("as-marked-cell", lambda: das(_stats(_as_values(**{
        "marked.0": "cell=5,3 peer=agv2 peer_cell=2,4 confidence=0.5"}), "agv1/stats", "agv1"), bounds=B),
     "cell_out_of_range"),
    ("encode-row-negative", lambda: ms.encode(ms.Position(1, 0, 0, -1, 0)), "cell_out_of_range"),
    ("fb-stale-episode", lambda: dfb(_fb(), **{**FBX, "episode": 3}), "stale_episode"),
    ("act-stale-episode", lambda: dact(_act(), **{**ACTX, "episode": 3, "step": 0}), "stale_episode"),
    ("ws-stale-episode", lambda: dws(_stats(_ws_values()), episode=4), "stale_episode"),
    ("pos-future-episode", lambda: dpos(_pos(), **{**POSX, "episode": 1, "step": 99}), "future_episode"),
    ("as-future-episode", lambda: das(_stats(_as_values(), "agv1/stats", "agv1"), episode=2),
     "future_episode"),
    ("fb-stale-step", lambda: dfb(_fb(), **{**FBX, "step": 4}), "stale_step"),
    ("act-stale-step", lambda: dact(_act(), **{**ACTX, "step": 4}), "stale_step"),
    ("pos-stale-step", lambda: dpos(_pos(), **{**POSX, "step": 4}), "stale_step"),
    ("fb-future-step", lambda: dfb(_fb(), **{**FBX, "step": 2}), "future_step"),
    ("act-future-step", lambda: dact(_act(), **{**ACTX, "step": 0}), "future_step"),
    ("pos-future-step-no-episode", lambda: dpos(_pos(), bounds=B, agent=2, step=0), "future_step"),
    ("act-no-mac", lambda: dact(_act(), **ACTX, key=KEY), "unauthenticated"),
    ("fb-other-key", lambda: dfb(ms.encode(ms.Feedback(1, 2, 3, 4, 5, -1.0), key=b"x" * 32), **FBX, key=KEY),
     "unauthenticated"),
    ("pos-changed-after-mac", lambda: dpos(with_data(ms.encode(ms.Position(2, 2, 3, 4, 10), key=KEY), 3, 3),
                                           **POSX, key=KEY), "unauthenticated"),
    ("fb-other-run", lambda: dfb(ms.serialize(ms.Feedback(1, 2, 3, 4, 5, -1.0), key=RunKey(KEY, run=7)), **FBX,
                                 key=RunKey(KEY, run=8)), "other_run"),
    ("act-other-run-message", lambda: dact(ms.encode(ms.Action(3, 2, 3, 1), key=RunKey(KEY, run=7)), **ACTX,
                                           key=RunKey(KEY, run=8)), "other_run"),
    ("hb-other-world", lambda: _bound_then(ms.Heartbeat(1, 0, 0), ms.Heartbeat(2, 0, 0), WORLD), "other_incarnation"),
    ("act-retired-agent", lambda: _bound_then(ms.Action(3, 2, 3, 1), ms.Action(3, 2, 3, 1), 3, retire=True),
     "other_incarnation"),
    ("hb-replayed", lambda: ms.check_beat(ms.decode_heartbeat(ms.encode(ms.Heartbeat(5, 0, 0))).beat, 5), "replayed"),
    ("hb-beat-zero", lambda: ms.decode_heartbeat(_arr(ms.HEARTBEAT_LAYOUT, [0, 0, 0, 1, 0, 0])), "out_of_range"),
    ("hb-stepping-two", lambda: ms.decode_heartbeat(_arr(ms.HEARTBEAT_LAYOUT, [1, 0, 0, 2, 0, 0])), "out_of_range"),
    ("hb-ticket-negative", lambda: ms.decode_heartbeat(_arr(ms.HEARTBEAT_LAYOUT, [1, 0, 0, 1, 0, -1])), "out_of_range"),
]
# Judged by the receiver (agent_node.peer_view.PeerView, agent_node.world_link.WorldLink; tests/test_driver.py),
# not by a decoder.
RECEIVER_KINDS = {"conflicting", "far_ahead"}


def _bound_then(first, second, sender, retire=False):
    """A receiver of run 7 bound to `first`'s sender incarnation (1), then given `second` from incarnation 2;
    with `retire`, incarnation 2 spoke before 1 (an agent restarted, its earlier life's message comes late)."""
    receiver = RunKey(KEY, run=7)
    decode = {ms.Heartbeat: ms.decode_heartbeat, ms.Action: lambda m, key: dact(m, key=key, **ACTX)}[type(first)]
    lives = (2, 1) if retire else (1, 2)
    decode(ms.serialize(first, key=RunKey(KEY, run=7, incarnation=lives[0])), key=receiver)
    if retire:
        decode(ms.serialize(first, key=RunKey(KEY, run=7, incarnation=lives[1])), key=receiver)
        assert receiver.replaced == 1 and receiver.held[sender] == 1
    return decode(ms.serialize(second, key=RunKey(KEY, run=7, incarnation=2)), key=receiver)


@pytest.mark.parametrize("thunk, kind", [r[1:] for r in REJECTIONS], ids=[r[0] for r in REJECTIONS])
def test_rejection(thunk, kind):
    with pytest.raises(ms.WireError) as e:
        thunk()
    assert e.value.kind == kind, str(e.value)
    assert e.value.detail  # always says what was seen


def test_every_kind_is_tested_and_the_good_messages_pass():
    assert {k for _, _, k in REJECTIONS} == set(ms.KINDS) - RECEIVER_KINDS
    assert dfb(_fb(), **FBX) == ms.Feedback(1, 2, 3, 4, 5, -1.0, False, False, 2)
    assert dfb(_fb(applied=-1.0), **FBX).applied == ms.NO_ACTION
    assert dpos(_pos(), **POSX) == ms.Position(2, 2, 3, 4, 10)
    assert dact(_act(), **ACTX) == ms.Action(3, 2, 3, 1)
    assert dws(_stats(_ws_values()), bounds=ms.Bounds(2, 5, 11), episode=3) == doc.EXAMPLES["world_stats"]
    assert das(_stats(_as_values(), "agv1/stats", "agv1"), bounds=B, agent=1, episode=3) == \
        doc.EXAMPLES["agent_stats"]
    with pytest.raises(ValueError):
        ms.WireError("no_such_kind")


def _raw(layout, values, run=7, incarnation=5, key=KEY):
    """Serialized bytes of `layout` holding `values` (any, even ones no encoder writes) as rclpy serializes
    them, keyed with `key` (None: plain): sealed with `run` and `incarnation` and MACed by hand (mac_words over
    the packed values and seal), not by the codec."""
    from msgs_spec.auth import mac_words

    if key is None:
        return serialize_message(_arr(layout, list(values)))
    word = "I" if layout.code == "i" else "d"
    seal = (run >> 32, run & 0xFFFFFFFF, incarnation)
    body = struct.pack(f"<{layout.size}{layout.code}", *values) + struct.pack(f"<3{word}", *seal)
    data = [*values, *seal, *mac_words(key, layout.label, body)]
    data = [float(v) for v in data] if word == "d" else [v - 2**32 if v > ms.INT32_MAX else v for v in data]
    n = layout.size + 7
    return serialize_message(_arr(layout, data, label=layout.keyed_label, size=n, stride=n))


def _bound(incarnation=5, sender=WORLD, run=7):
    key = RunKey(KEY, run=run)
    key.accept(run, incarnation, sender)
    return key


FB_VALUES = (1, 2, 3, 4, 5, -1.0, 0, 0, 2)
POS_VALUES = tuple(GOOD_POS)
ACT_VALUES = tuple(GOOD_ACT)


def _changed(values, layout, **changes):
    return tuple(changes.get(name, v) for name, v in zip(layout.fields, values))


# Serialized bytes as a raw subscription hears them, sealed under the run's key, decoded by a receiver holding it:
# every kind a decoder of bytes gives, after the MAC and the seal matched where the values are the wrong ones.
BYTES_REJECTIONS = [
    ("fb-label", lambda: dfb(serialize_message(_arr(FB, GOOD_FB, label="agent,episode,step,row,col,reward,done")),
                             **FBX), "wrong_layout"),
    ("act-keyed-short", lambda: dact(serialize_message(_arr(ACT, GOOD_ACT, label=ACT.keyed_label, size=11,
                                                            stride=11)), **ACTX, key=RunKey(KEY, run=7)),
     "wrong_length"),
    ("fb-junk", lambda: dfb(b"\x00\x01\x00\x00" + bytes(range(40)), **FBX), "malformed"),
    ("fb-nan-reward", lambda: dfb(_raw(FB, _changed(FB_VALUES, FB, reward=math.nan)), **FBX, key=_bound()),
     "not_finite"),
    ("fb-fraction-step", lambda: dfb(_raw(FB, _changed(FB_VALUES, FB, step=2.5)), **FBX, key=_bound()),
     "not_integer"),
    ("fb-huge-episode", lambda: dfb(_raw(FB, _changed(FB_VALUES, FB, episode=2.0**40)), **E, key=_bound()),
     "out_of_range"),
    ("pos-negative-step", lambda: dpos(_raw(POS, _changed(POS_VALUES, POS, step=-1)), **E, key=_bound()),
     "out_of_range"),
    ("hb-stepping-two", lambda: ms.decode_heartbeat(_raw(ms.HEARTBEAT_LAYOUT, (1, 0, 0, 2, 0, 0)), key=_bound()),
     "out_of_range"),
    ("fb-flag-half", lambda: dfb(_raw(FB, _changed(FB_VALUES, FB, done=0.5)), **FBX, key=_bound()), "malformed"),
    ("fb-done-and-truncated", lambda: dfb(_raw(FB, _changed(FB_VALUES, FB, done=1, truncated=1)), **FBX,
                                          key=_bound()), "malformed"),
    ("pos-agent-too-big", lambda: dpos(_raw(POS, _changed(POS_VALUES, POS, agent=4)), **E, key=_bound()),
     "unknown_agent"),
    ("act-wrong-agent", lambda: dact(_raw(ACT, _changed(ACT_VALUES, ACT, agent=1)), **ACTX, key=_bound(sender=3)),
     "wrong_agent"),
    ("act-4", lambda: dact(_raw(ACT, _changed(ACT_VALUES, ACT, action=4)), **ACTX, key=_bound(sender=3)),
     "action_out_of_range"),
    ("fb-applied-minus-2", lambda: dfb(_raw(FB, _changed(FB_VALUES, FB, applied=-2)), **FBX, key=_bound()),
     "action_out_of_range"),
    ("pos-col-W", lambda: dpos(_raw(POS, _changed(POS_VALUES, POS, col=11)), **POSX, key=_bound()),
     "cell_out_of_range"),
    ("fb-stale-episode", lambda: dfb(_raw(FB, FB_VALUES), **{**FBX, "episode": 3}, key=_bound()), "stale_episode"),
    ("pos-future-episode", lambda: dpos(_raw(POS, POS_VALUES), **{**POSX, "episode": 1}, key=_bound()),
     "future_episode"),
    ("act-stale-step", lambda: dact(_raw(ACT, ACT_VALUES), **{**ACTX, "step": 4}, key=_bound(sender=3)),
     "stale_step"),
    ("fb-future-step", lambda: dfb(_raw(FB, FB_VALUES), **{**FBX, "step": 2}, key=_bound()), "future_step"),
    ("pos-plain", lambda: dpos(_raw(POS, POS_VALUES, key=None), **POSX, key=_bound()), "unauthenticated"),
    ("fb-other-key", lambda: dfb(_raw(FB, FB_VALUES, key=b"x" * 32), **FBX, key=_bound()), "unauthenticated"),
    ("act-mac-changed", lambda: dact(_raw(ACT, ACT_VALUES)[:-1] + b"\x00", **ACTX, key=_bound(sender=3)),
     "unauthenticated"),
    ("fb-other-run", lambda: dfb(_raw(FB, FB_VALUES, run=8), **FBX, key=_bound()), "other_run"),
    ("hb-other-world", lambda: ms.decode_heartbeat(_raw(ms.HEARTBEAT_LAYOUT, (1, 0, 0, 1, 0, 0), incarnation=6),
                                                   key=_bound()), "other_incarnation"),
    ("hb-replayed", lambda: ms.check_beat(ms.decode_heartbeat(_raw(ms.HEARTBEAT_LAYOUT, (5, 0, 0, 1, 0, 0)),
                                                              key=_bound()).beat, 5), "replayed"),
]


@pytest.mark.parametrize("thunk, kind", [r[1:] for r in BYTES_REJECTIONS], ids=[r[0] for r in BYTES_REJECTIONS])
def test_rejection_of_bytes(thunk, kind):
    with pytest.raises(ms.WireError) as e:
        thunk()
    assert e.value.kind == kind, str(e.value)


def test_every_kind_of_bytes_is_tested_and_the_good_bytes_pass_and_bind():
    assert {k for _, _, k in BYTES_REJECTIONS} == set(ms.KINDS) - RECEIVER_KINDS - {"wrong_type"}  # bytes: untyped
    key = RunKey(KEY, run=7)
    assert dfb(_raw(FB, FB_VALUES), **FBX, key=key) == ms.Feedback(1, 2, 3, 4, 5, -1.0, False, False, 2)
    assert key.held == {WORLD: 5}
    assert dact(_raw(ACT, ACT_VALUES, incarnation=9), **ACTX, key=key) == ms.Action(3, 2, 3, 1)
    assert key.held == {WORLD: 5, 3: 9}
    with pytest.raises(ms.WireError, match="other_incarnation"):  # one world life per run
        dpos(_raw(POS, POS_VALUES, incarnation=6), **POSX, key=key)
    assert key.held == {WORLD: 5, 3: 9}  # a refused message binds nothing


@pytest.mark.parametrize("payload", [doc.EXAMPLES[k] for k in ("feedback", "position", "action", "heartbeat")],
                         ids=["feedback", "position", "action", "heartbeat"])
def test_keyed_messages_round_trip_and_only_the_key_holder_checks_them(payload):
    keyed = _wire(ms.encode(payload, key=KEY))
    lay = next(lay for lay in ms.ARRAY_LAYOUTS if lay.payload is type(payload))
    assert keyed.layout.dim[0].label == lay.keyed_label and len(keyed.data) == lay.size + 3 + 4
    assert ms.decode(keyed, key=KEY) == payload == ms.decode(keyed)  # a receiver without the key reads it too
    with pytest.raises(ms.WireError, match="unauthenticated"):
        ms.decode(_wire(ms.encode(payload)), key=KEY)
    decode = {ms.Feedback: dfb, ms.Position: dpos, ms.Action: dact, ms.Heartbeat: ms.decode_heartbeat}[type(payload)]
    assert decode(ms.serialize(payload, key=KEY), key=KEY) == payload  # as a raw subscription gets it
    with pytest.raises(ms.WireError, match="unauthenticated"):
        decode(ms.serialize(payload), key=KEY)
    for i in range(lay.size + 3 + 4):  # any value, seal word or MAC word changed: refused
        changed = _wire(ms.encode(payload, key=KEY))
        changed.data[i] = changed.data[i] + 1 if changed.data[i] < 2**31 - 1 else 0
        with pytest.raises(ms.WireError, match="unauthenticated"):
            ms.decode(changed, key=KEY)
        with pytest.raises(ms.WireError, match="unauthenticated"):
            decode(serialize_message(changed), key=KEY)


@settings(max_examples=100, deadline=None)
@given(st.binary(min_size=16, max_size=200), st.sampled_from([lay.label for lay in ms.ARRAY_LAYOUTS]),
       st.binary(max_size=64))
def test_the_mac_is_hmac_sha256_of_the_domain_label_and_values(key, label, packed):
    import hmac
    import struct

    from msgs_spec.auth import mac_words
    digest = hmac.new(key, b"cq_ros/mac/2\0" + label.encode() + b"\0" + packed, "sha256").digest()
    assert mac_words(key, label, packed) == struct.unpack(">4I", digest[:16])


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.floats(), st.integers(-2**31 - 2, 2**31 + 1).map(float),
                          st.sampled_from([0.0, 1.0, -0.0])), min_size=len(FB.fields), max_size=len(FB.fields)))
def test_the_float_arrays_one_pass_reading_is_the_checked_one(values):
    """The compiled reading of a float64 array's values (ArrayLayout._from_floats) gives what the field
    converters give (msgs_spec.checks), or None where they refuse."""
    fast = FB._from_floats(tuple(values))
    try:
        checked = FB._typed(values)
    except ms.WireError:
        assert fast is None
    else:
        kinds = [{"int": int, "float": float, "flag": bool}[kind] for kind in FB.field_kinds]
        assert fast == checked and list(map(type, fast)) == kinds


_anything = st.one_of(st.integers(-2**31 - 2, 2**31 + 1), st.floats(), st.booleans(), st.sampled_from(
    [0, 1, 0.0, 1.0, -0.0, 2**40, "1", None]))


@settings(max_examples=400, deadline=None)
@given(st.sampled_from(ms.ARRAY_LAYOUTS).flatmap(
    lambda lay: st.tuples(st.just(lay), st.tuples(*[_anything] * lay.size))))
def test_the_encoders_one_pass_check_is_the_converters(layout_values):
    """A payload passes the compiled check the encoders make first (ArrayLayout._plain) exactly when the field
    converters give each of its values back as it is, of the same type: as nodes build payloads."""
    layout, values = layout_values
    try:
        typed = layout._typed(values)
        same = typed == values and all(type(a) is type(b) for a, b in zip(typed, values))
    except ms.WireError:
        same = False
    assert layout._plain(layout.payload(*values)) == (values if same else None)


def test_check_order_first_failure_wins():
    # unknown agent beats the action range and the step; the action range beats the step
    with pytest.raises(ms.WireError, match="unknown_agent"):
        dact(_act(agent=9, action=7, step=99), **ACTX)
    with pytest.raises(ms.WireError, match="action_out_of_range"):
        dact(_act(action=7, step=99), **ACTX)
    with pytest.raises(ms.WireError, match="stale_episode"):  # episode before step
        dact(_act(episode=1, step=99), **ACTX)
    with pytest.raises(ms.WireError, match="not_finite"):  # numbers before agent
        dfb(_fb(agent=7.0, reward=math.nan), **FBX)


def test_wire_error_is_a_value_error_and_pickles():
    import pickle
    e = ms.WireError("stale_step", "episode 1 step 2, expected step 3")
    assert isinstance(e, ValueError)
    e2 = pickle.loads(pickle.dumps(e))
    assert (e2.kind, e2.detail, str(e2)) == (e.kind, e.detail, str(e))


# --------------------------------------------------------------------------------------------------------
# Fuzz: any message of the right ROS type decodes to a valid payload or raises WireError, nothing else

labels = st.sampled_from([FB.label, POS.label, ACT.label, FB.keyed_label, ACT.keyed_label, "", "agent", "x,y"])
RAW_DECODERS = {Float64MultiArray: (dfb,), Int32MultiArray: (dpos, dact)}  # decoders that take serialized bytes
any_float = st.floats(allow_nan=True, allow_infinity=True)
int32_any = st.integers(-2**31, 2**31 - 1)


@settings(max_examples=400, deadline=None)
@given(float_msg=st.booleans(), label=labels, dims=st.integers(0, 2), size=st.integers(0, 9),
       stride=st.integers(0, 9), offset=st.integers(0, 2), fdata=st.lists(any_float, max_size=10),
       idata=st.lists(int32_any, max_size=10), episode=st.none() | int32s, step=st.none() | int32s,
       agent=st.none() | agents)
def test_fuzz_arrays_only_raise_wire_error(float_msg, label, dims, size, stride, offset, fdata, idata,
                                           episode, step, agent):
    msg = (Float64MultiArray if float_msg else Int32MultiArray)()
    msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=stride)] * dims
    msg.layout.data_offset = offset
    msg.data = fdata if float_msg else idata
    for fn in (ms.decode, dfb, dpos, dact, dws, das):
        kw = {"bounds": B, "agent": agent, "episode": episode, "step": step}
        if fn in (dws,):
            kw = {"bounds": B, "episode": episode}
        if fn in (das,):
            kw = {"bounds": B, "agent": agent, "episode": episode}
        try:
            p = fn(msg, **kw)
        except ms.WireError as e:
            assert e.kind in ms.KINDS
            if fn in RAW_DECODERS[type(msg)]:  # a raw subscription's bytes are judged as the message
                with pytest.raises(ms.WireError) as raw:
                    fn(serialize_message(msg), **kw)
                assert raw.value.kind == e.kind
            continue
        assert ms.decode(_wire(ms.encode(p))) == p  # whatever passes is re-encodable
        if fn in RAW_DECODERS[type(msg)]:
            assert fn(serialize_message(msg), **kw) == p


keys = st.sampled_from(["episode", "steps", "truncated", "collisions", "missed_actions", "duration_s",
                        "return.agv1", "return.agv2", "return.agv0", "return.x", "count.dropped.x", "count.",
                        "agent", "algorithm", "joint_plays", "local_states", "joint_states",
                        "subscriptions_created", "subscriptions_active", "peer_messages", "marked.0",
                        "marked.1", "marked.x", "other"])
vals = st.sampled_from(["0", "1", "2", "-1", "1.5", "nan", "inf", "true", "false", "cq", "",
                        "cell=0,0 peer=agv2 peer_cell=0,1 confidence=1.0",
                        "cell=0,0 peer=agv1 peer_cell=0,1 confidence=0.5", "99999999999", "9" * 5000,
                        f"cell={'1' * 5000},0 peer=agv2 peer_cell=0,1 confidence=1.0"]) | st.text(max_size=8)


@settings(max_examples=400, deadline=None)
@given(pairs=st.lists(st.tuples(keys, vals), max_size=24), name=st.sampled_from(
    ["world/stats", "agv1/stats", "agv2/stats", "x", f"agv{'1' * 5000}/stats"]),
    hw=st.sampled_from(["world", "agv1", "agv2", "", f"agv{'1' * 5000}"]),
    n_status=st.integers(0, 2))
def test_fuzz_stats_only_raise_wire_error(pairs, name, hw, n_status):
    msg = _stats(pairs, name, hw, n_status)
    for fn in (ms.decode, dws, das):
        try:
            p = fn(msg, bounds=B)
        except ms.WireError as e:
            assert e.kind in ms.KINDS
            continue
        assert ms.decode(_wire(ms.encode(p))) == p


# --------------------------------------------------------------------------------------------------------
# DropCounter


def test_drop_counter_logs_first_and_every_nth_and_counts():
    logged = []
    ticks = iter(range(0, 1000, 2))  # a drop every 2 s: never a flood
    drops = ms.DropCounter(logged.append, every=3, clock=lambda: next(ticks))
    bad = _act(action=9)
    for _ in range(7):
        assert drops.guard(dact, bad, source="agv3/action", **ACTX) is None
    assert drops.guard(dact, _act(step=1), source="agv3/action", **ACTX) is None  # stale
    assert drops.guard(dact, _act(), **ACTX) == ms.Action(3, 2, 3, 1)  # good passes through
    assert drops.counts == {"action_out_of_range": 7, "stale_step": 1}
    assert drops["action_out_of_range"] == 7 and drops["never"] == 0 and drops.total == 8
    assert drops.as_counters() == {"dropped.action_out_of_range": 7, "dropped.stale_step": 1}
    # 1st, 3rd, 6th of action_out_of_range; 1st of stale_step
    assert len(logged) == 4
    assert "agv3/action" in logged[0] and "action_out_of_range" in logged[0] and "first" in logged[0]
    assert "3 of this kind" in logged[1] and "6 of this kind" in logged[2] and "stale_step" in logged[3]
    # counters feed the statistics as is
    s = ms.AgentStats(agent=3, episode=0, algorithm="cq", counters=drops.as_counters())
    assert ms.decode(_wire(ms.encode(s))).counters == drops.as_counters()


def test_a_flood_is_reported_once_with_its_rate_and_source_and_every_drop_counted():
    """5,000 refused messages on one topic in 0.5 s (and a few elsewhere): one line says the flood, its source
    and its rate; the rest are counted without a line; another source still logs its own."""
    logged, now = [], [0.0]
    drops = ms.DropCounter(logged.append, every=100, clock=lambda: now[0])
    for i in range(5000):
        now[0] = i * 1e-4
        drops.record(ms.WireError("malformed", "junk"), "agv1/action")
        if i % 1000 == 0:
            drops.record(ms.WireError("stale_step", "old"), "agv2/action")
    floods = [line for line in logged if "flood" in line]
    assert len(floods) == 1 and "on agv1/action" in floods[0] and "100 in 0.01 s" in floods[0], floods
    assert list(drops.floods) == ["agv1/action"] and 9000 < drops.floods["agv1/action"] < 11000
    assert len(logged) == 3 and sum("agv2/action" in line for line in logged) == 1  # and agv1's first line
    assert drops.counts == {"malformed": 5000, "stale_step": 5}


def test_drop_counter_without_logger_and_bugs_propagate():
    drops = ms.DropCounter(None, every=1)
    assert drops.record(ms.WireError("malformed", "x")) == 1

    def buggy(msg):
        raise KeyError("a bug, not bad input")

    with pytest.raises(KeyError):
        drops.guard(buggy, None)
    with pytest.raises(ValueError):
        ms.DropCounter(every=0)


def test_bounds_validates():
    for bad in ((0, 1, 1), (1, 0, 1), (1, 1, -1), (1.0, 1, 1), (True, 1, 1)):
        with pytest.raises(ValueError):
            ms.Bounds(*bad)


# --------------------------------------------------------------------------------------------------------
# Over real DDS, in process: each topic's QoS delivers its payload; the position topic is latched


def test_every_topic_delivers_over_dds_with_its_qos_and_position_is_latched(ros_context, spin_until):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    node = rclpy.create_node("msgs_spec_test", namespace="/t", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    try:
        got: dict[str, list] = {}
        pubs = {}
        for spec in ms.TOPICS:
            example = doc.EXAMPLES[spec.key]
            name = spec.name(example.agent) if spec.per_agent else spec.name()
            pubs[spec.key] = (node.create_publisher(spec.msg_type, name, profile(spec.qos)), name, example)
        # latched: publish the position BEFORE anyone subscribes
        pub, name, example = pubs["position"]
        pub.publish(ms.encode(example))

        def subscribe(spec, name):
            got[spec.key] = []
            node.create_subscription(spec.msg_type, name, lambda m, k=spec.key: got[k].append(m), profile(spec.qos))

        for spec in ms.TOPICS:
            subscribe(spec, pubs[spec.key][1])
        spin_until(ex, lambda: all(p.get_subscription_count() >= 1 for p, _, _ in pubs.values()), 10.0)
        for key, (pub, _, example) in pubs.items():
            if key != "position":
                pub.publish(ms.encode(example))
        spin_until(ex, lambda: all(got.values()), 10.0)
        for spec in ms.TOPICS:
            example = doc.EXAMPLES[spec.key]
            assert got[spec.key], f"nothing on {spec.pattern}"
            assert spec.decode(got[spec.key][0]) == example
        assert len(got["position"]) == 1  # exactly the latched sample
    finally:
        ex.shutdown()
        node.destroy_node()


@pytest.mark.parametrize("ros_type, label, n, dims", [
    (Int32MultiArray, ACT.keyed_label, 20_000, 1), (Float64MultiArray, FB.label, 20_000, 1),
    (Int32MultiArray, "x" * 10_000, 4, 1), (Int32MultiArray, ACT.label, 20_000, 2),
    (Int32MultiArray, "x,y", 4, 1)], ids=["20000-values", "20000-floats", "10KB-label", "2-dims", "small"])
def test_bytes_longer_than_the_keyed_form_are_refused_from_their_header_unread(monkeypatch, ros_type, label, n, dims):
    """A flood's message too large for its layout is refused before it is deserialized (its header read in
    place), with the kind the message object would get; one of the layout's size is still read whole."""
    msg = ros_type()
    msg.layout.dim = [MultiArrayDimension(label=label, size=n, stride=n)] * dims
    msg.data = [1] * n if ros_type is Int32MultiArray else [1.0] * n
    decode = dfb if ros_type is Float64MultiArray else dact
    with pytest.raises(ms.WireError) as as_object:
        decode(msg)
    raw = serialize_message(msg)
    oversized = len(raw) > (FB if ros_type is Float64MultiArray else ACT).forms[1].length
    read = []
    monkeypatch.setattr(ms.ArrayLayout, "_deserialized",
                        lambda layout, b: read.append(b) or deserialize_message(b, ros_type))
    with pytest.raises(ms.WireError) as as_bytes:
        decode(raw)
    assert as_bytes.value.kind == as_object.value.kind and read == ([] if oversized else [raw])
    assert oversized == (n > 4 or len(label) > 100)


_MARKED_MOST = 5 * 11 * 5 * 11 * 2  # B's grid: every (own cell, peer, peer cell) of 3 agents


@pytest.mark.parametrize("name, values, n_status, kind", [
    ("world/stats", [(f"k{i}", "v") for i in range(2000)], 1, "malformed"),
    ("world/stats", _ws_values(), 500, "wrong_layout"),
    ("world/stats", _ws_values(), 0, "wrong_layout"),
    ("world/stats", _ws_values(steps="1" * 400_000), 1, "malformed"),
    ("agv1/stats", [(f"marked.{i}", "x") for i in range(_MARKED_MOST + 400)], 1, "malformed"),
], ids=["2000-pairs", "500-statuses", "no-status", "400KB-value", "agent-too-many-pairs"])
def test_statistics_too_large_for_the_map_are_refused_from_their_header_unread(monkeypatch, name, values, n_status,
                                                                               kind):
    """A flood's statistics of 2,000 pairs, 500 statuses or a 400 KB value are refused from their CDR header,
    never deserialized: more pairs than a statistic of the map can carry, more bytes than so many of the longest
    pairs take, or a status count other than 1."""
    from msgs_spec import stats

    raw = serialize_message(_stats(values, name, name.split("/")[0], n_status))
    read = []
    monkeypatch.setattr("rclpy.serialization.deserialize_message", lambda *a: read.append(a))
    decode = dws if name == "world/stats" else das
    with pytest.raises(ms.WireError) as refused:
        decode(raw, bounds=B)
    assert refused.value.kind == kind and read == [], refused.value
    assert stats.pairs_bound(B, agent=False) < 300 < _MARKED_MOST < stats.pairs_bound(B, agent=True)


def test_statistics_as_bytes_decode_as_the_message_does_up_to_the_largest_the_map_allows():
    """Serialized statistics (what a raw subscription hears) decode to what the message decodes to, keyed and
    sealed or not, an agent's with as many marked joint states and counters as its map and the contract allow;
    a bad one as bytes is refused with the message's kind."""
    from msgs_spec import stats

    key = RunKey(KEY, run=7)
    world = doc.EXAMPLES["world_stats"]
    assert dws(serialize_message(ms.encode(world, key=key)), bounds=ms.Bounds(2, 5, 11), key=key) == world
    cells = [(r, c) for r in range(5) for c in range(11)]
    marked = tuple(ms.MarkedJointState(*a, 2, *b, -1.2345678901234567e-300) for a in cells for b in cells)
    counters = {f"c{i:03d}.{'x' * 40}": 2**31 - 1 for i in range(stats.COUNTERS_MAX)}
    agent = ms.AgentStats(agent=1, episode=2**31 - 1, algorithm="cq", local_states=10**200 - 1,
                          joint_states=10**200 - 1, marked=marked, counters=counters)
    bounds = ms.Bounds(2, 5, 11)
    raw = serialize_message(ms.encode(agent, key=key))
    assert len(raw) <= stats.bytes_bound(stats.pairs_bound(bounds, agent=True))
    assert das(raw, bounds=bounds, agent=1, key=key) == agent
    with pytest.raises(ms.WireError, match="more than 256"):
        ms.encode(ms.AgentStats(agent=1, episode=0, algorithm="cq", counters={**counters, "one_more": 1}))
    bad = _stats(_ws_values(steps="-3"))
    with pytest.raises(ms.WireError) as as_object:
        dws(bad, bounds=B)
    with pytest.raises(ms.WireError) as as_bytes:
        dws(serialize_message(bad), bounds=B)
    assert as_bytes.value.kind == as_object.value.kind == "out_of_range"
    with pytest.raises(ms.WireError, match="malformed: not a serialized DiagnosticArray"):
        dws(b"\x00\x01\x00\x00" + bytes(range(40)), bounds=B)

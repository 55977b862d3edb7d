"""encode(payload) -> standard ROS message; decode(message, what the receiver expects) -> payload.

Every decoder validates and raises only `WireError` for any input (whatever the message holds), with the
first failing check in this order: type, layout, length, numbers (finite, integer, int32 range), agent id,
action / cell range, episode, step. Encoders refuse what no decoder would accept (bad values, not context),
so a sender's bug shows at the sender.

Array layouts (one dimension; its label lists the fields in order, so `ros2 topic echo` is self-describing):

    Feedback  std_msgs/Float64MultiArray  label "agent,episode,step,row,col,reward,done,truncated,applied"
    Position  std_msgs/Int32MultiArray    label "agent,episode,step,row,col"
    Action    std_msgs/Int32MultiArray    label "agent,episode,step,action"
    Heartbeat std_msgs/Int32MultiArray    label "beat,episode,step"

Keyed (msgs_spec.auth): with the run's key the label ends in ",mac0,mac1,mac2,mac3" and the data holds the
MAC's four 32-bit words after the fields (as int32 in an Int32 array, as whole numbers in a Float64 one). A
decoder given the key refuses any other message as `unauthenticated`; one without the key accepts both forms
and checks no MAC (the tools, nodes started by hand without a key).

Statistics: diagnostic_msgs/DiagnosticArray holding one DiagnosticStatus whose `values` are KeyValue pairs.

Nodes publish `serialize(payload)`: for an array payload the bytes rclpy would make of `encode(payload)`,
built without a message object; they read with raw subscriptions, and every array decoder takes a message or
its serialized bytes alike.
"""

from __future__ import annotations

import math
import operator
import re
import struct
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Callable, Mapping

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Float64MultiArray, Int32MultiArray, MultiArrayDimension

from .auth import MAC_WORDS, mac_words
from .errors import WireError
from .payloads import (
    INT32_MAX, NO_ACTION, Action, AgentStats, Bounds, Feedback, Heartbeat, MarkedJointState, Position, WorldStats,
)

__all__ = [
    "ArrayLayout", "FEEDBACK_LAYOUT", "POSITION_LAYOUT", "ACTION_LAYOUT", "HEARTBEAT_LAYOUT", "ARRAY_LAYOUTS",
    "WORLD_STATS_NAME", "agent_stats_name", "WORLD_STATS_KEYS", "AGENT_STATS_KEYS",
    "encode_feedback", "decode_feedback", "encode_position", "decode_position",
    "encode_action", "decode_action", "encode_heartbeat", "decode_heartbeat", "encode_world_stats",
    "decode_world_stats", "encode_agent_stats", "decode_agent_stats", "encode", "serialize", "decode",
]


# --------------------------------------------------------------------------------------------------------
# Array layouts


@dataclass(frozen=True)
class ArrayLayout:
    """A 1-D MultiArray layout: which ROS type, which fields in which order, and what each field holds."""

    payload: type
    ros_type: type
    fields: tuple[str, ...]
    field_kinds: tuple[str, ...]  # "int" | "float" | "flag" per field
    meanings: tuple[str, ...]

    # Derived once per layout (cached_property: a codec call reads them several times per message).
    @cached_property
    def label(self) -> str:
        return ",".join(self.fields)

    @cached_property
    def size(self) -> int:
        return len(self.fields)

    @cached_property
    def keyed_label(self) -> str:
        """The label of the keyed form: the fields, then the MAC's words."""
        return ",".join(self.fields + tuple(f"mac{i}" for i in range(MAC_WORDS)))

    def dimension(self, keyed: bool) -> tuple[str, int]:
        """The label and size of the array's one dimension, in the keyed form (the MAC's words after the
        fields) or the plain one."""
        return (self.keyed_label, self.size + MAC_WORDS) if keyed else (self.label, self.size)

    @cached_property
    def _code(self) -> str:
        """The struct code of one value on the wire: int32 or float64."""
        return "i" if self.ros_type is Int32MultiArray else "d"

    @cached_property
    def _struct(self) -> struct.Struct:
        return struct.Struct(f"<{self.size}{self._code}")

    @cached_property
    def _values(self) -> Callable[[Any], tuple]:
        """payload -> its field values, in order."""
        return operator.attrgetter(*self.fields)

    @cached_property
    def _converters(self) -> tuple[tuple[str, Callable[[str, Any], Any]], ...]:
        return tuple((name, _CONVERT[kind]) for name, kind in zip(self.fields, self.field_kinds))

    def pack(self, values) -> bytes:
        """The field values as the MAC reads them (little-endian int32 or float64)."""
        return self._struct.pack(*values)

    def frame(self, keyed: bool) -> tuple[bytes, tuple[int, int], int, struct.Struct]:
        """The serialized form of this layout's messages (keyed or not): (the bytes before the values up to the
        data's length, with zeros for the alignment after the label; where that alignment lies, as a slice;
        the alignment bytes before the values; the values' Struct). All but the values and the alignment bytes
        (which rclpy's serializer leaves as they were in memory) is the same in every message of one form.
        Derived from rclpy's own serialization of one message, and checked against it."""
        return self._frames[keyed]

    @cached_property
    def _frames(self) -> dict[bool, tuple[bytes, tuple[int, int], int, struct.Struct]]:
        from rclpy.serialization import serialize_message

        frames = {}
        for keyed in (False, True):
            label, size = self.dimension(keyed)
            values = struct.Struct(f"<{size}{self._code}")
            msg = self.ros_type()
            msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=size)]
            msg.data = sample = [(i + 1) * 7 for i in range(size)]  # distinct values, to see where they lie
            raw = serialize_message(msg)
            start = len(raw) - values.size
            length = struct.pack("<I", size)  # the data's length, just before the values or their alignment
            pad = next((p for p in (0, 4) if raw[start - p - 4:start - p] == length), None)
            if pad is None or raw[start:] != values.pack(*sample):
                raise RuntimeError(f"{self.ros_type.__name__} {self.label}: its serialization does not end in "
                                   "its length and values")
            # CDR: a 4-byte header, the dimension count, the label's length, the label and its NUL, then
            # alignment to 4 bytes counted from after the header
            label_end = 12 + len(label) + 1
            gap = label_end, label_end + (4 - label_end) % 4
            head = bytearray(raw[:start - pad])
            head[gap[0]:gap[1]] = bytes(gap[1] - gap[0])
            frames[keyed] = bytes(head), gap, pad, values
        return frames


FEEDBACK_LAYOUT = ArrayLayout(
    Feedback, Float64MultiArray,
    ("agent", "episode", "step", "row", "col", "reward", "done", "truncated", "applied"),
    ("int", "int", "int", "int", "int", "float", "flag", "flag", "int"),
    ("agent id, 1..N (the topic's own agent)",
     "episode index, from 0",
     "step index within the episode, from 0 (0 = start observation)",
     "the agent's row at this step, 0..H-1 (0 = top)",
     "the agent's column at this step, 0..W-1",
     "reward of the transition into this step (0.0 at step 0); finite",
     "1.0 when the agent is at its goal (it sends no more actions this episode), else 0.0",
     "1.0 when the episode hit the step cap at this step (never with done), else 0.0",
     "the agent's action the world applied in the transition into this step, 0..3; -1 when it applied none "
     "(step 0, or no action within step_timeout: the agent stayed)"),
)
POSITION_LAYOUT = ArrayLayout(
    Position, Int32MultiArray,
    ("agent", "episode", "step", "row", "col"),
    ("int",) * 5,
    ("agent id, 1..N (the topic's own agent)",
     "episode index, from 0",
     "step index within the episode, from 0",
     "row, 0..H-1 (0 = top)",
     "column, 0..W-1"),
)
ACTION_LAYOUT = ArrayLayout(
    Action, Int32MultiArray,
    ("agent", "episode", "step", "action"),
    ("int",) * 4,
    ("agent id, 1..N (the topic's own agent)",
     "episode of the feedback this action answers",
     "step of the feedback this action answers",
     "0 NORTH (row-1), 1 EAST (col+1), 2 SOUTH (row+1), 3 WEST (col-1)"),
)
HEARTBEAT_LAYOUT = ArrayLayout(
    Heartbeat, Int32MultiArray,
    ("beat", "episode", "step"),
    ("int",) * 3,
    ("heartbeat number, from 1, one more each heartbeat",
     "episode the world is playing (0 before its first step)",
     "step whose actions the world is collecting (0 before its first step)"),
)
ARRAY_LAYOUTS: tuple[ArrayLayout, ...] = (FEEDBACK_LAYOUT, POSITION_LAYOUT, ACTION_LAYOUT, HEARTBEAT_LAYOUT)
_LAYOUT_BY_PAYLOAD = {lay.payload: lay for lay in ARRAY_LAYOUTS}
_LAYOUT_BY_WIRE = {(lay.ros_type, label): lay for lay in ARRAY_LAYOUTS for label in (lay.label, lay.keyed_label)}


# --------------------------------------------------------------------------------------------------------
# Value checks shared by encoders and decoders


def _as_int(name: str, v: Any) -> int:
    """An exact integer from an int-like or an integral finite float; else WireError."""
    if type(v) is int and -INT32_MAX - 1 <= v <= INT32_MAX:  # the common case, first
        return v
    if isinstance(v, bool):
        return int(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise WireError("not_finite", f"{name} = {v!r}")
        if v != int(v):
            raise WireError("not_integer", f"{name} = {v!r}")
        v = int(v)
    else:
        try:
            v = operator.index(v)
        except TypeError:
            raise WireError("not_integer", f"{name} = {v!r} ({type(v).__name__})") from None
    if not -INT32_MAX - 1 <= v <= INT32_MAX:
        raise WireError("out_of_range", f"{name} = {v} does not fit int32")
    return v


def _as_float(name: str, v: Any) -> float:
    if type(v) is float and math.isfinite(v):  # the common case, first
        return v
    if isinstance(v, (str, bytes)):
        raise WireError("malformed", f"{name} = {v!r} is not a number")
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise WireError("malformed", f"{name} = {v!r} is not a number") from None
    if not math.isfinite(f):
        raise WireError("not_finite", f"{name} = {f!r}")
    return f


def _as_flag(name: str, v: Any) -> bool:
    if isinstance(v, bool):
        return v
    if isinstance(v, float) and not math.isfinite(v):
        raise WireError("not_finite", f"{name} = {v!r}")
    if v == 0 or v == 1:
        return bool(v)
    raise WireError("malformed", f"flag {name} = {v!r}, must be 0 or 1")


_CONVERT: dict[str, Callable[[str, Any], Any]] = {"int": _as_int, "float": _as_float, "flag": _as_flag}


def _check_nonneg(name: str, v: int) -> None:
    if v < 0:
        raise WireError("out_of_range", f"{name} = {v} is negative")


def _check_agent(v: int, bounds: Bounds | None, agent: int | None, what: str = "agent") -> None:
    if v < 1 or (bounds is not None and v > bounds.n_agents):
        known = f"1..{bounds.n_agents}" if bounds is not None else ">= 1"
        raise WireError("unknown_agent", f"{what} {v}, known agents {known}")
    if agent is not None and v != agent:
        raise WireError("wrong_agent", f"{what} {v} on the topic of agent {agent}")


def _check_cell(row: int, col: int, bounds: Bounds | None, what: str = "cell") -> None:
    if row < 0 or col < 0 or (bounds is not None and (row >= bounds.rows or col >= bounds.cols)):
        grid = f"{bounds.rows}x{bounds.cols}" if bounds is not None else "grid"
        raise WireError("cell_out_of_range", f"{what} ({row}, {col}) outside the {grid} grid")


def check_sequence(ep: int, st: int | None, episode: int | None, step: int | None) -> None:
    """WireError stale_*/future_* when (ep, st) is not the expected (episode, step) (None: not checked)."""
    if episode is not None:
        if ep < episode:
            raise WireError("stale_episode", f"episode {ep}, expected {episode}")
        if ep > episode:
            raise WireError("future_episode", f"episode {ep}, expected {episode}")
    if step is not None and st is not None:
        if st < step:
            raise WireError("stale_step", f"episode {ep} step {st}, expected step {step}")
        if st > step:
            raise WireError("future_step", f"episode {ep} step {st}, expected step {step}")


def _validate(payload: Any, bounds: Bounds | None, agent: int | None,
              episode: int | None, step: int | None) -> None:
    """Semantic checks shared by the array payloads (values already typed)."""
    _check_nonneg("episode", payload.episode)
    _check_nonneg("step", payload.step)
    if isinstance(payload, Heartbeat):
        if payload.beat < 1:
            raise WireError("out_of_range", f"beat = {payload.beat}, must be >= 1")
        check_sequence(payload.episode, payload.step, episode, step)
        return
    _check_agent(payload.agent, bounds, agent)
    if isinstance(payload, Action):
        if not 0 <= payload.action <= 3:
            raise WireError("action_out_of_range", f"action {payload.action}, must be 0..3")
    else:
        _check_cell(payload.row, payload.col, bounds)
    if isinstance(payload, Feedback):
        if payload.done and payload.truncated:
            raise WireError("malformed", "done and truncated both set")
        if not NO_ACTION <= payload.applied <= 3:
            raise WireError("action_out_of_range", f"applied {payload.applied}, must be 0..3 or {NO_ACTION}")
    check_sequence(payload.episode, payload.step, episode, step)


# --------------------------------------------------------------------------------------------------------
# Array payloads


def _typed(layout: ArrayLayout, values) -> Any:
    return layout.payload(*[convert(name, v) for (name, convert), v in zip(layout._converters, values)])


def _mac_data(layout: ArrayLayout, words: tuple[int, ...]) -> list:
    """The MAC's words as the array's data holds them: int32 (two's complement) or whole float64."""
    if layout.ros_type is Float64MultiArray:
        return [float(w) for w in words]
    return [w - (1 << 32) if w > INT32_MAX else w for w in words]


def _wire_values(layout: ArrayLayout, payload: Any, key: bytes | None) -> list:
    """The array's data for `payload`: its checked field values, then the MAC's words when keyed."""
    if type(payload) is not layout.payload:
        raise WireError("wrong_type", f"expected {layout.payload.__name__}, got {type(payload).__name__}")
    typed = _typed(layout, layout._values(payload))
    _validate(typed, None, None, None, None)
    convert = float if layout.ros_type is Float64MultiArray else int
    data = [convert(v) for v in layout._values(typed)]
    if key is not None:
        data += _mac_data(layout, mac_words(key, layout.label, layout.pack(data)))
    return data


def _encode_array(layout: ArrayLayout, payload: Any, key: bytes | None = None) -> Any:
    data = _wire_values(layout, payload, key)
    label, size = layout.dimension(key is not None)
    msg = layout.ros_type()
    msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=size)]
    msg.layout.data_offset = 0
    msg.data = data
    return msg


def _decode_array(layout: ArrayLayout, msg: Any, bounds: Bounds | None, agent: int | None,
                  episode: int | None, step: int | None, key: bytes | None = None) -> Any:
    keyed, data = _raw_data(layout, msg) if type(msg) is bytes else _message_data(layout, msg)
    if key is not None:
        if not keyed:
            raise WireError("unauthenticated", f"no MAC ({layout.label}), and this receiver holds the run's key")
        try:
            expected = _mac_data(layout, mac_words(key, layout.label, layout.pack(data[:layout.size])))
        except struct.error:  # a value the wire type cannot hold: no MAC was made over it
            expected = None
        if expected != data[layout.size:]:
            raise WireError("unauthenticated", "the MAC does not match the run's key")
    payload = _typed(layout, data[:layout.size])
    _validate(payload, bounds, agent, episode, step)
    return payload


def _raw_data(layout: ArrayLayout, raw: bytes) -> tuple[bool, list]:
    """(keyed, data) of a serialized message (a raw subscription's): read straight from the bytes when they
    are in one of the layout's two forms (`ArrayLayout.frame`), else deserialized and checked as a message,
    so that anything else is refused exactly as the message would be."""
    for keyed in (True, False):
        head, (a, b), pad, values = layout.frame(keyed)
        if len(raw) == len(head) + pad + values.size and raw[:a] == head[:a] and raw[b:len(head)] == head[b:]:
            return keyed, list(values.unpack_from(raw, len(head) + pad))
    from rclpy.serialization import deserialize_message

    try:
        msg = deserialize_message(raw, layout.ros_type)
    except Exception as e:  # rclpy raises its own errors for bytes that are no such message
        raise WireError("malformed", f"not a serialized {layout.ros_type.__name__}: {e}") from None
    return _message_data(layout, msg)


def _message_data(layout: ArrayLayout, msg: Any) -> tuple[bool, list]:
    """(keyed, data) of a message, checked against the layout."""
    if type(msg) is not layout.ros_type:
        raise WireError("wrong_type", f"expected {layout.ros_type.__name__}, got {type(msg).__name__}")
    try:
        dims = list(msg.layout.dim)
        data = list(msg.data)
        offset = msg.layout.data_offset
    except (AttributeError, TypeError) as e:  # a hand-built message object with broken fields
        raise WireError("malformed", f"unreadable message: {e}") from None
    if len(dims) != 1:
        raise WireError("wrong_layout", f"{len(dims)} dims, expected 1 labelled {layout.label!r}")
    d = dims[0]
    keyed = d.label == layout.keyed_label
    if not keyed and d.label != layout.label:
        raise WireError("wrong_layout", f"label {d.label!r}, expected {layout.label!r}")
    _, size = layout.dimension(keyed)
    if d.size != size or d.stride != size or offset != 0:
        raise WireError("wrong_layout", f"size {d.size} stride {d.stride} data_offset {offset}, "
                                        f"expected {size} {size} 0")
    if len(data) != size:
        raise WireError("wrong_length", f"{len(data)} values, expected {size} ({d.label})")
    return keyed, data


def encode_feedback(fb: Feedback, *, key: bytes | None = None) -> Float64MultiArray:
    return _encode_array(FEEDBACK_LAYOUT, fb, key)


def decode_feedback(msg: Float64MultiArray | bytes, *, bounds: Bounds | None = None, agent: int | None = None,
                    episode: int | None = None, step: int | None = None,
                    key: bytes | None = None) -> Feedback:
    """Feedback from `msg`. `agent`: the topic's agent; `episode`/`step`: what the receiver waits for
    (None skips that check)."""
    return _decode_array(FEEDBACK_LAYOUT, msg, bounds, agent, episode, step, key)


def encode_position(pos: Position, *, key: bytes | None = None) -> Int32MultiArray:
    return _encode_array(POSITION_LAYOUT, pos, key)


def decode_position(msg: Int32MultiArray | bytes, *, bounds: Bounds | None = None, agent: int | None = None,
                    episode: int | None = None, step: int | None = None,
                    key: bytes | None = None) -> Position:
    """Position from `msg`. `agent`: the peer whose topic this is; `episode`/`step`: the step waited for."""
    return _decode_array(POSITION_LAYOUT, msg, bounds, agent, episode, step, key)


def encode_action(act: Action, *, key: bytes | None = None) -> Int32MultiArray:
    return _encode_array(ACTION_LAYOUT, act, key)


def decode_action(msg: Int32MultiArray | bytes, *, bounds: Bounds | None = None, agent: int | None = None,
                  episode: int | None = None, step: int | None = None,
                  key: bytes | None = None) -> Action:
    """Action from `msg`. `agent`: the topic's agent; `episode`/`step`: the step the world is collecting."""
    return _decode_array(ACTION_LAYOUT, msg, bounds, agent, episode, step, key)


def encode_heartbeat(hb: Heartbeat, *, key: bytes | None = None) -> Int32MultiArray:
    return _encode_array(HEARTBEAT_LAYOUT, hb, key)


def decode_heartbeat(msg: Int32MultiArray | bytes, *, after: int | None = None, key: bytes | None = None) -> Heartbeat:
    """Heartbeat from `msg`. `after`: the last beat heard; a beat not above it is `replayed`."""
    hb = _decode_array(HEARTBEAT_LAYOUT, msg, None, None, None, None, key)
    if after is not None and hb.beat <= after:
        raise WireError("replayed", f"beat {hb.beat}, the last one heard was {after}")
    return hb


# --------------------------------------------------------------------------------------------------------
# Statistics: DiagnosticArray with one DiagnosticStatus of KeyValue pairs

WORLD_STATS_NAME = "world/stats"


def agent_stats_name(agent: int) -> str:
    return f"agv{agent}/stats"


# key -> (kind, meaning). Per-agent and open-ended keys are described by pattern.
WORLD_STATS_KEYS: Mapping[str, tuple[str, str]] = {
    "episode": ("int", "episode index, from 0"),
    "steps": ("int", "joint steps taken in the episode"),
    "truncated": ("bool", "true when the step cap ended the episode"),
    "collisions": ("int", "collisions in the episode"),
    "missed_actions": ("int", "actions that missed the step timeout (the agent stayed)"),
    "duration_s": ("float", "wall-clock length of the episode, seconds"),
    "return.agv<k>": ("float", "undiscounted return of agent k, one key per agent 1..N"),
    "count.<name>": ("int", "further monotonic counters, e.g. count.dropped.stale_step"),
}
AGENT_STATS_KEYS: Mapping[str, tuple[str, str]] = {
    "agent": ("int", "agent id, 1..N"),
    "episode": ("int", "episode that just ended for this agent"),
    "algorithm": ("str", "learner name, e.g. cq, indep, js, loc"),
    "joint_plays": ("int", "times this episode the agent used global information / chose COORDINATE"),
    "local_states": ("int", "local states in use"),
    "joint_states": ("int", "joint states in use"),
    "subscriptions_created": ("int", "peer position subscriptions created since start"),
    "subscriptions_active": ("int", "peer position subscriptions alive now"),
    "peer_messages": ("int", "peer position messages received since start"),
    "marked.<i>": ("str", "marked joint state i (0..M-1): "
                          "'cell=R,C peer=agvJ peer_cell=R,C confidence=X'"),
    "count.<name>": ("int", "further monotonic counters, e.g. count.dropped.stale_step"),
}

_INT_RE = re.compile(r"-?[0-9]+")
_NAME_RE = re.compile(r"[a-z0-9_][a-z0-9_.]*")
_ALGO_RE = re.compile(r"[a-z][a-z0-9_]*")
_RETURN_RE = re.compile(r"return\.agv([1-9][0-9]*)")
_MARKED_KEY_RE = re.compile(r"marked\.(0|[1-9][0-9]*)")
_MARKED_RE = re.compile(
    r"cell=([0-9]+),([0-9]+) peer=agv([0-9]+) peer_cell=([0-9]+),([0-9]+) confidence=(\S+)")


def _fmt_float(v: float) -> str:
    return repr(float(v))  # shortest string that reads back to the same double


def _parse_int(key: str, s: str) -> int:
    if not _INT_RE.fullmatch(s):
        try:  # tell a fraction or NaN apart from garbage
            f = float(s)
        except ValueError:
            raise WireError("malformed", f"{key} = {s!r} is not an integer") from None
        if not math.isfinite(f):
            raise WireError("not_finite", f"{key} = {s!r}")
        raise WireError("not_integer", f"{key} = {s!r}")
    return _as_int(key, int(s))


def _parse_float(key: str, s: str) -> float:
    try:
        f = float(s)
    except ValueError:
        raise WireError("malformed", f"{key} = {s!r} is not a number") from None
    if not math.isfinite(f):
        raise WireError("not_finite", f"{key} = {s!r}")
    return f


def _parse_bool(key: str, s: str) -> bool:
    if s == "true":
        return True
    if s == "false":
        return False
    raise WireError("malformed", f"{key} = {s!r}, must be true or false")


def _counter_pairs(counters: Mapping[str, int]) -> list[tuple[str, str]]:
    out = []
    for name in sorted(counters):
        if not isinstance(name, str) or not _NAME_RE.fullmatch(name):
            raise WireError("malformed", f"counter name {name!r} must match {_NAME_RE.pattern}")
        v = _as_int(f"count.{name}", counters[name])
        _check_nonneg(f"count.{name}", v)
        out.append((f"count.{name}", str(v)))
    return out


def _stats_msg(name: str, hardware_id: str, summary: str, pairs: list[tuple[str, str]],
               stamp: Time | None) -> DiagnosticArray:
    status = DiagnosticStatus(level=DiagnosticStatus.OK, name=name, message=summary, hardware_id=hardware_id,
                              values=[KeyValue(key=k, value=v) for k, v in pairs])
    arr = DiagnosticArray(status=[status])
    if stamp is not None:
        arr.header.stamp = stamp
    return arr


def _stats_values(msg: Any) -> tuple[str, str, dict[str, str]]:
    """(status name, hardware_id, key -> value) of a one-status DiagnosticArray; rejects repeated keys."""
    if type(msg) is not DiagnosticArray:
        raise WireError("wrong_type", f"expected DiagnosticArray, got {type(msg).__name__}")
    try:
        statuses = list(msg.status)
        if len(statuses) != 1:
            raise WireError("wrong_layout", f"{len(statuses)} statuses, expected exactly 1")
        st = statuses[0]
        values: dict[str, str] = {}
        for kv in st.values:
            if kv.key in values:
                raise WireError("malformed", f"key {kv.key!r} repeated")
            values[kv.key] = kv.value
        return st.name, st.hardware_id, values
    except (AttributeError, TypeError) as e:
        raise WireError("malformed", f"unreadable message: {e}") from None


def _take(values: dict[str, str], key: str) -> str:
    try:
        return values.pop(key)
    except KeyError:
        raise WireError("malformed", f"key {key!r} missing") from None


def _take_counters(values: dict[str, str]) -> dict[str, int]:
    counters = {}
    for key in [k for k in values if k.startswith("count.")]:
        name = key[len("count."):]
        if not _NAME_RE.fullmatch(name):
            raise WireError("malformed", f"counter key {key!r}")
        v = _parse_int(key, values.pop(key))
        _check_nonneg(key, v)
        counters[name] = v
    return counters


def _no_leftovers(values: dict[str, str]) -> None:
    if values:
        raise WireError("malformed", f"unknown keys {sorted(values)}")


def encode_world_stats(s: WorldStats, *, stamp: Time | None = None) -> DiagnosticArray:
    """`stamp`: header time (wall clock, e.g. node.get_clock().now().to_msg()); zero if None."""
    if type(s) is not WorldStats:
        raise WireError("wrong_type", f"expected WorldStats, got {type(s).__name__}")
    ints = {k: _as_int(k, getattr(s, k)) for k in ("episode", "steps", "collisions", "missed_actions")}
    for k, v in ints.items():
        _check_nonneg(k, v)
    truncated = _as_flag("truncated", s.truncated)
    returns = [_as_float(f"return.agv{i + 1}", r) for i, r in enumerate(s.returns)]
    if not returns:
        raise WireError("malformed", "returns is empty (one per agent)")
    duration = _as_float("duration_s", s.duration_s)
    if duration < 0:
        raise WireError("out_of_range", f"duration_s = {duration}")
    pairs = [("episode", str(ints["episode"])), ("steps", str(ints["steps"])),
             ("truncated", "true" if truncated else "false"), ("collisions", str(ints["collisions"])),
             ("missed_actions", str(ints["missed_actions"])), ("duration_s", _fmt_float(duration))]
    pairs += [(f"return.agv{i + 1}", _fmt_float(r)) for i, r in enumerate(returns)]
    pairs += _counter_pairs(s.counters)
    end = "truncated at the step cap" if truncated else "all agents at their goals"
    summary = (f"episode {ints['episode']}: {ints['steps']} steps, {ints['collisions']} collisions, "
               f"{ints['missed_actions']} missed actions, {end}")
    return _stats_msg(WORLD_STATS_NAME, "world", summary, pairs, stamp)


def decode_world_stats(msg: DiagnosticArray, *, bounds: Bounds | None = None,
                       episode: int | None = None) -> WorldStats:
    name, hw, values = _stats_values(msg)
    if name != WORLD_STATS_NAME or hw != "world":
        raise WireError("wrong_layout", f"status name {name!r} hardware_id {hw!r}, "
                                        f"expected {WORLD_STATS_NAME!r} 'world'")
    ints = {}
    for k in ("episode", "steps", "collisions", "missed_actions"):
        ints[k] = _parse_int(k, _take(values, k))
        _check_nonneg(k, ints[k])
    truncated = _parse_bool("truncated", _take(values, "truncated"))
    duration = _parse_float("duration_s", _take(values, "duration_s"))
    if duration < 0:
        raise WireError("out_of_range", f"duration_s = {duration}")
    found = {}
    for key in [k for k in values if k.startswith("return.")]:
        m = _RETURN_RE.fullmatch(key)
        if not m:
            raise WireError("malformed", f"key {key!r}, expected return.agv<k>")
        found[int(m.group(1))] = _parse_float(key, values.pop(key))
    n = len(found)
    if n == 0 or set(found) != set(range(1, n + 1)):
        raise WireError("malformed", f"return keys for agents {sorted(found)}, expected 1..{n or 'N'}")
    if bounds is not None and n != bounds.n_agents:
        raise WireError("unknown_agent" if n > bounds.n_agents else "malformed",
                        f"returns for {n} agents, the world has {bounds.n_agents}")
    counters = _take_counters(values)
    _no_leftovers(values)
    check_sequence(ints["episode"], None, episode, None)
    return WorldStats(episode=ints["episode"], steps=ints["steps"], truncated=truncated,
                      collisions=ints["collisions"], missed_actions=ints["missed_actions"],
                      returns=tuple(found[k] for k in range(1, n + 1)), duration_s=duration,
                      counters=counters)


_AGENT_INT_KEYS = ("agent", "episode", "joint_plays", "local_states", "joint_states",
                   "subscriptions_created", "subscriptions_active", "peer_messages")


def _check_marked(m: MarkedJointState, agent: int, bounds: Bounds | None, where: str) -> MarkedJointState:
    if type(m) is not MarkedJointState:
        raise WireError("wrong_type", f"{where}: expected MarkedJointState, got {type(m).__name__}")
    row, col, peer, prow, pcol = (_as_int(f"{where}.{f}", getattr(m, f))
                                  for f in ("row", "col", "peer", "peer_row", "peer_col"))
    conf = _as_float(f"{where}.confidence", m.confidence)
    _check_cell(row, col, bounds, f"{where} cell")
    _check_agent(peer, bounds, None, f"{where} peer")
    if peer == agent:
        raise WireError("malformed", f"{where}: peer {peer} is the agent itself")
    _check_cell(prow, pcol, bounds, f"{where} peer cell")
    return MarkedJointState(row, col, peer, prow, pcol, conf)


def encode_agent_stats(s: AgentStats, *, stamp: Time | None = None) -> DiagnosticArray:
    if type(s) is not AgentStats:
        raise WireError("wrong_type", f"expected AgentStats, got {type(s).__name__}")
    ints = {k: _as_int(k, getattr(s, k)) for k in _AGENT_INT_KEYS}
    _check_agent(ints["agent"], None, None)
    for k in _AGENT_INT_KEYS[1:]:
        _check_nonneg(k, ints[k])
    if not isinstance(s.algorithm, str) or not _ALGO_RE.fullmatch(s.algorithm):
        raise WireError("malformed", f"algorithm {s.algorithm!r} must match {_ALGO_RE.pattern}")
    marked = [_check_marked(m, ints["agent"], None, f"marked.{i}") for i, m in enumerate(s.marked)]
    pairs = [(k, str(ints[k])) for k in _AGENT_INT_KEYS[:2]] + [("algorithm", s.algorithm)]
    pairs += [(k, str(ints[k])) for k in _AGENT_INT_KEYS[2:]]
    pairs += [(f"marked.{i}", f"cell={m.row},{m.col} peer=agv{m.peer} peer_cell={m.peer_row},{m.peer_col} "
                              f"confidence={_fmt_float(m.confidence)}") for i, m in enumerate(marked)]
    pairs += _counter_pairs(s.counters)
    summary = (f"agv{ints['agent']} ({s.algorithm}) episode {ints['episode']}: {ints['joint_plays']} joint "
               f"plays, {len(marked)} marked joint states, {ints['subscriptions_active']} live subscriptions")
    return _stats_msg(agent_stats_name(ints["agent"]), f"agv{ints['agent']}", summary, pairs, stamp)


def decode_agent_stats(msg: DiagnosticArray, *, bounds: Bounds | None = None, agent: int | None = None,
                       episode: int | None = None) -> AgentStats:
    name, hw, values = _stats_values(msg)
    m = re.fullmatch(r"agv([0-9]+)/stats", name)
    if not m or hw != f"agv{m.group(1)}":
        raise WireError("wrong_layout", f"status name {name!r} hardware_id {hw!r}, "
                                        "expected 'agv<k>/stats' 'agv<k>'")
    ints = {}
    for k in _AGENT_INT_KEYS:
        ints[k] = _parse_int(k, _take(values, k))
    _check_agent(ints["agent"], bounds, agent)
    if int(m.group(1)) != ints["agent"]:
        raise WireError("wrong_agent", f"status {name!r} carries agent {ints['agent']}")
    for k in _AGENT_INT_KEYS[1:]:
        _check_nonneg(k, ints[k])
    algorithm = _take(values, "algorithm")
    if not _ALGO_RE.fullmatch(algorithm):
        raise WireError("malformed", f"algorithm {algorithm!r}")
    found = {}
    for key in [k for k in values if k.startswith("marked.")]:
        km = _MARKED_KEY_RE.fullmatch(key)
        if not km:
            raise WireError("malformed", f"key {key!r}, expected marked.<i>")
        text = values.pop(key)
        vm = _MARKED_RE.fullmatch(text)
        if not vm:
            raise WireError("malformed", f"{key} = {text!r}")
        r, c, p, pr, pc = (_as_int(key, int(g)) for g in vm.groups()[:5])
        conf = _parse_float(f"{key}.confidence", vm.group(6))
        found[int(km.group(1))] = _check_marked(MarkedJointState(r, c, p, pr, pc, conf), ints["agent"],
                                                bounds, key)
    if set(found) != set(range(len(found))):
        raise WireError("malformed", f"marked indices {sorted(found)}, expected 0..{len(found) - 1}")
    counters = _take_counters(values)
    _no_leftovers(values)
    check_sequence(ints["episode"], None, episode, None)
    return AgentStats(agent=ints["agent"], episode=ints["episode"], algorithm=algorithm,
                      joint_plays=ints["joint_plays"], local_states=ints["local_states"],
                      joint_states=ints["joint_states"], subscriptions_created=ints["subscriptions_created"],
                      subscriptions_active=ints["subscriptions_active"], peer_messages=ints["peer_messages"],
                      marked=tuple(found[i] for i in range(len(found))), counters=counters)


# --------------------------------------------------------------------------------------------------------
# Generic entry points

_STATS_ENCODERS: dict[type, Callable[..., Any]] = {WorldStats: encode_world_stats, AgentStats: encode_agent_stats}


def encode(payload: Any, *, key: bytes | None = None, stamp: Time | None = None) -> Any:
    """The ROS message for any payload: `key` keys an array payload (msgs_spec.auth; statistics carry no MAC),
    `stamp` is the header time of statistics."""
    if type(payload) in _LAYOUT_BY_PAYLOAD:
        return _encode_array(_LAYOUT_BY_PAYLOAD[type(payload)], payload, key)
    try:
        enc = _STATS_ENCODERS[type(payload)]
    except KeyError:
        raise WireError("wrong_type", f"no wire encoding for {type(payload).__name__}") from None
    return enc(payload, stamp=stamp)


def serialize(payload: Any, *, key: bytes | None = None) -> Any:
    """What a node publishes for `payload` (rclpy's Publisher.publish takes either): for an array payload the
    bytes rclpy would serialize `encode(payload, key=key)` to (alignment bytes zero), built without a message
    object; for statistics the message. Either way the same message goes on the wire."""
    layout = _LAYOUT_BY_PAYLOAD.get(type(payload))
    if layout is None:
        return encode(payload, key=key)
    head, _, pad, values = layout.frame(key is not None)
    return head + bytes(pad) + values.pack(*_wire_values(layout, payload, key))


def decode(msg: Any, *, bounds: Bounds | None = None, agent: int | None = None,
           episode: int | None = None, step: int | None = None, key: bytes | None = None) -> Any:
    """Decode any project message, recognising the payload from the ROS type and the layout label or status
    name (messages are self-describing). Expectations that do not apply to the payload are ignored
    (`step` for statistics, `agent` for world statistics; `key` for statistics, which carry no MAC)."""
    t = type(msg)
    if t is DiagnosticArray:
        try:
            name = msg.status[0].name if len(msg.status) == 1 else ""
        except (AttributeError, TypeError, IndexError):
            name = ""
        if name == WORLD_STATS_NAME:
            return decode_world_stats(msg, bounds=bounds, episode=episode)
        return decode_agent_stats(msg, bounds=bounds, agent=agent, episode=episode)
    if t in (Float64MultiArray, Int32MultiArray):
        try:
            label = msg.layout.dim[0].label if len(msg.layout.dim) == 1 else None
        except (AttributeError, TypeError, IndexError):
            label = None
        layout = _LAYOUT_BY_WIRE.get((t, label))
        if layout is None:
            raise WireError("wrong_layout", f"{t.__name__} with label {label!r} is no project payload")
        return _decode_array(layout, msg, bounds, agent, episode, step, key)
    raise WireError("wrong_type", f"{t.__module__}.{t.__name__} is no project message type")

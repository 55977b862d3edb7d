"""The array payloads' codec (feedback, positions, actions, heartbeats): their layouts on the std_msgs
MultiArray types, encode and serialize with the run's MAC, decode with every check.

Every decoder validates and raises only `WireError` for any input (whatever the message holds), with the
first failing check in this order: type, layout, length, numbers (finite, integer, int32 range), agent id,
action / cell range, episode, step. Serialized bytes longer than any message of the layout are judged from
their header alone (`_oversized`), never deserialized: a flood's large junk costs what a small one does.
Encoders refuse what no decoder would accept (bad values, not context), so a sender's bug shows at the sender.

Array layouts (one dimension; its label lists the fields in order, so `ros2 topic echo` is self-describing):

    Feedback  std_msgs/Float64MultiArray  label "agent,episode,step,row,col,reward,done,truncated,applied"
    Position  std_msgs/Int32MultiArray    label "agent,episode,step,row,col"
    Action    std_msgs/Int32MultiArray    label "agent,episode,step,action"
    Heartbeat std_msgs/Int32MultiArray    label "beat,episode,step,stepping,started,ticket"

Keyed (msgs_spec.auth): with the run's key the label ends in ",run0,run1,inc,mac0,mac1,mac2,mac3" and the
data holds, after the fields, the seal (the run nonce's high and low 32-bit words, the sender's incarnation)
and the MAC's four 32-bit words over the fields and the seal (each word as int32 in an Int32 array, as a whole
number in a Float64 one). A decoder given the key refuses any other message as `unauthenticated`, then a seal
its RunKey does not hold as `other_run` / `other_incarnation`; one without the key accepts both forms and
checks neither (the tools, nodes started by hand without a key). A bare key (bytes) seals with run and
incarnation 0 and checks the MAC only.

This module is the reference codec: straightforward, every check in the order above. msgs_spec.fast is the
one nodes call; it agrees with this one on every input (tests/test_msgs_spec.py) and hands it whatever it is
not sure of.

Nodes publish `serialize(payload)`: for an array payload the bytes rclpy would make of `encode(payload)`,
built without a message object; they read with raw subscriptions, and every array decoder takes a message or
its serialized bytes alike.
"""

from __future__ import annotations

import math
import operator
import struct
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Callable

from std_msgs.msg import Float64MultiArray, Int32MultiArray, MultiArrayDimension

from .auth import MAC_WORDS, SEAL_WORDS, WORLD, RunKey, mac_words
from .checks import CONVERT, check_agent, check_cell, check_nonneg, check_sequence
from .errors import WireError
from .payloads import INT32_MAX, NO_ACTION, Action, Bounds, Feedback, Heartbeat, Position

__all__ = [
    "ArrayLayout", "FEEDBACK_LAYOUT", "POSITION_LAYOUT", "ACTION_LAYOUT", "HEARTBEAT_LAYOUT", "ARRAY_LAYOUTS",
    "LAYOUT_BY_PAYLOAD", "LAYOUT_BY_WIRE", "encode_array", "decode_array", "serialize_array",
    "encode_feedback", "decode_feedback", "encode_position", "decode_position",
    "encode_action", "decode_action", "encode_heartbeat", "decode_heartbeat",
]



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
        """The label of the keyed form: the fields, the seal's words, then the MAC's."""
        return ",".join(self.fields + ("run0", "run1", "inc") + tuple(f"mac{i}" for i in range(MAC_WORDS)))

    def dimension(self, keyed: bool) -> tuple[str, int]:
        """The label and size of the array's one dimension, in the keyed form (the seal's and the MAC's words
        after the fields) or the plain one."""
        return (self.keyed_label, self.size + SEAL_WORDS + MAC_WORDS) if keyed else (self.label, self.size)

    @cached_property
    def from_agent(self) -> bool:
        """An agent sends it (its sender in a RunKey is the topic's agent); else the world does."""
        return self.payload is Action

    @cached_property
    def _seal_struct(self) -> struct.Struct:
        """The seal's words as the data holds them (as _mac_struct)."""
        return struct.Struct(f"<{SEAL_WORDS}{'I' if self._code == 'i' else 'd'}")

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
        return tuple((name, CONVERT[kind]) for name, kind in zip(self.fields, self.field_kinds))

    @cached_property
    def _types(self) -> tuple[type, ...]:
        """The exact Python type of each field's value in a payload built as the nodes build them."""
        return tuple({"int": int, "float": float, "flag": bool}[kind] for kind in self.field_kinds)

    @cached_property
    def _ints(self) -> tuple[Callable[[tuple], Any], struct.Struct]:
        """(the int fields' values of a values tuple, their int32 Struct): packing them checks their range."""
        at = [i for i, kind in enumerate(self.field_kinds) if kind == "int"]
        return (lambda values: tuple(values[i] for i in at)), struct.Struct(f"<{len(at)}i")

    @cached_property
    def _floats_at(self) -> tuple[int, ...]:
        return tuple(i for i, kind in enumerate(self.field_kinds) if kind == "float")

    @cached_property
    def _mac_struct(self) -> struct.Struct:
        """The MAC's words as the data holds them: int32 (two's complement: the unsigned word's bytes) or whole
        float64."""
        return struct.Struct(f"<{MAC_WORDS}{'I' if self._code == 'i' else 'd'}")

    def packed(self, payload: Any) -> tuple[tuple, bytes]:
        """(field values, their packed bytes) of a payload of this layout, checked as a decoder would check
        them (WireError otherwise): the MAC is made over the bytes, which the wire carries as they are."""
        if type(payload) is not self.payload:
            raise WireError("wrong_type", f"expected {self.payload.__name__}, got {type(payload).__name__}")
        values = self._values(payload)
        if not self._plain(values):  # converted (e.g. numpy numbers, a whole float), or the check's own error
            payload = _typed(self, values)
            values = self._values(payload)
        _validate(payload, None, None, None, None)
        return values, self._struct.pack(*values)

    def _plain(self, values: tuple) -> bool:
        """Every value of exactly its field's type, the ints in int32 range, the floats finite: as _typed would
        give them back."""
        if tuple(map(type, values)) != self._types:
            return False
        ints, int32 = self._ints
        try:
            int32.pack(*ints(values))
        except struct.error:
            return False
        return all(math.isfinite(values[i]) for i in self._floats_at)

    def from_floats(self, values: tuple) -> Any:
        """The payload of a float64 array's field values when each is what its field holds (a whole number in
        int32 range, a finite float, a flag 0 or 1): as _typed gives it, in one pass; None otherwise (then
        _typed says which check fails, in the decoders' order)."""
        out = []
        for v, kind in zip(values, self.field_kinds):
            if kind == "int":
                if not (-INT32_MAX - 1 <= v <= INT32_MAX and v.is_integer()):
                    return None
                out.append(int(v))
            elif kind == "float":
                if not math.isfinite(v):
                    return None
                out.append(v)
            elif v == 1.0 or v == 0.0:
                out.append(v == 1.0)
            else:
                return None
        return self.payload(*out)

    def pack(self, values) -> bytes:
        """The field values as the MAC reads them (little-endian int32 or float64)."""
        return self._struct.pack(*values)

    @cached_property
    def _longest(self) -> int:
        """The length of the layout's longer serialized form, the keyed one: no message of it is longer."""
        head, _, pad, values = self.frame(True)
        return len(head) + pad + values.size

    def frame(self, keyed: bool) -> tuple[bytes, tuple[int, int], int, struct.Struct]:
        """The serialized form of this layout's messages (keyed or not): (the bytes before the values up to the
        data's length, with zeros for the alignment after the label; where that alignment lies, as a slice;
        the alignment bytes before the values; the values' Struct). All but the values and the alignment bytes
        (which rclpy's serializer leaves as they were in memory) is the same in every message of one form.
        Written out from CDR here, without rclpy (the contract's codec loads none); tests/test_msgs_spec.py
        checks serialize() against rclpy's own bytes for every form."""
        return self._frames[keyed]

    @cached_property
    def _frames(self) -> dict[bool, tuple[bytes, tuple[int, int], int, struct.Struct]]:
        frames = {}
        for keyed in (False, True):
            label, size = self.dimension(keyed)
            values = struct.Struct(f"<{size}{self._code}")
            text = label.encode("ascii") + b"\0"
            # CDR, little-endian: the encapsulation header, the dimension count, the label (its length with its
            # NUL, then it), alignment to 4 bytes counted from after the header, the dimension's size and
            # stride, the layout's data_offset (0), the data's length; then alignment to a value's size
            head = b"\x00\x01\x00\x00" + struct.pack("<II", 1, len(text)) + text
            gap = len(head), len(head) + (4 - len(head)) % 4
            head += bytes(gap[1] - gap[0]) + struct.pack("<IIII", size, size, 0, size)
            pad = -(len(head) - 4) % struct.calcsize(f"<{self._code}")
            frames[keyed] = head, gap, pad, values
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
    ("beat", "episode", "step", "stepping", "started", "ticket"),
    ("int",) * 6,
    ("heartbeat number, from 1, one more each heartbeat",
     "episode the world is playing (0 before its first step)",
     "step whose actions the world is collecting (0 before its first step)",
     "1 once the world has begun stepping, 0 while it waits for its agents",
     "the second the world started, Unix time (as builtin_interfaces/Time.sec)",
     "a number the world drew at its start, 0..2**31-1: orders two worlds started in the same second"),
)
ARRAY_LAYOUTS: tuple[ArrayLayout, ...] = (FEEDBACK_LAYOUT, POSITION_LAYOUT, ACTION_LAYOUT, HEARTBEAT_LAYOUT)
LAYOUT_BY_PAYLOAD = {lay.payload: lay for lay in ARRAY_LAYOUTS}
LAYOUT_BY_WIRE = {(lay.ros_type, label): lay for lay in ARRAY_LAYOUTS for label in (lay.label, lay.keyed_label)}



def _validate(payload: Any, bounds: Bounds | None, agent: int | None,
              episode: int | None, step: int | None) -> None:
    """Semantic checks shared by the array payloads (values already typed)."""
    check_nonneg("episode", payload.episode)
    check_nonneg("step", payload.step)
    if isinstance(payload, Heartbeat):
        if payload.beat < 1:
            raise WireError("out_of_range", f"beat = {payload.beat}, must be >= 1")
        if payload.stepping not in (0, 1):
            raise WireError("out_of_range", f"stepping = {payload.stepping}, must be 0 or 1")
        check_nonneg("started", payload.started)
        check_nonneg("ticket", payload.ticket)
        check_sequence(payload.episode, payload.step, episode, step)
        return
    check_agent(payload.agent, bounds, agent)
    if isinstance(payload, Action):
        if not 0 <= payload.action <= 3:
            raise WireError("action_out_of_range", f"action {payload.action}, must be 0..3")
    else:
        check_cell(payload.row, payload.col, bounds)
    if isinstance(payload, Feedback):
        if payload.done and payload.truncated:
            raise WireError("malformed", "done and truncated both set")
        if not NO_ACTION <= payload.applied <= 3:
            raise WireError("action_out_of_range", f"applied {payload.applied}, must be 0..3 or {NO_ACTION}")
    check_sequence(payload.episode, payload.step, episode, step)




def _typed(layout: ArrayLayout, values) -> Any:
    return layout.payload(*[convert(name, v) for (name, convert), v in zip(layout._converters, values)])


def _mac_data(layout: ArrayLayout, words: tuple[int, ...]) -> list:
    """The MAC's words as the array's data holds them: int32 (two's complement) or whole float64."""
    if layout.ros_type is Float64MultiArray:
        return [float(w) for w in words]
    return [w - (1 << 32) if w > INT32_MAX else w for w in words]


def _mac(layout: ArrayLayout, key: bytes, packed: bytes) -> bytes:
    """The MAC of the packed values and seal, as the bytes that follow them on the wire."""
    return layout._mac_struct.pack(*mac_words(key, layout.label, packed))


def _seal_words(key: bytes | RunKey) -> tuple[bytes, tuple[int, int, int]]:
    """(the secret, the seal's words: run high, run low, incarnation) a sender seals with."""
    if type(key) is not RunKey:
        return key, (0, 0, 0)
    if key.run is None:  # an agent acts only on a sealed feedback, which binds the run first
        raise ValueError("no run nonce yet: a node seals only after it knows its run")
    return key.secret, (key.run >> 32, key.run & 0xFFFFFFFF, key.incarnation)


def _sealed(layout: ArrayLayout, key: bytes | RunKey, packed: bytes) -> bytes:
    """The values' bytes, the seal and the MAC over both: what follows the frame on the wire."""
    secret, words = _seal_words(key)
    body = packed + layout._seal_struct.pack(*words)
    return body + _mac(layout, secret, body)


def _wire_values(layout: ArrayLayout, payload: Any, key: bytes | RunKey | None) -> list:
    """The array's data for `payload` (as a message object holds it): its checked field values, then the
    seal's and the MAC's words when keyed."""
    values, packed = layout.packed(payload)
    convert = float if layout.ros_type is Float64MultiArray else int
    data = [convert(v) for v in values]
    if key is not None:
        tail = _sealed(layout, key, packed)[len(packed):]
        data += _mac_data(layout, struct.unpack(f"<{SEAL_WORDS + MAC_WORDS}{layout._seal_struct.format[-1]}", tail))
    return data


def encode_array(layout: ArrayLayout, payload: Any, key: bytes | None = None) -> Any:
    data = _wire_values(layout, payload, key)
    label, size = layout.dimension(key is not None)
    msg = layout.ros_type()
    msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=size)]
    msg.layout.data_offset = 0
    msg.data = data
    return msg


def serialize_array(layout: ArrayLayout, payload: Any, key: bytes | RunKey | None = None) -> bytes:
    """The bytes rclpy would serialize `encode_array(layout, payload, key)` to (alignment bytes zero): the
    layout's frame, the packed values, then keyed the seal and the MAC over those very bytes."""
    head, _, pad, _ = layout.frame(key is not None)
    _, packed = layout.packed(payload)
    return head + bytes(pad) + (_sealed(layout, key, packed) if key is not None else packed)


def decode_array(layout: ArrayLayout, msg: Any, bounds: Bounds | None, agent: int | None,
                 episode: int | None, step: int | None, key: bytes | RunKey | None = None) -> Any:
    framed = _framed(layout, msg) if type(msg) is bytes else None
    seal = None
    if framed is not None:  # the bytes as our nodes send them: values, seal and MAC read and checked in place
        keyed, start = framed
        end = start + layout._struct.size
        if key is not None:
            if not keyed:
                raise WireError("unauthenticated", f"no MAC ({layout.label}), and this receiver holds the run's key")
            sealed_end = end + layout._seal_struct.size
            if _mac(layout, _secret(key), msg[start:sealed_end]) != msg[sealed_end:]:
                raise WireError("unauthenticated", "the MAC does not match the run's key")
            seal = _check_seal(layout, key, layout._seal_struct.unpack_from(msg, end), msg, agent, start)
        values = layout._struct.unpack_from(msg, start)
        # int32 values read from the wire are ints in range: only a float64 layout's need converting
        payload = layout.payload(*values) if layout._code == "i" else (layout.from_floats(values)
                                                                        or _typed(layout, values))
    else:
        if type(msg) is bytes and len(msg) > layout._longest:  # no message of the layout: refused unread
            refusal = _oversized(layout, msg)
            if refusal is not None:
                raise refusal
        keyed, data = _message_data(layout, _deserialized(layout, msg) if type(msg) is bytes else msg)
        if key is not None:
            if not keyed:
                raise WireError("unauthenticated", f"no MAC ({layout.label}), and this receiver holds the run's key")
            sealed = data[:layout.size + SEAL_WORDS]
            try:
                body = layout.pack(data[:layout.size]) + layout._seal_struct.pack(
                    *[w & 0xFFFFFFFF if layout._code == "i" else w for w in sealed[layout.size:]])
                expected = _mac_data(layout, mac_words(_secret(key), layout.label, body))
            except struct.error:  # a value the wire type cannot hold: no MAC was made over it
                expected = None
            if expected != data[layout.size + SEAL_WORDS:]:
                raise WireError("unauthenticated", "the MAC does not match the run's key")
            words = layout._seal_struct.unpack_from(body, layout._struct.size)
            seal = _check_seal(layout, key, words, body, agent, 0)
        payload = _typed(layout, data[:layout.size])
    _validate(payload, bounds, agent, episode, step)
    if seal is not None:  # bound only by a message every check accepted
        key.accept(*seal)
    return payload


def _secret(key: bytes | RunKey) -> bytes:
    return key.secret if type(key) is RunKey else key


def _check_seal(layout: ArrayLayout, key: bytes | RunKey, words: tuple, values: bytes, agent: int | None,
                start: int) -> tuple[int, int, int] | None:
    """(run, incarnation, sender) of a sealed message whose MAC matched, for `key.accept` once every check
    passed; WireError other_run / other_incarnation when `key` holds another. None for a bare key (it checks
    the MAC only). `values`: bytes holding the packed values at `start` (an action's sender is the topic's
    agent, else the agent it names)."""
    if type(key) is not RunKey:
        return None
    run, incarnation = (int(words[0]) << 32) | int(words[1]), int(words[2])
    sender = WORLD
    if layout.from_agent:
        sender = agent if agent is not None else layout._struct.unpack_from(values, start)[0]
    refusal = key.refusal(run, incarnation, sender)
    if refusal is not None:
        raise WireError(*refusal)
    return run, incarnation, sender


def _framed(layout: ArrayLayout, raw: bytes) -> tuple[bool, int] | None:
    """(keyed, where the values start) when a serialized message (a raw subscription's) is in one of the
    layout's two forms (`ArrayLayout.frame`); None otherwise."""
    for keyed in (True, False):
        head, (a, b), pad, values = layout.frame(keyed)
        if len(raw) == len(head) + pad + values.size and raw[:a] == head[:a] and raw[b:len(head)] == head[b:]:
            return keyed, len(head) + pad
    return None


def _oversized(layout: ArrayLayout, raw: bytes) -> WireError | None:
    """The refusal of serialized bytes longer than the layout's keyed form, which no message of the layout is
    (a flood's 20,000 values, a 10 KB label), read from the CDR header alone, as _message_data would word it
    for the message: dims, label, size, stride, data_offset, the data's length; its values are never read.
    None for bytes whose header is the layout's own (then only what follows can be wrong: deserialized)."""
    try:
        dims, n = struct.unpack_from("<2I", raw, 4)
        if dims != 1:
            return WireError("wrong_layout", f"{dims} dims, expected 1 labelled {layout.label!r}")
        if not 1 <= n <= len(raw) - 12 or raw[12 + n - 1] != 0:  # a CDR string: its length counts the NUL
            raise ValueError(f"a label of {n} bytes")
        if n - 1 not in (len(layout.label), len(layout.keyed_label)):  # not read: it may be 10 KB
            return WireError("wrong_layout", f"a label of {n - 1} bytes, expected {layout.label!r}")
        label = raw[12:12 + n - 1].decode()
        keyed = label == layout.keyed_label
        if not keyed and label != layout.label:
            return WireError("wrong_layout", f"label {label!r}, expected {layout.label!r}")
        at = 12 + n + (4 - (12 + n)) % 4
        size_, stride, offset, length = struct.unpack_from("<4I", raw, at)
    except (struct.error, ValueError) as e:  # UnicodeDecodeError is a ValueError
        return WireError("malformed", f"not a serialized {layout.ros_type.__name__} ({len(raw)} bytes): {e}")
    _, size = layout.dimension(keyed)
    if size_ != size or stride != size or offset != 0:
        return WireError("wrong_layout", f"size {size_} stride {stride} data_offset {offset}, expected {size} {size} 0")
    if length != size:
        return WireError("wrong_length", f"{length} values, expected {size} ({label})")
    return None


def _deserialized(layout: ArrayLayout, raw: bytes) -> Any:
    """The message of serialized bytes in no form of the layout's, to be checked as a message, so that they are
    refused exactly as it would be."""
    from rclpy.serialization import deserialize_message

    try:
        return deserialize_message(raw, layout.ros_type)
    except Exception as e:  # rclpy raises its own errors for bytes that are no such message
        raise WireError("malformed", f"not a serialized {layout.ros_type.__name__}: {e}") from None


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
    return encode_array(FEEDBACK_LAYOUT, fb, key)


def decode_feedback(msg: Float64MultiArray | bytes, *, bounds: Bounds | None = None, agent: int | None = None,
                    episode: int | None = None, step: int | None = None,
                    key: bytes | None = None) -> Feedback:
    """Feedback from `msg`. `agent`: the topic's agent; `episode`/`step`: what the receiver waits for
    (None skips that check)."""
    return decode_array(FEEDBACK_LAYOUT, msg, bounds, agent, episode, step, key)


def encode_position(pos: Position, *, key: bytes | None = None) -> Int32MultiArray:
    return encode_array(POSITION_LAYOUT, pos, key)


def decode_position(msg: Int32MultiArray | bytes, *, bounds: Bounds | None = None, agent: int | None = None,
                    episode: int | None = None, step: int | None = None,
                    key: bytes | None = None) -> Position:
    """Position from `msg`. `agent`: the peer whose topic this is; `episode`/`step`: the step waited for."""
    return decode_array(POSITION_LAYOUT, msg, bounds, agent, episode, step, key)


def encode_action(act: Action, *, key: bytes | None = None) -> Int32MultiArray:
    return encode_array(ACTION_LAYOUT, act, key)


def decode_action(msg: Int32MultiArray | bytes, *, bounds: Bounds | None = None, agent: int | None = None,
                  episode: int | None = None, step: int | None = None,
                  key: bytes | None = None) -> Action:
    """Action from `msg`. `agent`: the topic's agent; `episode`/`step`: the step the world is collecting."""
    return decode_array(ACTION_LAYOUT, msg, bounds, agent, episode, step, key)


def encode_heartbeat(hb: Heartbeat, *, key: bytes | None = None) -> Int32MultiArray:
    return encode_array(HEARTBEAT_LAYOUT, hb, key)


def decode_heartbeat(msg: Int32MultiArray | bytes, *, after: int | None = None, key: bytes | None = None) -> Heartbeat:
    """Heartbeat from `msg`. `after`: the last beat heard; a beat not above it is `replayed`."""
    hb = decode_array(HEARTBEAT_LAYOUT, msg, None, None, None, None, key)
    if after is not None and hb.beat <= after:
        raise WireError("replayed", f"beat {hb.beat}, the last one heard was {after}")
    return hb



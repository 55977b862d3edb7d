"""The array payloads' codec (feedback, positions, actions, heartbeats): their layouts on the std_msgs
MultiArray types, and for each the one serializer, encoder and validating decoder, with the run's MAC and seal.
msgs_spec/README.md is the reference ("The codec", "The run's key", "Validation and dropping", the generated
layouts): the keyed form, the order of the checks, the serialized forms read in place.
"""

from __future__ import annotations

import struct
from dataclasses import MISSING, dataclass, fields
from functools import cached_property
from typing import Any, Callable

from std_msgs.msg import Float64MultiArray, Int32MultiArray, MultiArrayDimension

from .auth import MAC_WORDS, SEAL_WORDS, WORLD, RunKey, mac_of, primed
from .checks import CONVERT, check_agent, check_cell, check_nonneg, check_sequence, check_type
from .errors import WireError
from .payloads import NO_ACTION, Action, Bounds, Feedback, Heartbeat, Position

__all__ = [
    "ArrayLayout", "FEEDBACK_LAYOUT", "POSITION_LAYOUT", "ACTION_LAYOUT", "HEARTBEAT_LAYOUT", "ARRAY_LAYOUTS",
    "LAYOUT_BY_PAYLOAD", "LAYOUT_BY_WIRE", "encode_feedback", "decode_feedback", "encode_position",
    "decode_position", "encode_action", "decode_action", "encode_heartbeat", "decode_heartbeat",
]


@dataclass(frozen=True, slots=True)
class _Form:
    """One serialized form of a layout (plain, or keyed: the seal and the MAC after the fields). Every message
    of a form has the same bytes but for the values and the alignment bytes (after the label, before the
    values), which rclpy's serializer leaves as memory held them (`head` has zeros there)."""

    head: bytes  # everything before the values, alignment bytes zero
    gap: tuple[int, int]  # where the alignment after the label lies (the one before the values ends `head`)
    data: struct.Struct  # every value of the data: the fields, then keyed the seal's and the MAC's words
    # derived from those, read per message
    start: int  # where the values start
    end: int  # where the fields' values end (and the seal starts)
    sealed_end: int  # where the seal ends (and the MAC starts)
    length: int
    before_gap: bytes
    after_gap: bytes  # up to the alignment before the values

    def holds(self, raw: bytes) -> bool:
        """Has `raw` this form's length and frame (the alignment bytes are free)?"""
        return (len(raw) == self.length and raw.startswith(self.before_gap)
                and raw.startswith(self.after_gap, self.gap[1]))


def _form(label: str, size: int, fields: int, code: str) -> _Form:
    """The form of a one-dimension array labelled `label` of `size` values of struct code `code` (`fields` of
    them the payload's, then keyed the seal's and the MAC's words), in CDR (little-endian): the encapsulation
    header, the dimension count, the label (its length with its NUL, then it), alignment to 4 bytes counted
    from after the header, the dimension's size and stride, the layout's data_offset (0), the data's length,
    alignment to a value's size. tests/test_msgs_spec.py checks it against rclpy's own bytes for every form."""
    text = label.encode("ascii") + b"\0"
    head = b"\x00\x01\x00\x00" + struct.pack("<II", 1, len(text)) + text
    gap = len(head), len(head) + (4 - len(head)) % 4
    head += bytes(gap[1] - gap[0]) + struct.pack("<IIII", size, size, 0, size)
    framed = head
    head += bytes(-(len(head) - 4) % struct.calcsize(code))
    data, value = struct.Struct(f"<{size}{code}"), struct.calcsize(code)
    end = len(head) + fields * value
    return _Form(head, gap, data, len(head), end, end + SEAL_WORDS * value, len(head) + data.size, head[:gap[0]],
                 framed[gap[1]:])


# What a value of each field kind must be, as source over a value {v}: (the test that a value as nodes build
# payloads is one: its exact type, and an int in int32's range or a finite float; the test that a float64 read
# from the wire is one; that float as the field's value). Compiled per layout (ArrayLayout._plain,
# _from_floats), as dataclasses compiles an __init__: a loop over the fields costs three times the tests.
_KIND_SOURCE = {
    "int": ("type({v}) is int and -2147483648 <= {v} <= 2147483647",
            "-2147483648.0 <= {v} <= 2147483647.0 and {v}.is_integer()", "int({v})"),
    "float": ("type({v}) is float and {v} - {v} == 0.0", "{v} - {v} == 0.0", "{v}"),
    "flag": ("type({v}) is bool", "({v} == 0.0 or {v} == 1.0)", "{v} == 1.0"),
}


def _compiled(name: str, source: str, **scope: Any) -> Callable[..., Any]:
    """The function `name` that `source` defines, with `scope` its globals."""
    exec(source, scope)
    return scope[name]


@dataclass(frozen=True, eq=False)  # a layout is itself alone: hashed as a dict key per message, by identity
class ArrayLayout:
    """A 1-D MultiArray layout: which ROS type, which fields in which order, what each holds, and the payload's
    own checks (`check(values, bounds, agent)`, raising the first failing one; its values are of their fields'
    types, whole int32 numbers, finite floats and bools; `read` judges the step expected after them). Its
    serialize, encode and decode are the codec of its payload."""

    payload: type
    ros_type: type
    fields: tuple[str, ...]
    field_kinds: tuple[str, ...]  # "int" | "float" | "flag" per field
    meanings: tuple[str, ...]
    check: Callable[[tuple, Bounds | None, int | None], None]

    # Derived once per layout (cached_property: read on every message).
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
        """The label and size of the array's one dimension, in the keyed form or the plain one."""
        return (self.keyed_label, self.size + SEAL_WORDS + MAC_WORDS) if keyed else (self.label, self.size)

    @cached_property
    def code(self) -> str:
        """The struct code of one value on the wire: int32 or float64 (the seal's and MAC's words as unsigned
        ints in an int32 array: their two's complement bytes)."""
        return "i" if self.ros_type is Int32MultiArray else "d"

    @cached_property
    def forms(self) -> tuple[_Form, _Form]:
        """(plain, keyed)."""
        return tuple(_form(*self.dimension(keyed), self.size, self.code) for keyed in (False, True))

    @cached_property
    def _struct(self) -> struct.Struct:
        """The fields' values as the wire holds them, and as the MAC reads them."""
        return struct.Struct(f"<{self.size}{self.code}")

    @cached_property
    def _seal(self) -> struct.Struct:
        return struct.Struct(f"<{SEAL_WORDS}{'I' if self.code == 'i' else 'd'}")

    @cached_property
    def _mac(self) -> struct.Struct:
        return struct.Struct(f"<{MAC_WORDS}{'I' if self.code == 'i' else 'd'}")

    @cached_property
    def _names(self) -> str:
        """The fields' values as compiled code names them: v0, v1, ..."""
        return ", ".join(f"v{i}" for i in range(self.size))

    def _per_field(self, column: int, sep: str) -> str:
        """A column of _KIND_SOURCE for every field, in order, joined by `sep`."""
        return sep.join(_KIND_SOURCE[kind][column].format(v=f"v{i}") for i, kind in enumerate(self.field_kinds))

    @cached_property
    def new(self) -> Callable[..., Any]:
        """payload(*values), the fields in order, those with a default optional (as the dataclass's), without its
        __init__ (which sets each field through object.__setattr__): the same object in two thirds of the time.
        For values already checked (the decoder's), or checked when they are serialized (the nodes' own)."""
        setters = {f"set{i}": self.payload.__dict__[name].__set__ for i, name in enumerate(self.fields)}
        defaults = {f"d{i}": f.default for i, f in enumerate(fields(self.payload)) if f.default is not MISSING}
        params = ", ".join(f"v{i}=d{i}" if f"d{i}" in defaults else f"v{i}" for i in range(self.size))
        return _compiled("new", f"def new({params}):\n    o = make(payload)\n"
                         + "".join(f"    {set_}(o, v{i})\n" for i, set_ in enumerate(setters)) + "    return o\n",
                         make=object.__new__, payload=self.payload, **setters, **defaults)

    @cached_property
    def _plain(self) -> Callable[[Any], tuple | None]:
        """payload -> its field values when each is of exactly its field's type and what the field holds (an
        int that fits int32, a finite float, a bool), as _typed would give them back: as nodes build payloads;
        None otherwise."""
        reads = "".join(f"    v{i} = payload.{name}\n" for i, name in enumerate(self.fields))
        return _compiled("plain", f"def plain(payload):\n{reads}    if {self._per_field(0, ' and ')}:\n"
                                  f"        return ({self._names},)\n    return None\n")

    @cached_property
    def _from_floats(self) -> Callable[[tuple], tuple | None]:
        """A float64 array's field values -> their fields' values when each is what its field holds (a whole
        number in int32 range, a finite float, a flag 0 or 1); None otherwise (then _typed says which is not)."""
        return _compiled("from_floats", f"def from_floats(values):\n    {self._names}, = values\n"
                                        f"    if {self._per_field(1, ' and ')}:\n"
                                        f"        return ({self._per_field(2, ', ')},)\n    return None\n")

    # -- encode ---------------------------------------------------------------------------------------------

    def serialize(self, payload: Any, key: bytes | RunKey | None = None) -> bytes:
        """The bytes rclpy would serialize `encode(payload, key=key)` to (alignment bytes zero): the frame, the
        values, checked as a decoder checks them (WireError otherwise), then keyed the seal and the MAC over the
        values and the seal."""
        if type(payload) is not self.payload:  # check_type's, inline: per message
            check_type(payload, self.payload)
        # as nodes build them, else converted (numpy numbers, a whole float) or the numbers' own error
        values = self._plain(payload) or self._typed([getattr(payload, f) for f in self.fields])
        self.check(values, None, None)
        packed = self._struct.pack(*values)
        if key is None:
            return self.forms[0].head + packed
        if type(key) is RunKey:  # derived once per binding (RunKey.accept clears it)
            seal, hashes = key.derived.get(self) or key.derived.setdefault(self, (key.seal(self.code),
                                                                                  key.hashes(self.label)))
        else:
            seal, hashes = self._seal.pack(0, 0, 0), primed(key, self.label)
        body = packed + seal
        return self.forms[1].head + body + self._mac.pack(*mac_of(hashes, body))

    def encode(self, payload: Any, *, key: bytes | RunKey | None = None) -> Any:
        """The message whose serialization `serialize` gives."""
        form = self.forms[key is not None]
        data = form.data.unpack_from(self.serialize(payload, key), form.start)
        label, size = self.dimension(key is not None)
        msg = self.ros_type()
        msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=size)]  # data_offset: 0 as made
        msg.data = list(data)
        return msg

    def _typed(self, values: tuple) -> tuple:
        """The values as their fields' types: WireError (not_finite, not_integer, out_of_range, malformed)
        for the first that is no such value."""
        return tuple(CONVERT[kind](name, v) for name, kind, v in zip(self.fields, self.field_kinds, values))

    # -- decode ---------------------------------------------------------------------------------------------

    def decode(self, msg: Any, *, bounds: Bounds | None = None, agent: int | None = None,
               episode: int | None = None, step: int | None = None, key: bytes | RunKey | None = None) -> Any:
        """The payload of a message or its serialized bytes, every check passed (WireError otherwise).
        `agent`: the topic's agent; `episode`/`step`: what the receiver waits for (None skips a check)."""
        values, seal = self.read(msg, bounds, agent, episode, step, key)
        if seal is not None:  # bound only by a message every check accepted
            key.accept(*seal)
        return self.new(*values)

    def read(self, msg: Any, bounds: Bounds | None = None, agent: int | None = None, episode: int | None = None,
             step: int | None = None, key: bytes | RunKey | None = None) -> tuple[tuple, tuple | None]:
        """(decode's values, the seal they bind `key` to or None), every check but the binding, which the world's
        core makes once an action is of the step it collects. A message object is checked as its bytes are."""
        raw = msg if type(msg) is bytes else self._serialized(msg)
        plain, keyed = self.forms
        form = keyed if keyed.holds(raw) else plain if plain.holds(raw) else None
        if form is None:  # not as our nodes send them: refused from the header when too long, else deserialized
            if len(raw) > keyed.length:
                refusal = self._oversized(raw)
                if refusal is not None:
                    raise refusal
            raw = self._serialized(self._deserialized(raw))
            form = keyed if len(raw) == keyed.length else plain
        seal = None
        if key is not None:
            if form is plain:
                raise WireError("unauthenticated", f"no MAC ({self.label}), and this receiver holds the run's key")
            if type(key) is RunKey:  # an action's sender is the topic's agent, else the one it names
                sender = WORLD if self.payload is not Action else agent if agent is not None else \
                    self._struct.unpack_from(raw, form.start)[0]
                held, hashes = key.derived.get((self, sender)) or self._checking(key, sender)
            else:
                held, hashes = None, primed(key, self.label)
            if not raw.endswith(self._mac.pack(*mac_of(hashes, raw[form.start:form.sealed_end]))):
                raise WireError("unauthenticated", "the MAC does not match the run's key")
            if type(key) is RunKey and (held is None or not raw.startswith(held, form.end)):
                # not the seal held: refused here, or bound by decode (key.accept) once every check passed
                words = self._seal.unpack_from(raw, form.end)
                seal = (int(words[0]) << 32) | int(words[1]), int(words[2]), sender
                refusal = key.refusal(*seal)
                if refusal is not None:
                    raise WireError(*refusal)
        values = self._struct.unpack_from(raw, form.start)
        if self.code == "d":
            values = self._from_floats(values) or self._typed(values)
        self.check(values, bounds, agent)
        if episode is not None or step is not None:  # every layout's values start (agent or beat, episode, step)
            check_sequence(values[1], values[2], episode, step)
        return values, seal

    def _checking(self, key: RunKey, sender: int) -> tuple[bytes | None, tuple]:
        """(the seal `key` holds for `sender`'s messages of this layout, None while it holds no run or no
        incarnation of it; the primed HMAC hashes), kept in the key's `derived` until its binding changes."""
        incarnation = key.held.get(sender)
        seal = None if key.run is None or incarnation is None else key.seal(self.code, incarnation)
        return key.derived.setdefault((self, sender), (seal, key.hashes(self.label)))

    def _serialized(self, msg: Any) -> bytes:
        """The bytes of a message object in the layout's form, once its type, layout and length are the
        layout's (WireError otherwise): then it is checked as those bytes are."""
        check_type(msg, self.ros_type)
        try:
            dims = list(msg.layout.dim)
            data = list(msg.data)
            d = dims[0] if len(dims) == 1 else MultiArrayDimension()
            refusal = self._refusal(len(dims), d.label, d.size, d.stride, msg.layout.data_offset, len(data))
        except (AttributeError, TypeError) as e:  # a hand-built message object with broken fields
            raise WireError("malformed", f"unreadable message: {e}") from None
        if refusal is not None:
            raise refusal
        form = self.forms[d.label == self.keyed_label]
        try:
            return form.head + form.data.pack(*data)
        except struct.error as e:  # a value the wire type cannot hold
            raise WireError("malformed", f"unreadable message: {e}") from None

    def _oversized(self, raw: bytes) -> WireError | None:
        """The refusal of serialized bytes longer than the layout's keyed form, which no message of the layout
        is (a flood's 20,000 values, a 10 KB label), read from the CDR header alone, as _serialized words
        it for the message: dims, label, size, stride, data_offset, the data's length; its values are never
        read. None for bytes whose header is the layout's own (then only what follows can be wrong)."""
        try:
            dims, n = struct.unpack_from("<2I", raw, 4)
            if dims != 1:  # refused on the count alone
                return self._refusal(dims, "", 0, 0, 0, 0)
            if not 1 <= n <= len(raw) - 12 or raw[12 + n - 1] != 0:  # a CDR string: its length counts the NUL
                raise ValueError(f"a label of {n} bytes")
            if n - 1 not in (len(self.label), len(self.keyed_label)):  # not read: it may be 10 KB
                return WireError("wrong_layout", f"a label of {n - 1} bytes, expected {self.label!r}")
            label = raw[12:12 + n - 1].decode()
            return self._refusal(1, label, *struct.unpack_from("<4I", raw, 12 + n + (4 - (12 + n)) % 4))
        except (struct.error, ValueError) as e:  # UnicodeDecodeError is a ValueError
            return WireError("malformed", f"not a serialized {self.ros_type.__name__} ({len(raw)} bytes): {e}")

    def _refusal(self, dims: int, label: str, size: int, stride: int, offset: int, length: int) -> WireError | None:
        """The refusal of an array's dimensions and length, read from a message or from its header, or None when
        they are the layout's (plain or keyed)."""
        if dims != 1:
            return WireError("wrong_layout", f"{dims} dims, expected 1 labelled {self.label!r}")
        if label != self.label and label != self.keyed_label:
            return WireError("wrong_layout", f"label {label!r}, expected {self.label!r}")
        _, n = self.dimension(label == self.keyed_label)
        if size != n or stride != n or offset != 0:
            return WireError("wrong_layout", f"size {size} stride {stride} data_offset {offset}, expected {n} {n} 0")
        if length != n:
            return WireError("wrong_length", f"{length} values, expected {n} ({label})")
        return None

    def _deserialized(self, raw: bytes) -> Any:
        """The message of serialized bytes in no form of the layout's, to be checked as a message, so that
        they are refused exactly as it would be."""
        from rclpy.serialization import deserialize_message

        try:
            return deserialize_message(raw, self.ros_type)
        except Exception as e:  # rclpy raises its own errors for bytes that are no such message
            raise WireError("malformed", f"not a serialized {self.ros_type.__name__}: {e}") from None


# -- each payload's checks, past the numbers: the first failing one raises --------------------------------------


def _check_counts(e: int, s: int) -> None:
    """What every payload's check starts with: its episode and step count from 0."""
    if e < 0 or s < 0:
        check_nonneg("episode", e)
        check_nonneg("step", s)


def _check_feedback(v: tuple, bounds: Bounds | None, agent: int | None) -> None:
    sender, e, s, row, col, _, done, truncated, applied = v
    _check_counts(e, s)
    check_agent(sender, bounds, agent)
    check_cell(row, col, bounds)
    if done and truncated:
        raise WireError("malformed", "done and truncated both set")
    if not NO_ACTION <= applied <= 3:
        raise WireError("action_out_of_range", f"applied {applied}, must be 0..3 or {NO_ACTION}")


def _check_position(v: tuple, bounds: Bounds | None, agent: int | None) -> None:
    sender, e, s, row, col = v
    _check_counts(e, s)
    check_agent(sender, bounds, agent)
    check_cell(row, col, bounds)


def _check_action(v: tuple, bounds: Bounds | None, agent: int | None) -> None:
    sender, e, s, action = v
    _check_counts(e, s)
    check_agent(sender, bounds, agent)
    if not 0 <= action <= 3:
        raise WireError("action_out_of_range", f"action {action}, must be 0..3")


def _check_heartbeat(v: tuple, bounds: Bounds | None, agent: int | None) -> None:
    beat, e, s, stepping, started, ticket = v
    _check_counts(e, s)
    if beat < 1:
        raise WireError("out_of_range", f"beat = {beat}, must be >= 1")
    if stepping not in (0, 1):
        raise WireError("out_of_range", f"stepping = {stepping}, must be 0 or 1")
    check_nonneg("started", started)
    check_nonneg("ticket", ticket)


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
    _check_feedback,
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
    _check_position,
)
ACTION_LAYOUT = ArrayLayout(
    Action, Int32MultiArray,
    ("agent", "episode", "step", "action"),
    ("int",) * 4,
    ("agent id, 1..N (the topic's own agent)",
     "episode of the feedback this action answers",
     "step of the feedback this action answers",
     "0 NORTH (row-1), 1 EAST (col+1), 2 SOUTH (row+1), 3 WEST (col-1)"),
    _check_action,
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
    _check_heartbeat,
)
ARRAY_LAYOUTS: tuple[ArrayLayout, ...] = (FEEDBACK_LAYOUT, POSITION_LAYOUT, ACTION_LAYOUT, HEARTBEAT_LAYOUT)
LAYOUT_BY_PAYLOAD = {lay.payload: lay for lay in ARRAY_LAYOUTS}
LAYOUT_BY_WIRE = {(lay.ros_type, label): lay for lay in ARRAY_LAYOUTS for label in (lay.label, lay.keyed_label)}

encode_feedback, decode_feedback = FEEDBACK_LAYOUT.encode, FEEDBACK_LAYOUT.decode
encode_position, decode_position = POSITION_LAYOUT.encode, POSITION_LAYOUT.decode
encode_action, decode_action = ACTION_LAYOUT.encode, ACTION_LAYOUT.decode
encode_heartbeat, decode_heartbeat = HEARTBEAT_LAYOUT.encode, HEARTBEAT_LAYOUT.decode

"""The codec's fast path: what the nodes call to serialize and decode feedback, positions, actions and
heartbeats, with exactly the checks of the reference codec (msgs_spec.arrays) and byte-identical output.

Each function here accepts only what it can prove every reference check would accept (the frame, every value's
type and range, the agent, cell, action and sequence expectations, the seal and the MAC) and then returns what
the reference would; anything else (a message object, a bare key, an unbound RunKey, an error of any kind)
goes to the reference codec, which gives the value or raises the same WireError with the same detail. So the
fast path never raises a WireError of its own, and tests/test_msgs_spec.py checks the two agree on random and
mutated messages.

Where the time went in the reference and what this does instead (per call, docs/speed.md): a frozen
dataclass's __init__ sets each field through object.__setattr__ (1.5 us for a Feedback), so payloads are built
from their slot descriptors, one setter call a field (0.34 us for a Position, the same object); the checks run
as one expression on the unpacked tuple instead of one function per check; the frame is compared in place
(startswith), not sliced; the MAC copies the HMAC hashes the node's RunKey primed for the layout; a received
seal is compared as bytes with the one the key holds for its sender (packed once per binding and kept, with
the hashes, in the key's `derived`), not unpacked and compared word by word.
"""

from __future__ import annotations

import struct
from typing import Any, Callable

from .arrays import (
    ACTION_LAYOUT, FEEDBACK_LAYOUT, HEARTBEAT_LAYOUT, POSITION_LAYOUT, ArrayLayout, decode_array, serialize_array,
)
from .auth import MAC_WORDS, SEAL_WORDS, WORLD, RunKey
from .errors import WireError
from .payloads import INT32_MAX, Action, Bounds, Feedback, Heartbeat, Position

__all__ = ["serialize_array", "serialize_feedback", "serialize_position", "serialize_action", "serialize_heartbeat",
           "decode_feedback", "decode_position", "decode_action", "decode_heartbeat", "action_of",
           "new_feedback", "new_position", "new_action"]

_reference_serialize = serialize_array
_DIGEST_WORDS = struct.Struct(f">{MAC_WORDS}I")  # as msgs_spec.auth reads the digest


def _builder(payload: type) -> Callable[..., Any]:
    """payload(*values) without the frozen dataclass's __init__: the same object, in half the time. Unrolled
    (one setter call per field, no loop): a loop over the setters cost as much as the __init__ it replaces."""
    setters = [payload.__dict__[name].__set__ for name in payload.__slots__]
    new = object.__new__
    if len(setters) == 4:
        s0, s1, s2, s3 = setters

        def build4(a, b, c, d):
            o = new(payload)
            s0(o, a); s1(o, b); s2(o, c); s3(o, d)  # noqa: E702
            return o
        return build4
    if len(setters) == 5:
        s0, s1, s2, s3, s4 = setters

        def build5(a, b, c, d, e):
            o = new(payload)
            s0(o, a); s1(o, b); s2(o, c); s3(o, d); s4(o, e)  # noqa: E702
            return o
        return build5
    s0, s1, s2, s3, s4, s5, s6, s7, s8 = setters  # Feedback's nine

    def build9(a, b, c, d, e, f, g, h, i):
        o = new(payload)
        s0(o, a); s1(o, b); s2(o, c); s3(o, d); s4(o, e); s5(o, f); s6(o, g); s7(o, h); s8(o, i)  # noqa: E702
        return o
    return build9


class _Form:
    """One layout's serialized form, keyed or plain (msgs_spec.arrays.ArrayLayout.frame), as the fast path
    reads it: the frame's bytes either side of the label's alignment gap, where the values start and end,
    where the seal ends, and the Structs of the values, the seal and the MAC."""

    __slots__ = ("layout", "length", "head", "head_a", "gap_end", "head_b", "start", "end", "sealed_end",
                 "values", "seal", "mac", "label", "code")

    def __init__(self, layout: ArrayLayout, keyed: bool):
        head, (a, b), pad, values = layout.frame(keyed)
        self.layout, self.label, self.code = layout, layout.label, layout._code
        self.head = head + bytes(pad)  # what serialize_array puts before the values
        self.head_a, self.gap_end, self.head_b = head[:a], b, head[b:]
        self.start = len(head) + pad
        self.end = self.start + layout._struct.size
        self.values = layout._struct
        seal = f"{SEAL_WORDS}{'I' if self.code == 'i' else 'd'}"
        self.seal = struct.Struct(f"<{seal}")
        self.sealed_end = self.end + self.seal.size
        self.mac = layout._mac_struct
        self.length = self.sealed_end + self.mac.size if keyed else self.end

    def framed(self, raw: bytes) -> bool:
        """Does `raw` have this form's length and frame (the alignment gap's bytes are free)?"""
        return (len(raw) == self.length and raw.startswith(self.head_a)
                and raw.startswith(self.head_b, self.gap_end))

    def sealing(self, key: RunKey) -> tuple:
        """(the frame, the seal's bytes, the primed inner and outer HMAC hashes) this form seals with under a
        RunKey bound to its run, kept in the key's `derived` until its binding changes."""
        got = key.derived.get(self)
        if got is None:
            got = key.derived[self] = (self.head, key.seal(self.code), *key.hashes(self.label))
        return got

    def checking(self, key: RunKey, sender: int) -> tuple | None:
        """(the seal's bytes a message from `sender` must carry, the primed inner and outer HMAC hashes) when
        `key` holds the run and an incarnation of `sender`, kept in the key's `derived` until its binding
        changes; None when it holds neither (the reference checks, and binds)."""
        got = key.derived.get((self, sender))
        if got is None:
            run, incarnation = key.run, key.held.get(sender)
            if run is None or incarnation is None:
                return None
            try:
                seal = self.seal.pack(run >> 32, run & 0xFFFFFFFF, incarnation)
            except struct.error:  # no seal of this form carries it: the reference says why
                return None
            got = key.derived[(self, sender)] = (seal, *key.hashes(self.label))
        return got

    def sealed(self, key: RunKey, packed: bytes) -> bytes:
        """The frame, the values, the seal and the MAC: serialize_array's bytes for a bound RunKey."""
        head, seal, inner, outer = key.derived.get(self) or self.sealing(key)
        body = packed + seal
        inner = inner.copy()
        inner.update(body)
        outer = outer.copy()
        outer.update(inner.digest())
        return head + body + self.mac.pack(*_DIGEST_WORDS.unpack_from(outer.digest()))


_FORMS = {lay.payload: (_Form(lay, False), _Form(lay, True))
          for lay in (FEEDBACK_LAYOUT, POSITION_LAYOUT, ACTION_LAYOUT, HEARTBEAT_LAYOUT)}
_FB, _FB_KEYED = _FORMS[Feedback]
_POS, _POS_KEYED = _FORMS[Position]
_ACT, _ACT_KEYED = _FORMS[Action]
_HB, _HB_KEYED = _FORMS[Heartbeat]
_NEW_FEEDBACK = _builder(Feedback)
_NEW_POSITION, _NEW_ACTION = _builder(Position), _builder(Action)
# For the nodes' own payloads, built every step: the same objects as Feedback(...), Position(...), Action(...)
# with every field given in order (no defaults), a third of the time. Their values are checked where they
# matter, when they are serialized.
new_feedback, new_position, new_action = _NEW_FEEDBACK, _NEW_POSITION, _NEW_ACTION
_I32 = INT32_MAX


def _limits(bounds: Bounds | None) -> tuple[int, int, int]:
    """(highest agent id, rows, cols) a value must stay within (below rows/cols): without bounds, int32's."""
    if bounds is None:
        return _I32, _I32 + 1, _I32 + 1
    return bounds.n_agents, bounds.rows, bounds.cols


# -- serialize ------------------------------------------------------------------------------------------------


def _key_form(key: Any, plain: _Form, keyed: _Form) -> _Form | None:
    """The form to write with `key`: None when the reference must (a bare key, a RunKey with no run yet)."""
    if key is None:
        return plain
    if type(key) is RunKey and key.run is not None:
        return keyed
    return None


# One serializer a payload type, which a node holding its payload's type calls straight (serialize_array's
# lookup is one call more per message); each gives msgs_spec.arrays.serialize_array's bytes, faster for a payload
# whose values are all of their field's exact type and valid (as nodes build them), the reference's for anything
# else.

def serialize_feedback(payload: Any, key: Any = None) -> bytes:
    """serialize_array(FEEDBACK_LAYOUT, payload, key)."""
    if type(payload) is Feedback:
        form = _key_form(key, _FB, _FB_KEYED)
        if form is not None:
            p = payload
            a, e, s, r, c, rw, d, tr, ap = (p.agent, p.episode, p.step, p.row, p.col, p.reward, p.done,
                                            p.truncated, p.applied)
            if (type(a) is int and type(e) is int and type(s) is int and type(r) is int and type(c) is int
                    and type(rw) is float and type(d) is bool and type(tr) is bool and type(ap) is int
                    and 0 < a <= _I32 and 0 <= e <= _I32 and 0 <= s <= _I32 and 0 <= r <= _I32
                    and 0 <= c <= _I32 and rw - rw == 0.0 and not (d and tr) and -1 <= ap <= 3):
                packed = form.values.pack(a, e, s, r, c, rw, d, tr, ap)
                return form.head + packed if key is None else form.sealed(key, packed)
    return _reference_serialize(FEEDBACK_LAYOUT, payload, key)


def serialize_position(payload: Any, key: Any = None) -> bytes:
    """serialize_array(POSITION_LAYOUT, payload, key)."""
    if type(payload) is Position:
        form = _key_form(key, _POS, _POS_KEYED)
        if form is not None:
            p = payload
            a, e, s, r, c = p.agent, p.episode, p.step, p.row, p.col
            if (type(a) is int and type(e) is int and type(s) is int and type(r) is int and type(c) is int
                    and 0 < a <= _I32 and 0 <= e <= _I32 and 0 <= s <= _I32 and 0 <= r <= _I32
                    and 0 <= c <= _I32):
                packed = form.values.pack(a, e, s, r, c)
                return form.head + packed if key is None else form.sealed(key, packed)
    return _reference_serialize(POSITION_LAYOUT, payload, key)


def serialize_action(payload: Any, key: Any = None) -> bytes:
    """serialize_array(ACTION_LAYOUT, payload, key)."""
    if type(payload) is Action:
        form = _key_form(key, _ACT, _ACT_KEYED)
        if form is not None:
            p = payload
            a, e, s, x = p.agent, p.episode, p.step, p.action
            if (type(a) is int and type(e) is int and type(s) is int and type(x) is int
                    and 0 < a <= _I32 and 0 <= e <= _I32 and 0 <= s <= _I32 and 0 <= x <= 3):
                packed = form.values.pack(a, e, s, x)
                return form.head + packed if key is None else form.sealed(key, packed)
    return _reference_serialize(ACTION_LAYOUT, payload, key)


def serialize_heartbeat(payload: Any, key: Any = None) -> bytes:
    """serialize_array(HEARTBEAT_LAYOUT, payload, key)."""
    if type(payload) is Heartbeat:
        form = _key_form(key, _HB, _HB_KEYED)
        if form is not None:
            p = payload
            v = (p.beat, p.episode, p.step, p.stepping, p.started, p.ticket)
            if all(type(x) is int and 0 <= x <= _I32 for x in v) and v[0] > 0 and v[3] <= 1:
                packed = form.values.pack(*v)
                return form.head + packed if key is None else form.sealed(key, packed)
    return _reference_serialize(HEARTBEAT_LAYOUT, payload, key)


def serialize_array(layout: ArrayLayout, payload: Any, key: Any = None) -> bytes:
    """msgs_spec.arrays.serialize_array's bytes: the layout's own serializer above (the reference for a layout
    of its own)."""
    if layout is FEEDBACK_LAYOUT:
        return serialize_feedback(payload, key)
    if layout is POSITION_LAYOUT:
        return serialize_position(payload, key)
    if layout is ACTION_LAYOUT:
        return serialize_action(payload, key)
    if layout is HEARTBEAT_LAYOUT:
        return serialize_heartbeat(payload, key)
    return _reference_serialize(layout, payload, key)


# -- decode ---------------------------------------------------------------------------------------------------


def _sealed_values(msg: Any, key: Any, plain: _Form, keyed: _Form, sender: int | None) -> tuple | None:
    """The values of bytes in the form `key` reads, keyed ones carrying the seal `key` holds for `sender` (None:
    the agent the values name) and the key's MAC; None when the reference must decide (a message object, a bare
    key, another form, a seal not held yet, a bad MAC)."""
    if type(msg) is not bytes:
        return None
    if key is None:
        return plain.values.unpack_from(msg, plain.start) if plain.framed(msg) else None
    # the keyed form's frame, seal and MAC checked here, inline: no call per check on every message a node reads
    if (type(key) is not RunKey or len(msg) != keyed.length or not msg.startswith(keyed.head_a)
            or not msg.startswith(keyed.head_b, keyed.gap_end)):
        return None
    values = keyed.values.unpack_from(msg, keyed.start)
    if sender is None:
        sender = values[0]
    held = key.derived.get((keyed, sender)) or keyed.checking(key, sender)
    if held is None or not msg.startswith(held[0], keyed.end):
        return None
    inner = held[1].copy()
    inner.update(msg[keyed.start:keyed.sealed_end])
    outer = held[2].copy()
    outer.update(inner.digest())
    return values if msg.endswith(keyed.mac.pack(*_DIGEST_WORDS.unpack_from(outer.digest()))) else None


def decode_feedback(msg: Any, *, bounds: Bounds | None = None, agent: int | None = None,
                    episode: int | None = None, step: int | None = None, key: Any = None) -> Feedback:
    """msgs_spec.arrays.decode_feedback, fast for the bytes a world node sends."""
    v = _sealed_values(msg, key, _FB, _FB_KEYED, WORLD)
    if v is not None:
        a, e, s, r, c, rw, d, t, ap = v
        n, rows, cols = _limits(bounds)
        # The ranges first (NaN and infinities fail them), so int() cannot raise; whole numbers: int(x) == x.
        if (1 <= a <= n and 0 <= e <= _I32 and 0 <= s <= _I32 and 0 <= r < rows and 0 <= c < cols
                and -1 <= ap <= 3 and rw - rw == 0.0 and (d == 0.0 or d == 1.0) and (t == 0.0 or t == 1.0)
                and not (d == 1.0 and t == 1.0) and (agent is None or a == agent)
                and (episode is None or e == episode) and (step is None or s == step)):
            ia, ie, is_, ir, ic, iap = int(a), int(e), int(s), int(r), int(c), int(ap)
            if ia == a and ie == e and is_ == s and ir == r and ic == c and iap == ap:
                return _NEW_FEEDBACK(ia, ie, is_, ir, ic, rw, d == 1.0, t == 1.0, iap)
    return decode_array(FEEDBACK_LAYOUT, msg, bounds, agent, episode, step, key)


def decode_position(msg: Any, *, bounds: Bounds | None = None, agent: int | None = None,
                    episode: int | None = None, step: int | None = None, key: Any = None) -> Position:
    """msgs_spec.arrays.decode_position, fast for the bytes a world node sends."""
    v = _sealed_values(msg, key, _POS, _POS_KEYED, WORLD)
    if v is not None:
        a, e, s, r, c = v
        n, rows, cols = _limits(bounds)
        if (1 <= a <= n and e >= 0 and s >= 0 and 0 <= r < rows and 0 <= c < cols
                and (agent is None or a == agent) and (episode is None or e == episode)
                and (step is None or s == step)):
            return _NEW_POSITION(a, e, s, r, c)
    return decode_array(POSITION_LAYOUT, msg, bounds, agent, episode, step, key)


def _action_values(msg: Any, bounds: Bounds | None, agent: int | None, episode: int | None, step: int | None,
                   key: Any) -> tuple | None:
    """(agent, episode, step, action) of bytes an agent node sends that pass every check of decode_action (its
    sender: the topic's agent, else the agent it names); None when the reference must decide."""
    v = _sealed_values(msg, key, _ACT, _ACT_KEYED, agent)
    if v is not None:
        a, e, s, x = v
        if (1 <= a <= (bounds.n_agents if bounds is not None else _I32) and e >= 0 and s >= 0 and 0 <= x <= 3
                and (agent is None or a == agent) and (episode is None or e == episode)
                and (step is None or s == step)):
            return v
    return None


def decode_action(msg: Any, *, bounds: Bounds | None = None, agent: int | None = None,
                  episode: int | None = None, step: int | None = None, key: Any = None) -> Action:
    """msgs_spec.arrays.decode_action, fast for the bytes an agent node sends."""
    v = _action_values(msg, bounds, agent, episode, step, key)
    if v is not None:
        return _NEW_ACTION(*v)
    return decode_array(ACTION_LAYOUT, msg, bounds, agent, episode, step, key)


def action_of(msg: Any, *, bounds: Bounds | None = None, agent: int | None = None, episode: int | None = None,
              step: int | None = None, key: Any = None) -> int:
    """decode_action(...).action, with every check of it (its WireError likewise), without the Action: what the
    world keeps of an action, which it stamps with the agent, episode and step it expected."""
    v = _action_values(msg, bounds, agent, episode, step, key)
    if v is not None:
        return v[3]
    return decode_array(ACTION_LAYOUT, msg, bounds, agent, episode, step, key).action


def decode_heartbeat(msg: Any, *, after: int | None = None, key: Any = None) -> Heartbeat:
    """msgs_spec.arrays.decode_heartbeat, fast for the bytes a world node sends."""
    v = _sealed_values(msg, key, _HB, _HB_KEYED, WORLD)
    if v is not None and min(v) >= 0 and v[0] >= 1 and v[3] <= 1 and (after is None or v[0] > after):
        return Heartbeat(*v)  # once a heartbeat period: built by its own __init__
    hb = decode_array(HEARTBEAT_LAYOUT, msg, None, None, None, None, key)
    if after is not None and hb.beat <= after:
        raise WireError("replayed", f"beat {hb.beat}, the last one heard was {after}")
    return hb

"""The statistics' codec: WorldStats and AgentStats as a diagnostic_msgs/DiagnosticArray holding one
DiagnosticStatus whose `values` are KeyValue pairs (WORLD_STATS_KEYS, AGENT_STATS_KEYS), keyed with a `mac`
pair and sealed with `run` and `inc`. One table of fields per payload drives its encoder and its decoder;
decoders take a message or its serialized bytes, judge bytes from their CDR header first (`_message`) and
raise only `WireError` (msgs_spec/README.md, "The run's key", "Validation and dropping")."""

from __future__ import annotations

import hmac
import re
import struct
from functools import partial
from typing import Any, Callable, Mapping

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from .auth import RunKey, mac_words, secret_of
from .checks import as_flag, as_float, as_int, check_agent, check_cell, check_nonneg, check_sequence, check_type
from .errors import WireError
from .payloads import DIGITS, INT32_MAX, AgentStats, Bounds, MarkedJointState, WorldStats

__all__ = ["WORLD_STATS_NAME", "agent_stats_name", "WORLD_STATS_KEYS", "AGENT_STATS_KEYS", "COUNTERS_MAX",
           "pairs_bound", "bytes_bound", "encode_world_stats", "decode_world_stats", "encode_agent_stats",
           "decode_agent_stats"]

WORLD_STATS_NAME = "world/stats"


def agent_stats_name(agent: int) -> str:
    return f"agv{agent}/stats"


# key -> (kind, meaning). A payload's own fields, in the order of their pairs; the kind says how a value is
# written ('int' in decimal, 'float' as Python's repr, 'bool' true/false, 'str' a name) and read back.
_WORLD_FIELDS: Mapping[str, tuple[str, str]] = {
    "episode": ("int", "episode index, from 0"),
    "steps": ("int", "joint steps taken in the episode"),
    "truncated": ("bool", "true when the step cap ended the episode"),
    "collisions": ("int", "collisions in the episode"),
    "missed_actions": ("int", "actions that missed the step timeout (the agent stayed)"),
    "duration_s": ("float", "wall-clock length of the episode, seconds"),
}
_AGENT_FIELDS: Mapping[str, tuple[str, str]] = {
    "agent": ("int", "agent id, 1..N"),
    "episode": ("int", "episode that just ended for this agent"),
    "algorithm": ("str", "learner name, e.g. cq, indep, js, loc"),
    "joint_plays": ("int", "times this episode the agent used global information / chose COORDINATE"),
    "heard": ("int", "peer positions the learner's decisions took in this episode"),
    "local_states": ("int", "local states in use (any size, as are joint_states)"),
    "joint_states": ("int", "joint states in use; JS's joint state space, cells**N, can pass int64"),
    "subscriptions_created": ("int", "peer position subscriptions created since start"),
    "subscriptions_active": ("int", "peer position subscriptions alive now"),
    "peer_messages": ("int", "peer position messages received since start"),
}
_COUNTER_KEYS = {"count.<name>": ("int", "further monotonic counters, e.g. count.dropped.stale_step")}
# The keyed form's pairs, last in every status: the seal (with a RunKey), then the MAC over everything before it.
SEAL_KEYS: Mapping[str, tuple[str, str]] = {
    "run": ("str", "keyed with a run: the run nonce, 16 hex digits (msgs_spec.auth)"),
    "inc": ("str", "keyed with a run: the sender's incarnation, 8 hex digits"),
    "mac": ("str", "keyed: the run's HMAC over the name, hardware id and every pair before it, 32 hex digits"),
}
# Every key of a status, the open-ended ones by pattern.
WORLD_STATS_KEYS: Mapping[str, tuple[str, str]] = {
    **_WORLD_FIELDS, "return.agv<k>": ("float", "undiscounted return of agent k, one key per agent 1..N"),
    **_COUNTER_KEYS, **SEAL_KEYS,
}
AGENT_STATS_KEYS: Mapping[str, tuple[str, str]] = {
    **_AGENT_FIELDS,
    "marked.<i>": ("str", "marked joint state i (0..M-1): 'cell=R,C peer=agvJ peer_cell=R,C confidence=X'"),
    **_COUNTER_KEYS, **SEAL_KEYS,
}

# State counts of any size: a JS agent conditions on cells**N states (about 4.7e36 on warehouse_16), which
# the text of a diagnostic value carries exactly where an int32 could not. Bounded, so a forged value of a
# million digits is dropped before Python parses it.
_WIDE_KEYS = frozenset({"local_states", "joint_states"})
WIDE_DIGITS = 200
_WIDE_LIMIT = 10 ** WIDE_DIGITS  # the least count of more than WIDE_DIGITS digits
# A node counts a few dozen kinds of things (every WireError kind dropped, a dozen of its own, a checkpoint
# failure per errno seen): encoders refuse more counters than this, so no statistic carries more.
COUNTERS_MAX = 256

_INT_RE = re.compile(r"-?[0-9]+")
_NAME_RE = re.compile(r"[a-z0-9_][a-z0-9_.]*")
_ALGO_RE = re.compile(r"[a-z][a-z0-9_]*")
_MARKED_RE = re.compile(r"cell=({0}),({0}) peer=agv({0}) peer_cell=({0}),({0}) confidence=(\S+)".format(DIGITS))
_RUN_RE, _INC_RE = re.compile(r"[0-9a-f]{16}"), re.compile(r"[0-9a-f]{8}")


# -- the payloads ------------------------------------------------------------------------------------------

def encode_world_stats(s: WorldStats, *, stamp: Time | None = None, key: bytes | None = None) -> DiagnosticArray:
    """`stamp`: header time (wall clock, e.g. node.get_clock().now().to_msg()); zero if None. `key`: the run's."""
    check_type(s, WorldStats)
    f = _fields(_WORLD_FIELDS, partial(getattr, s), text=False)
    returns = [(f"return.agv{k}", _text(as_float(f"return.agv{k}", r))) for k, r in enumerate(s.returns, 1)]
    if not returns:
        raise WireError("malformed", "returns is empty (one per agent)")
    end = "truncated at the step cap" if f["truncated"] else "all agents at their goals"
    summary = (f"episode {f['episode']}: {f['steps']} steps, {f['collisions']} collisions, "
               f"{f['missed_actions']} missed actions, {end}")
    return _stats_msg("world", summary, _pairs(f) + returns + _counter_pairs(s.counters), stamp, key)


def decode_world_stats(msg: DiagnosticArray, *, bounds: Bounds | None = None,
                       episode: int | None = None, key: Any = None, run: int | None = None) -> WorldStats:
    """`msg`: a DiagnosticArray or its serialized bytes; `key`: the run's (bytes, or a RunKey); `run`: the run
    nonce it must be sealed with (None: a RunKey's)."""
    _, values = _status(msg, bounds, False, key, run)
    f = _fields(_WORLD_FIELDS, partial(_take, values), text=True)
    returns = _take_indexed(values, "return.", "return.agv{}", 1, partial(as_float, text=True))
    if not returns:
        raise WireError("malformed", "no return keys, expected return.agv1..N")
    if bounds is not None and len(returns) != bounds.n_agents:
        raise WireError("unknown_agent" if len(returns) > bounds.n_agents else "malformed",
                        f"returns for {len(returns)} agents, the world has {bounds.n_agents}")
    counters = _take_counters(values)
    check_sequence(f["episode"], None, episode, None)
    return WorldStats(**f, returns=returns, counters=counters)


def encode_agent_stats(s: AgentStats, *, stamp: Time | None = None, key: bytes | None = None) -> DiagnosticArray:
    check_type(s, AgentStats)
    f = _fields(_AGENT_FIELDS, partial(getattr, s), text=False)
    marked = [_check_marked(m, f["agent"], None, f"marked.{i}") for i, m in enumerate(s.marked)]
    pairs = _pairs(f) + [(f"marked.{i}", _marked_text(m)) for i, m in enumerate(marked)]
    summary = (f"agv{f['agent']} ({f['algorithm']}) episode {f['episode']}: {f['joint_plays']} joint plays, "
               f"{len(marked)} marked joint states, {f['subscriptions_active']} live subscriptions")
    return _stats_msg(f"agv{f['agent']}", summary, pairs + _counter_pairs(s.counters), stamp, key)


def decode_agent_stats(msg: DiagnosticArray, *, bounds: Bounds | None = None, agent: int | None = None,
                       episode: int | None = None, key: Any = None, run: int | None = None) -> AgentStats:
    """As decode_world_stats."""
    hardware_id, values = _status(msg, bounds, True, key, run)
    f = _fields(_AGENT_FIELDS, partial(_take, values), text=True, bounds=bounds, agent=agent)
    if int(hardware_id[len("agv"):]) != f["agent"]:
        raise WireError("wrong_agent", f"status {hardware_id}/stats carries agent {f['agent']}")
    marked = _take_indexed(values, "marked.", "marked.{}", 0,
                           lambda k, text: _marked_of(k, text, f["agent"], bounds))
    counters = _take_counters(values)
    check_sequence(f["episode"], None, episode, None)
    return AgentStats(**f, marked=marked, counters=counters)


# -- a payload's fields and their pairs ---------------------------------------------------------------------

def _fields(fields: Mapping[str, tuple[str, str]], get: Callable[[str], Any], text: bool,
            bounds: Bounds | None = None, agent: int | None = None) -> dict[str, Any]:
    """Field -> value, `get` giving a payload's field or (`text`) its pair's text: every number read first,
    then each field judged in its range (the README's order of checks): the agent id of the map (and the one
    expected), a name of its form, any other number >= 0."""
    values = {key: _value(key, kind, get(key), text) for key, (kind, _) in fields.items()}
    for key, v in values.items():
        if key == "agent":
            check_agent(v, bounds, agent)
        elif fields[key][0] != "str":
            check_nonneg(key, v)
        elif not isinstance(v, str) or not _ALGO_RE.fullmatch(v):
            raise WireError("malformed", f"{key} {v!r} must match {_ALGO_RE.pattern}")
    return values


def _value(key: str, kind: str, v: Any, text: bool) -> Any:
    """Field `key`'s value of `kind` from a payload's `v`, or from its pair's text (`text`); a name as it is."""
    if kind == "str":
        return v
    if kind == "float":
        return as_float(key, v, text=text)
    if kind == "bool" and not text:
        return as_flag(key, v)
    if kind == "bool":
        if v not in ("true", "false"):
            raise WireError("malformed", f"{key} = {v!r}, must be true or false")
        return v == "true"
    wide = key in _WIDE_KEYS
    if not text:
        v = as_int(key, v, wide=wide)
        if v >= _WIDE_LIMIT:
            raise WireError("out_of_range", f"{key} has more than {WIDE_DIGITS} digits")
        return v
    if wide and len(v) > WIDE_DIGITS:
        raise WireError("out_of_range", f"{key} has {len(v)} digits, more than {WIDE_DIGITS}")
    if not _INT_RE.fullmatch(v):
        as_float(key, v, text=True)  # garbage is malformed, NaN not_finite; else it is a fraction
        raise WireError("not_integer", f"{key} = {v!r}")
    if not wide and len(v) > len(str(-INT32_MAX - 1)):  # no int32 (nor text int() reads without a ValueError)
        raise WireError("out_of_range", f"{key} has {len(v)} characters, more than any int32")
    return as_int(key, int(v), wide=wide)


def _text(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return repr(v) if isinstance(v, float) else str(v)  # repr: the shortest text that reads back the same double


def _pairs(fields: Mapping[str, Any]) -> list[tuple[str, str]]:
    return [(k, _text(v)) for k, v in fields.items()]


def _count(key: str, v: Any, text: bool) -> int:
    v = _value(key, "int", v, text)
    check_nonneg(key, v)
    return v


def _counter_pairs(counters: Mapping[str, int]) -> list[tuple[str, str]]:
    if len(counters) > COUNTERS_MAX:
        raise WireError("malformed", f"{len(counters)} counters, more than {COUNTERS_MAX}")
    pairs = []
    for name in sorted(counters):
        if not isinstance(name, str) or not _NAME_RE.fullmatch(name):
            raise WireError("malformed", f"counter name {name!r} must match {_NAME_RE.pattern}")
        pairs.append((f"count.{name}", str(_count(f"count.{name}", counters[name], text=False))))
    return pairs


def _take_counters(values: dict[str, str]) -> dict[str, int]:
    """The counters (`count.<name>`) of what is left of a status's pairs, which must be all that is left."""
    counters = {}
    for key in [k for k in values if k.startswith("count.")]:
        name = key[len("count."):]
        if not _NAME_RE.fullmatch(name):
            raise WireError("malformed", f"counter key {key!r}")
        counters[name] = _count(key, values.pop(key), text=True)
    if values:
        raise WireError("malformed", f"unknown keys {sorted(values)}")
    return counters


def _take(values: dict[str, str], key: str) -> str:
    try:
        return values.pop(key)
    except KeyError:
        raise WireError("malformed", f"key {key!r} missing") from None


def _take_indexed(values: dict[str, str], prefix: str, key: str, first: int,
                  read: Callable[[str, str], Any]) -> tuple:
    """What `read` makes of the pairs `key`.format(i), i from `first` on, as many as there are keys starting
    with `prefix`: a key of another form, or a gap, leaves one of them missing."""
    n = sum(k.startswith(prefix) for k in values)
    return tuple(read(k, _take(values, k)) for k in (key.format(i) for i in range(first, first + n)))


def _check_marked(m: MarkedJointState, agent: int, bounds: Bounds | None, where: str) -> MarkedJointState:
    if type(m) is not MarkedJointState:
        raise WireError("wrong_type", f"{where}: expected MarkedJointState, got {type(m).__name__}")
    row, col, peer, prow, pcol = (as_int(f"{where}.{f}", getattr(m, f))
                                  for f in ("row", "col", "peer", "peer_row", "peer_col"))
    conf = as_float(f"{where}.confidence", m.confidence)
    check_cell(row, col, bounds, f"{where} cell")
    check_agent(peer, bounds, None, f"{where} peer")
    if peer == agent:
        raise WireError("malformed", f"{where}: peer {peer} is the agent itself")
    check_cell(prow, pcol, bounds, f"{where} peer cell")
    return MarkedJointState(row, col, peer, prow, pcol, conf)


def _marked_text(m: MarkedJointState) -> str:
    return (f"cell={m.row},{m.col} peer=agv{m.peer} peer_cell={m.peer_row},{m.peer_col} "
            f"confidence={_text(m.confidence)}")


def _marked_of(key: str, text: str, agent: int, bounds: Bounds | None) -> MarkedJointState:
    m = _MARKED_RE.fullmatch(text)
    if not m:
        raise WireError("malformed", f"{key} = {text!r}")
    *cells, confidence = m.groups()
    marked = MarkedJointState(*map(int, cells), as_float(f"{key}.confidence", confidence, text=True))
    return _check_marked(marked, agent, bounds, key)


# -- the status: its name, pairs, MAC and seal -----------------------------------------------------------

def _stats_msg(hardware_id: str, summary: str, pairs: list[tuple[str, str]], stamp: Time | None,
               key: Any) -> DiagnosticArray:
    name = f"{hardware_id}/stats"
    secret = secret_of(key)
    if secret is not None:
        if type(key) is RunKey and key.run is not None:
            pairs = [*pairs, ("run", f"{key.run:016x}"), ("inc", f"{key.incarnation:08x}")]
        pairs = [*pairs, ("mac", _mac_hex(secret, name, hardware_id, pairs))]
    status = DiagnosticStatus(level=DiagnosticStatus.OK, name=name, message=summary, hardware_id=hardware_id,
                              values=[KeyValue(key=k, value=v) for k, v in pairs])
    arr = DiagnosticArray(status=[status])
    if stamp is not None:
        arr.header.stamp = stamp
    return arr


def _status(msg: Any, bounds: Bounds | None, agent: bool, key: Any, run: int | None) -> tuple[str, dict[str, str]]:
    """(hardware_id, key -> value but the MAC and the seal) of a world's statistic (an agent's: `agent`) given
    as a message or its bytes: one status named '<hardware_id>/stats'. Rejects repeated keys; with `key`, a
    status whose MAC is missing or does not match; given a run (`run`, else a RunKey's), a status sealed with
    another run or with none (`other_run`)."""
    msg = _message(msg, bounds, agent)
    if run is None and type(key) is RunKey:
        run = key.run
    key = secret_of(key)
    check_type(msg, DiagnosticArray)
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
        mac = values.pop("mac", None)
        if key is not None:
            if mac is None:
                raise WireError("unauthenticated", "statistics without a MAC, and this receiver holds the run's key")
            pairs = [(kv.key, kv.value) for kv in st.values if kv.key != "mac"]
            if not hmac.compare_digest(mac, _mac_hex(key, st.name, st.hardware_id, pairs)):
                raise WireError("unauthenticated", "the statistics' MAC does not match the run's key")
        _check_seal(values.pop("run", None), values.pop("inc", None), run)
        name, hw = st.name, st.hardware_id
    except (AttributeError, TypeError) as e:
        raise WireError("malformed", f"unreadable message: {e}") from None
    like = "agv<k>" if agent else "world"
    if name != f"{hw}/stats" or not re.fullmatch("agv" + DIGITS if agent else "world", hw):
        raise WireError("wrong_layout", f"status name {name!r} hardware_id {hw!r}, expected '{like}/stats' '{like}'")
    return hw, values


def _mac_hex(key: bytes, name: str, hardware_id: str, pairs: list[tuple[str, str]]) -> str:
    """The run's MAC of a status: every string length-prefixed, so no two statuses pack alike."""
    fields = [name, hardware_id, *(text for pair in pairs for text in pair)]
    packed = b"".join(struct.pack(">I", len(b)) + b for b in (f.encode() for f in fields))
    return "".join(f"{w:08x}" for w in mac_words(key, "stats", packed))


def _check_seal(sealed_run: str | None, incarnation: str | None, run: int | None) -> None:
    """A status's seal (its `run` and `inc` values, both or neither) well formed, and of `run` when one is
    expected (None: any)."""
    if (sealed_run is None) != (incarnation is None) or sealed_run is not None and not (
            _RUN_RE.fullmatch(sealed_run) and _INC_RE.fullmatch(incarnation)):
        raise WireError("malformed", f"seal run = {sealed_run!r} inc = {incarnation!r}, expected both or neither, "
                                     "of 16 and 8 hex digits")
    if run is not None and (sealed_run is None or int(sealed_run, 16) != run):
        raise WireError("other_run", f"statistics sealed to run {sealed_run}, this receiver's run is {run:016x}")


# -- how large a statistic can be, judged before it is deserialized ------------------------------------------

_KEY_CHARS = 64  # the longest key: a counter's name ('count.dropped.other_incarnation' is 31)
# Everything but the pairs: the encapsulation, the header (stamp, an empty frame_id), the status count, level,
# name, the one-line summary, hardware id and the pair count, with room to spare.
_HEAD_BYTES = 1024


def pairs_bound(bounds: Bounds, agent: bool) -> int:
    """The most pairs a statistic of a map of `bounds` can carry: a world's fixed keys, a return per agent,
    COUNTERS_MAX counters and the seal; an agent's fixed keys, a marked joint state per (own cell, peer, peer
    cell) of the grid, the counters and the seal."""
    cells = bounds.rows * bounds.cols
    fixed = (len(_AGENT_FIELDS) + cells * cells * (bounds.n_agents - 1) if agent
             else len(_WORLD_FIELDS) + bounds.n_agents)
    return fixed + COUNTERS_MAX + len(SEAL_KEYS)


def bytes_bound(pairs: int) -> int:
    """The longest serialized statistic of `pairs` pairs, each of the longest key and value (a state count of
    WIDE_DIGITS digits and a sign); a string on the wire is its length word, its characters and NUL, and up to 3
    bytes of alignment."""
    pair = (4 + _KEY_CHARS + 1 + 3) + (4 + WIDE_DIGITS + 1 + 1 + 3)
    return _HEAD_BYTES + pairs * pair


def _message(msg: Any, bounds: Bounds | None, agent: bool) -> Any:
    """`msg`, or the message of its serialized bytes, refused from their CDR header alone (unread) when they hold
    other than one status, or (with `bounds`) more pairs or bytes than a statistic of the map can."""
    if type(msg) is not bytes:
        return msg
    try:
        at = _string_end(msg, 12)  # after the encapsulation and the stamp: the frame_id
        at += -at % 4
        (statuses,) = struct.unpack_from("<I", msg, at)
        if statuses == 1:
            at += 4 + 1  # the status count; the level, a byte
            for _ in range(3):  # name, message, hardware_id
                at = _string_end(msg, at)
            at += -at % 4
            (pairs,) = struct.unpack_from("<I", msg, at)
    except (struct.error, ValueError) as e:
        raise WireError("malformed", f"not a serialized DiagnosticArray ({len(msg)} bytes): {e}") from None
    if statuses != 1:
        raise WireError("wrong_layout", f"{statuses} statuses, expected exactly 1")
    if bounds is not None:
        most = pairs_bound(bounds, agent)
        if pairs > most:
            raise WireError("malformed", f"{pairs} pairs, more than the {most} a statistic of this map carries")
        if len(msg) > bytes_bound(most):
            raise WireError("malformed", f"{len(msg)} bytes, more than the {bytes_bound(most)} of the longest "
                                         "statistic of this map")
    from rclpy.serialization import deserialize_message

    try:
        return deserialize_message(msg, DiagnosticArray)
    except Exception as e:  # rclpy raises its own errors for bytes that are no such message
        raise WireError("malformed", f"not a serialized DiagnosticArray: {e}") from None


def _string_end(raw: bytes, at: int) -> int:
    """Where the CDR string at `at` (aligned to 4 first) ends; ValueError if it is no string."""
    at += -at % 4
    (n,) = struct.unpack_from("<I", raw, at)
    if not 1 <= n <= len(raw) - at - 4 or raw[at + 4 + n - 1] != 0:
        raise ValueError(f"a string of {n} bytes at {at}")
    return at + 4 + n

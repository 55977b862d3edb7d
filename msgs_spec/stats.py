"""The statistics' codec: WorldStats and AgentStats as a diagnostic_msgs/DiagnosticArray holding one
DiagnosticStatus whose `values` are KeyValue pairs (WORLD_STATS_KEYS, AGENT_STATS_KEYS), keyed with a `mac`
pair and sealed with `run` and `inc`; decoders take a message or its serialized bytes, judge bytes from their
CDR header first (`_oversized`) and raise only `WireError` (msgs_spec/README.md, "The run's key",
"Validation and dropping")."""

from __future__ import annotations

import hmac
import re
import struct
from typing import Any, Mapping

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from .auth import RunKey, mac_words, secret_of
from .checks import as_flag, as_float, as_int, check_agent, check_cell, check_nonneg, check_sequence
from .errors import WireError
from .payloads import AgentStats, Bounds, MarkedJointState, WorldStats

__all__ = ["WORLD_STATS_NAME", "agent_stats_name", "WORLD_STATS_KEYS", "AGENT_STATS_KEYS", "COUNTERS_MAX",
           "pairs_bound", "bytes_bound", "encode_world_stats", "decode_world_stats", "encode_agent_stats",
           "decode_agent_stats"]

WORLD_STATS_NAME = "world/stats"


def agent_stats_name(agent: int) -> str:
    return f"agv{agent}/stats"


_MAC_KEY = "mac"
_RUN_KEY, _INC_KEY = "run", "inc"
_RUN_RE, _INC_RE = re.compile(r"[0-9a-f]{16}"), re.compile(r"[0-9a-f]{8}")
# The keyed form's pairs, last in every status: the seal (with a RunKey), then the MAC over everything before it.
SEAL_KEYS: Mapping[str, tuple[str, str]] = {
    _RUN_KEY: ("str", "keyed with a run: the run nonce, 16 hex digits (msgs_spec.auth)"),
    _INC_KEY: ("str", "keyed with a run: the sender's incarnation, 8 hex digits"),
    _MAC_KEY: ("str", "keyed: the run's HMAC over the name, hardware id and every pair before it, 32 hex digits"),
}

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
    **SEAL_KEYS,
}
AGENT_STATS_KEYS: Mapping[str, tuple[str, str]] = {
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
    "marked.<i>": ("str", "marked joint state i (0..M-1): "
                          "'cell=R,C peer=agvJ peer_cell=R,C confidence=X'"),
    "count.<name>": ("int", "further monotonic counters, e.g. count.dropped.stale_step"),
    **SEAL_KEYS,
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


def _parse_int(key: str, s: str, wide: bool = False) -> int:
    if wide and len(s) > WIDE_DIGITS:
        raise WireError("out_of_range", f"{key} has {len(s)} digits, more than {WIDE_DIGITS}")
    if not _INT_RE.fullmatch(s):
        as_float(key, s, text=True)  # garbage is malformed, NaN not_finite; else it is a fraction
        raise WireError("not_integer", f"{key} = {s!r}")
    return as_int(key, int(s), wide=wide)


def _parse_bool(key: str, s: str) -> bool:
    if s == "true":
        return True
    if s == "false":
        return False
    raise WireError("malformed", f"{key} = {s!r}, must be true or false")


def _counter_pairs(counters: Mapping[str, int]) -> list[tuple[str, str]]:
    if len(counters) > COUNTERS_MAX:
        raise WireError("malformed", f"{len(counters)} counters, more than {COUNTERS_MAX}")
    out = []
    for name in sorted(counters):
        if not isinstance(name, str) or not _NAME_RE.fullmatch(name):
            raise WireError("malformed", f"counter name {name!r} must match {_NAME_RE.pattern}")
        v = as_int(f"count.{name}", counters[name])
        check_nonneg(f"count.{name}", v)
        out.append((f"count.{name}", str(v)))
    return out



# -- how large a statistic can be, judged before it is deserialized ------------------------------------------

# A node counts a few dozen kinds of things (every WireError kind dropped, a dozen of its own, a checkpoint
# failure per errno seen): encoders refuse more counters than this, so no statistic carries more.
COUNTERS_MAX = 256
_KEY_CHARS = 64  # the longest key: a counter's name ('count.dropped.other_incarnation' is 31)
# Everything but the pairs: the encapsulation, the header (stamp, an empty frame_id), the status count, level,
# name, the one-line summary, hardware id and the pair count, with room to spare.
_HEAD_BYTES = 1024


def pairs_bound(bounds: Bounds, agent: bool) -> int:
    """The most pairs a statistic of a map of `bounds` can carry: a world's fixed keys, a return per agent,
    COUNTERS_MAX counters and the seal; an agent's fixed keys, a marked joint state per (own cell, peer, peer
    cell) of the grid, the counters and the seal."""
    cells = bounds.rows * bounds.cols
    fixed = len(_AGENT_INT_KEYS) + 1 + cells * cells * (bounds.n_agents - 1) if agent else 6 + bounds.n_agents
    return fixed + COUNTERS_MAX + len(SEAL_KEYS)


def bytes_bound(pairs: int) -> int:
    """The longest serialized statistic of `pairs` pairs, each of the longest key and value (a state count of
    WIDE_DIGITS digits and a sign); a string on the wire is its length word, its characters and NUL, and up to 3
    bytes of alignment."""
    pair = (4 + _KEY_CHARS + 1 + 3) + (4 + WIDE_DIGITS + 1 + 1 + 3)
    return _HEAD_BYTES + pairs * pair


def _string_end(raw: bytes, at: int) -> int:
    """Where the CDR string at `at` (aligned to 4 first) ends; ValueError if it is no string."""
    at += -at % 4
    (n,) = struct.unpack_from("<I", raw, at)
    if not 1 <= n <= len(raw) - at - 4 or raw[at + 4 + n - 1] != 0:
        raise ValueError(f"a string of {n} bytes at {at}")
    return at + 4 + n


def _oversized(raw: bytes, bounds: Bounds | None, agent: bool) -> WireError | None:
    """The refusal of a serialized DiagnosticArray read from its header alone (the counts of statuses and of the
    first status's pairs, and its length against the map's bounds), or None: deserialize it and check it."""
    try:
        at = _string_end(raw, 12)  # after the encapsulation and the stamp: the frame_id
        at += -at % 4
        (statuses,) = struct.unpack_from("<I", raw, at)
        if statuses != 1:
            return WireError("wrong_layout", f"{statuses} statuses, expected exactly 1")
        at += 4 + 1  # the level, a byte
        for _ in range(3):  # name, message, hardware_id
            at = _string_end(raw, at)
        at += -at % 4
        (pairs,) = struct.unpack_from("<I", raw, at)
    except (struct.error, ValueError) as e:
        return WireError("malformed", f"not a serialized DiagnosticArray ({len(raw)} bytes): {e}")
    if bounds is None:
        return None
    most = pairs_bound(bounds, agent)
    if pairs > most:
        return WireError("malformed", f"{pairs} pairs, more than the {most} a statistic of this map carries")
    if len(raw) > bytes_bound(most):
        return WireError("malformed", f"{len(raw)} bytes, more than the {bytes_bound(most)} of the longest statistic "
                                      "of this map")
    return None


def _message(msg: Any, bounds: Bounds | None, agent: bool) -> Any:
    """`msg`, or the message of serialized bytes that pass `_oversized` (refused otherwise, unread)."""
    if type(msg) is not bytes:
        return msg
    refusal = _oversized(msg, bounds, agent)
    if refusal is not None:
        raise refusal
    from rclpy.serialization import deserialize_message

    try:
        return deserialize_message(msg, DiagnosticArray)
    except Exception as e:  # rclpy raises its own errors for bytes that are no such message
        raise WireError("malformed", f"not a serialized DiagnosticArray: {e}") from None


def _mac_hex(key: bytes, name: str, hardware_id: str, pairs: list[tuple[str, str]]) -> str:
    """The run's MAC of a status: every string length-prefixed, so no two statuses pack alike."""
    fields = [name, hardware_id, *(text for pair in pairs for text in pair)]
    packed = b"".join(struct.pack(">I", len(b)) + b for b in (f.encode() for f in fields))
    return "".join(f"{w:08x}" for w in mac_words(key, "stats", packed))


def _stats_msg(name: str, hardware_id: str, summary: str, pairs: list[tuple[str, str]],
               stamp: Time | None, key: Any) -> DiagnosticArray:
    secret = secret_of(key)
    if secret is not None:
        if type(key) is RunKey and key.run is not None:
            pairs = [*pairs, (_RUN_KEY, f"{key.run:016x}"), (_INC_KEY, f"{key.incarnation:08x}")]
        pairs = [*pairs, (_MAC_KEY, _mac_hex(secret, name, hardware_id, pairs))]
    status = DiagnosticStatus(level=DiagnosticStatus.OK, name=name, message=summary, hardware_id=hardware_id,
                              values=[KeyValue(key=k, value=v) for k, v in pairs])
    arr = DiagnosticArray(status=[status])
    if stamp is not None:
        arr.header.stamp = stamp
    return arr


def _stats_values(msg: Any, key: Any, run: int | None = None) -> tuple[str, str, dict[str, str]]:
    """(status name, hardware_id, key -> value but the MAC and the seal) of a one-status DiagnosticArray;
    rejects repeated keys, with `key` a status whose MAC is missing or does not match, and given a run (`run`,
    else a RunKey's) a status sealed with another run or with none (`other_run`)."""
    if run is None and type(key) is RunKey:
        run = key.run
    key = secret_of(key)
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
        mac = values.pop(_MAC_KEY, None)
        if key is not None:
            if mac is None:
                raise WireError("unauthenticated", "statistics without a MAC, and this receiver holds the run's key")
            pairs = [(kv.key, kv.value) for kv in st.values if kv.key != _MAC_KEY]
            if not hmac.compare_digest(mac, _mac_hex(key, st.name, st.hardware_id, pairs)):
                raise WireError("unauthenticated", "the statistics' MAC does not match the run's key")
        _check_seal(values.pop(_RUN_KEY, None), values.pop(_INC_KEY, None), run)
        return st.name, st.hardware_id, values
    except (AttributeError, TypeError) as e:
        raise WireError("malformed", f"unreadable message: {e}") from None


def _check_seal(sealed_run: str | None, incarnation: str | None, run: int | None) -> None:
    """A status's seal (its `run` and `inc` values, both or neither) well formed, and of `run` when one is
    expected (None: any)."""
    if (sealed_run is None) != (incarnation is None):
        raise WireError("malformed", "a seal has both run and inc, or neither")
    if sealed_run is not None and not (_RUN_RE.fullmatch(sealed_run) and _INC_RE.fullmatch(incarnation)):
        raise WireError("malformed", f"seal run = {sealed_run!r} inc = {incarnation!r}, expected 16 and 8 hex digits")
    if run is None:
        return
    if sealed_run is None:
        raise WireError("other_run", f"statistics sealed to no run, this receiver's run is {run:016x}")
    if int(sealed_run, 16) != run:
        raise WireError("other_run", f"run {sealed_run}, this receiver's run is {run:016x}")


def _take(values: dict[str, str], key: str) -> str:
    try:
        return values.pop(key)
    except KeyError:
        raise WireError("malformed", f"key {key!r} missing") from None


def _take_counters(values: dict[str, str]) -> dict[str, int]:
    """The counters (`count.<name>`) of what is left of a status's pairs, which must be all that is left."""
    counters = {}
    for key in [k for k in values if k.startswith("count.")]:
        name = key[len("count."):]
        if not _NAME_RE.fullmatch(name):
            raise WireError("malformed", f"counter key {key!r}")
        v = _parse_int(key, values.pop(key))
        check_nonneg(key, v)
        counters[name] = v
    if values:
        raise WireError("malformed", f"unknown keys {sorted(values)}")
    return counters


def encode_world_stats(s: WorldStats, *, stamp: Time | None = None, key: bytes | None = None) -> DiagnosticArray:
    """`stamp`: header time (wall clock, e.g. node.get_clock().now().to_msg()); zero if None. `key`: the run's."""
    if type(s) is not WorldStats:
        raise WireError("wrong_type", f"expected WorldStats, got {type(s).__name__}")
    ints = {k: as_int(k, getattr(s, k)) for k in ("episode", "steps", "collisions", "missed_actions")}
    for k, v in ints.items():
        check_nonneg(k, v)
    truncated = as_flag("truncated", s.truncated)
    returns = [as_float(f"return.agv{i + 1}", r) for i, r in enumerate(s.returns)]
    if not returns:
        raise WireError("malformed", "returns is empty (one per agent)")
    duration = as_float("duration_s", s.duration_s)
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
    return _stats_msg(WORLD_STATS_NAME, "world", summary, pairs, stamp, key)


def decode_world_stats(msg: DiagnosticArray, *, bounds: Bounds | None = None,
                       episode: int | None = None, key: Any = None, run: int | None = None) -> WorldStats:
    """`msg`: a DiagnosticArray or its serialized bytes; `key`: the run's (bytes, or a RunKey); `run`: the run
    nonce it must be sealed with (None: a RunKey's)."""
    name, hw, values = _stats_values(_message(msg, bounds, False), key, run)
    if name != WORLD_STATS_NAME or hw != "world":
        raise WireError("wrong_layout", f"status name {name!r} hardware_id {hw!r}, "
                                        f"expected {WORLD_STATS_NAME!r} 'world'")
    ints = {}
    for k in ("episode", "steps", "collisions", "missed_actions"):
        ints[k] = _parse_int(k, _take(values, k))
        check_nonneg(k, ints[k])
    truncated = _parse_bool("truncated", _take(values, "truncated"))
    duration = as_float("duration_s", _take(values, "duration_s"), text=True)
    if duration < 0:
        raise WireError("out_of_range", f"duration_s = {duration}")
    found = {}
    for key in [k for k in values if k.startswith("return.")]:
        m = _RETURN_RE.fullmatch(key)
        if not m:
            raise WireError("malformed", f"key {key!r}, expected return.agv<k>")
        found[int(m.group(1))] = as_float(key, values.pop(key), text=True)
    n = len(found)
    if n == 0 or set(found) != set(range(1, n + 1)):
        raise WireError("malformed", f"return keys for agents {sorted(found)}, expected 1..{n or 'N'}")
    if bounds is not None and n != bounds.n_agents:
        raise WireError("unknown_agent" if n > bounds.n_agents else "malformed",
                        f"returns for {n} agents, the world has {bounds.n_agents}")
    counters = _take_counters(values)
    check_sequence(ints["episode"], None, episode, None)
    return WorldStats(episode=ints["episode"], steps=ints["steps"], truncated=truncated,
                      collisions=ints["collisions"], missed_actions=ints["missed_actions"],
                      returns=tuple(found[k] for k in range(1, n + 1)), duration_s=duration,
                      counters=counters)


_AGENT_INT_KEYS = ("agent", "episode", "joint_plays", "heard", "local_states", "joint_states",
                   "subscriptions_created", "subscriptions_active", "peer_messages")
# State counts of any size: a JS agent conditions on cells**N states (about 4.7e36 on warehouse_16), which
# the text of a diagnostic value carries exactly where an int32 could not. Bounded, so a forged value of a
# million digits is dropped before Python parses it.
_WIDE_KEYS = frozenset({"local_states", "joint_states"})
WIDE_DIGITS = 200
_WIDE_LIMIT = 10 ** WIDE_DIGITS  # the least count of more than WIDE_DIGITS digits


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


def encode_agent_stats(s: AgentStats, *, stamp: Time | None = None, key: bytes | None = None) -> DiagnosticArray:
    if type(s) is not AgentStats:
        raise WireError("wrong_type", f"expected AgentStats, got {type(s).__name__}")
    ints = {k: as_int(k, getattr(s, k), wide=k in _WIDE_KEYS) for k in _AGENT_INT_KEYS}
    if any(ints[k] >= _WIDE_LIMIT for k in _WIDE_KEYS):
        raise WireError("out_of_range", f"a state count of more than {WIDE_DIGITS} digits")
    check_agent(ints["agent"], None, None)
    for k in _AGENT_INT_KEYS[1:]:
        check_nonneg(k, ints[k])
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
    return _stats_msg(agent_stats_name(ints["agent"]), f"agv{ints['agent']}", summary, pairs, stamp, key)


def decode_agent_stats(msg: DiagnosticArray, *, bounds: Bounds | None = None, agent: int | None = None,
                       episode: int | None = None, key: Any = None, run: int | None = None) -> AgentStats:
    """As decode_world_stats."""
    name, hw, values = _stats_values(_message(msg, bounds, True), key, run)
    m = re.fullmatch(r"agv([0-9]+)/stats", name)
    if not m or hw != f"agv{m.group(1)}":
        raise WireError("wrong_layout", f"status name {name!r} hardware_id {hw!r}, "
                                        "expected 'agv<k>/stats' 'agv<k>'")
    ints = {}
    for k in _AGENT_INT_KEYS:
        ints[k] = _parse_int(k, _take(values, k), k in _WIDE_KEYS)
    check_agent(ints["agent"], bounds, agent)
    if int(m.group(1)) != ints["agent"]:
        raise WireError("wrong_agent", f"status {name!r} carries agent {ints['agent']}")
    for k in _AGENT_INT_KEYS[1:]:
        check_nonneg(k, ints[k])
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
        r, c, p, pr, pc = (as_int(key, int(g)) for g in vm.groups()[:5])
        conf = as_float(f"{key}.confidence", vm.group(6), text=True)
        found[int(km.group(1))] = _check_marked(MarkedJointState(r, c, p, pr, pc, conf), ints["agent"],
                                                bounds, key)
    if set(found) != set(range(len(found))):
        raise WireError("malformed", f"marked indices {sorted(found)}, expected 0..{len(found) - 1}")
    counters = _take_counters(values)
    check_sequence(ints["episode"], None, episode, None)
    return AgentStats(agent=ints["agent"], episode=ints["episode"], algorithm=algorithm,
                      joint_plays=ints["joint_plays"], heard=ints["heard"], local_states=ints["local_states"],
                      joint_states=ints["joint_states"], subscriptions_created=ints["subscriptions_created"],
                      subscriptions_active=ints["subscriptions_active"], peer_messages=ints["peer_messages"],
                      marked=tuple(found[i] for i in range(len(found))), counters=counters)



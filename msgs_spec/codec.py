"""encode(payload) -> standard ROS message; decode(message, what the receiver expects) -> payload: the entry
points over every payload (the arrays' codec is msgs_spec.arrays, the statistics' msgs_spec.stats). Every
decoder validates and raises only `WireError` for any input."""

from __future__ import annotations

from typing import Any, Callable

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from std_msgs.msg import Float64MultiArray, Int32MultiArray

from .arrays import (
    ACTION_LAYOUT, ARRAY_LAYOUTS, FEEDBACK_LAYOUT, HEARTBEAT_LAYOUT, LAYOUT_BY_PAYLOAD, LAYOUT_BY_WIRE,
    POSITION_LAYOUT, ArrayLayout, decode_action, decode_feedback, decode_heartbeat, decode_position, encode_action,
    encode_feedback, encode_heartbeat, encode_position,
)
from .checks import check_beat, check_sequence
from .errors import WireError
from .payloads import AgentStats, Bounds, WorldStats
from .stats import (
    AGENT_STATS_KEYS, WORLD_STATS_KEYS, WORLD_STATS_NAME, agent_stats_name, decode_agent_stats, decode_world_stats,
    encode_agent_stats, encode_world_stats,
)

__all__ = [
    "ArrayLayout", "FEEDBACK_LAYOUT", "POSITION_LAYOUT", "ACTION_LAYOUT", "HEARTBEAT_LAYOUT", "ARRAY_LAYOUTS",
    "WORLD_STATS_NAME", "agent_stats_name", "WORLD_STATS_KEYS", "AGENT_STATS_KEYS", "check_sequence", "check_beat",
    "encode_feedback", "decode_feedback", "encode_position", "decode_position",
    "encode_action", "decode_action", "encode_heartbeat", "decode_heartbeat", "encode_world_stats",
    "decode_world_stats", "encode_agent_stats", "decode_agent_stats", "encode", "serialize", "decode",
]


_STATS_ENCODERS: dict[type, Callable[..., Any]] = {WorldStats: encode_world_stats, AgentStats: encode_agent_stats}


def encode(payload: Any, *, key: bytes | None = None, stamp: Time | None = None) -> Any:
    """The ROS message for any payload: `key` keys it (msgs_spec.auth), `stamp` is the header time of
    statistics."""
    if type(payload) in LAYOUT_BY_PAYLOAD:
        return LAYOUT_BY_PAYLOAD[type(payload)].encode(payload, key=key)
    try:
        enc = _STATS_ENCODERS[type(payload)]
    except KeyError:
        raise WireError("wrong_type", f"no wire encoding for {type(payload).__name__}") from None
    return enc(payload, stamp=stamp, key=key)


def serialize(payload: Any, *, key: bytes | None = None, stamp: Time | None = None) -> Any:
    """What a node publishes for `payload` (rclpy's Publisher.publish takes either): for an array payload the
    bytes rclpy would serialize `encode(payload, key=key)` to (alignment bytes zero), built without a message
    object; for statistics the message, its header stamped `stamp` (an array has no header). Either way the
    same message goes on the wire."""
    layout = LAYOUT_BY_PAYLOAD.get(type(payload))
    if layout is None:
        return encode(payload, key=key, stamp=stamp)
    return layout.serialize(payload, key)


def decode(msg: Any, *, bounds: Bounds | None = None, agent: int | None = None,
           episode: int | None = None, step: int | None = None, key: bytes | None = None) -> Any:
    """Decode any project message, recognising the payload from the ROS type and the layout label or status
    name (messages are self-describing). Expectations that do not apply to the payload are ignored
    (`step` for statistics, `agent` for world statistics)."""
    t = type(msg)
    if t is DiagnosticArray:
        try:
            name = msg.status[0].name if len(msg.status) == 1 else ""
        except (AttributeError, TypeError, IndexError):
            name = ""
        if name == WORLD_STATS_NAME:
            return decode_world_stats(msg, bounds=bounds, episode=episode, key=key)
        return decode_agent_stats(msg, bounds=bounds, agent=agent, episode=episode, key=key)
    if t in (Float64MultiArray, Int32MultiArray):
        try:
            label = msg.layout.dim[0].label if len(msg.layout.dim) == 1 else None
        except (AttributeError, TypeError, IndexError):
            label = None
        layout = LAYOUT_BY_WIRE.get((t, label))
        if layout is None:
            raise WireError("wrong_layout", f"{t.__name__} with label {label!r} is no project payload")
        return layout.decode(msg, bounds=bounds, agent=agent, episode=episode, step=step, key=key)
    raise WireError("wrong_type", f"{t.__module__}.{t.__name__} is no project message type")

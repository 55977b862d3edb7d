"""cq_ros wire contract: topic names, standard message types, QoS, and validating encode/decode.

Nodes import this; it imports neither cq_ros nor any node code. Only common_interfaces message types are
used, so `ros2 topic echo` and `ros2 bag record` work on every topic of a full ROS 2 install.
See msgs_spec/README.md (its tables are generated from this code; `python -m msgs_spec --check`).

    from msgs_spec import (Bounds, Action, Feedback, Position, WireError, DropCounter,
                           action_topic, feedback_topic, position_topic, ACTION, FEEDBACK, POSITION)
    pub = node.create_publisher(ACTION.msg_type, action_topic(k), profile(ACTION.qos))  # node_runtime.qos
    pub.publish(encode_action(Action(agent=k, episode=e, step=s, action=EAST)))
    ...
    fb = drops.guard(decode_feedback, msg, bounds=bounds, agent=k, episode=e, step=s + 1,
                     source=feedback_topic(k))
"""

from .auth import KeyFileError, new_key_file, read_key, write_key_file
from .codec import (
    ACTION_LAYOUT, AGENT_STATS_KEYS, ARRAY_LAYOUTS, FEEDBACK_LAYOUT, HEARTBEAT_LAYOUT, POSITION_LAYOUT,
    WORLD_STATS_KEYS, WORLD_STATS_NAME, ArrayLayout, agent_stats_name, check_sequence, decode, decode_action,
    decode_agent_stats, decode_feedback, decode_heartbeat, decode_position, decode_world_stats, encode,
    encode_action, encode_agent_stats, encode_feedback, encode_heartbeat, encode_position, encode_world_stats,
    serialize,
)
from .errors import KINDS, DropCounter, WireError
from .payloads import (
    ACTION_NAMES, ACTIONS, EAST, INT32_MAX, NO_ACTION, NORTH, SOUTH, WEST, Action, AgentStats, Bounds, Feedback,
    Heartbeat, MarkedJointState, Position, WorldStats,
)
from .topics import (
    ACTION, AGENT_PREFIX, AGENT_STATS, FEEDBACK, HEARTBEAT, HEARTBEAT_TOPIC, POSITION, QOS_ACTION, Qos,
    QOS_FEEDBACK, QOS_POSITION, QOS_STATS, READER_DEPTH, TOPICS, WORLD_STATS, WORLD_STATS_TOPIC, TopicSpec,
    action_topic, agent_namespace, agent_stats_topic, agent_topics, feedback_topic, parse_topic,
    position_topic, qos_summary, type_name,
)

__all__ = [
    # payloads
    "NORTH", "EAST", "SOUTH", "WEST", "ACTIONS", "ACTION_NAMES", "NO_ACTION", "INT32_MAX",
    "Bounds", "Feedback", "Position", "Action", "Heartbeat", "MarkedJointState", "AgentStats", "WorldStats",
    # auth
    "KeyFileError", "new_key_file", "read_key", "write_key_file",
    # errors
    "KINDS", "WireError", "DropCounter",
    # codec
    "ArrayLayout", "FEEDBACK_LAYOUT", "POSITION_LAYOUT", "ACTION_LAYOUT", "HEARTBEAT_LAYOUT", "ARRAY_LAYOUTS",
    "WORLD_STATS_NAME", "agent_stats_name", "WORLD_STATS_KEYS", "AGENT_STATS_KEYS",
    "encode", "serialize", "decode", "check_sequence", "encode_feedback", "decode_feedback", "encode_position",
    "decode_position",
    "encode_action", "decode_action", "encode_heartbeat", "decode_heartbeat", "encode_world_stats",
    "decode_world_stats",
    "encode_agent_stats", "decode_agent_stats",
    # topics
    "AGENT_PREFIX", "Qos", "QOS_FEEDBACK", "QOS_ACTION", "QOS_POSITION", "QOS_STATS",
    "TopicSpec", "FEEDBACK", "POSITION", "ACTION", "HEARTBEAT", "AGENT_STATS", "WORLD_STATS", "TOPICS",
    "WORLD_STATS_TOPIC", "HEARTBEAT_TOPIC", "READER_DEPTH", "agent_namespace", "feedback_topic", "position_topic",
    "action_topic",
    "agent_stats_topic", "agent_topics", "parse_topic", "qos_summary", "type_name",
]

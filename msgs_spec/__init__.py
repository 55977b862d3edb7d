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

from . import codec, errors, payloads, topics
from .auth import KeyFileError, new_key_file, read_key, write_key_file
from .codec import *  # noqa: F403 (each module's __all__ says what it exports)
from .errors import *  # noqa: F403
from .payloads import *  # noqa: F403
from .topics import *  # noqa: F403

__all__ = [*payloads.__all__, "KeyFileError", "new_key_file", "read_key", "write_key_file", *errors.__all__,
           *codec.__all__, *topics.__all__]

"""What the nodes do around rclpy 7.1.6 from pip (Jazzy): the only module of ours that touches an rclpy
`handle` or a node's private state (tests/test_layout.py checks the handles). Each function says why it
exists; drop one when the rclpy the project runs on no longer needs it. It imports no rclpy itself (the cores
import node_runtime.parameters, which uses `given_parameters`).

- `raw_publisher`: rclpy 7.1.6's Publisher.publish(bytes) checks the type and takes the handle's lock at every
  call; the nodes publish serialized bytes every step and destroy their publishers only once they have
  stopped spinning, so they call what it calls, the handle's publish_raw, directly.
- `take_now`: rclpy 7.1.6's EventsExecutor learns of a message through the middleware's new-message callback,
  which it sets on a subscription after the node made it. rmw_fastrtps (Jazzy) reads the reader's unread count
  first and only then switches its data-available listener on: a latched sample that lands between the two is
  never announced, and sits in the reader until the next one (a peer's next position comes only after the
  world's step_timeout). Within one process the latched sample follows the match within a millisecond or two,
  often inside that window. An agent node takes a position still
  missing after a whole check period from the reader (agent_node.peer_subscriptions), as the executor would.
- `given_parameters`: rclpy 7.1.6 lists the parameters given to a node (command line, parameters file,
  parameter_overrides) only in the node's private `_parameter_overrides`, and ignores those the node does not
  declare; node_runtime.parameters.undeclared_overrides reads them to refuse a misspelt one.
"""

from __future__ import annotations

from typing import Any, Callable

__all__ = ["raw_publisher", "take_now", "given_parameters"]


def raw_publisher(pub: Any) -> Callable[[bytes], None]:
    """The publisher's own publish of serialized bytes: what Publisher.publish(bytes) calls, the same bytes,
    without its per-call type check and handle lock (call it only while the publisher lives)."""
    return pub.handle.publish_raw


def take_now(sub: Any) -> tuple | None:
    """The next message the subscription's reader holds, as the executor takes it ((message, info); raw bytes
    for a raw subscription), or None when it holds none."""
    with sub.handle:
        return sub.handle.take_message(sub.msg_type, sub.raw)


def given_parameters(node: Any) -> set[str]:
    """The names of every parameter given to `node`, declared or not."""
    return set(node._parameter_overrides)

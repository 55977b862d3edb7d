"""What a driver asks its agent node to do, in order: subscribe to, drop or renew a peer's position topic, send a
message, save a checkpoint, finish. Drivers return lists of these (`Effects`) and never touch ROS themselves,
so the protocol is tested without a ROS graph (tests/test_driver.py)."""

from __future__ import annotations

from dataclasses import dataclass

from cq_ros.learners import Learner
from msgs_spec import Action, AgentStats

__all__ = ["Subscribe", "Unsubscribe", "Renew", "Send", "SaveCheckpoint", "Finish", "Effects"]


@dataclass(frozen=True)
class Subscribe:
    peer: int  # agent id whose position topic to subscribe to (with msgs_spec POSITION.qos)


@dataclass(frozen=True)
class Unsubscribe:
    peer: int


@dataclass(frozen=True)
class Renew:
    """Drop the peer's position subscription and make it anew: it delivered nothing while waited for."""

    peer: int


@dataclass(frozen=True)
class Send:
    payload: Action | AgentStats  # on the topic of payload.agent


@dataclass(frozen=True)
class SaveCheckpoint:
    episode: int  # the last episode learnt
    # The learner as it was after that episode: named here because the driver may have moved on to its
    # greedy copy by the time the node carries the effect out.
    learner: Learner


@dataclass(frozen=True)
class Finish:
    """The last episode (the last greedy one, if any) is over: the node may exit."""


Effects = list  # of the effects above

"""The world node's side of the payload boundary: each message on agv<k>/action decoded (msgs_spec.arrays, the
one codec) with what the node knows before any step, and handed to the core, `world_node.lockstep.Lockstep`, as
an `Action`; each on world/heartbeat handed to `world_node.twin.Twins` as a `Heartbeat`.

The decode checks what holds for every action of the run: its layout and numbers, the map's bounds, that it
names the topic's agent, and with the run's key its MAC and seal. What needs the core's state, the step it
collects (stale_*, future_*) and whether the agent is asked, the core judges; a refusal here is counted in the
core's one DropCounter, under the kind and topic the core would count it by (`Lockstep.refused`), so the
world's statistics and report say the same as when the core decoded. No ROS here: tests/test_lockstep.py feeds
the core wire messages through it.
"""

from __future__ import annotations

from typing import Any

from msgs_spec import ACTION_LAYOUT, HEARTBEAT_TOPIC, DropCounter, WireError, decode_heartbeat

from .lockstep import Lockstep, Outbox
from .twin import Twins

__all__ = ["action_in", "heartbeat_in"]


def action_in(core: Lockstep, agent: int, msg: Any) -> Outbox:
    """A message on agv<agent>/action (its serialized bytes, or a message object): what the core returns for its
    Action, or for its refusal."""
    try:  # DropCounter.guard's work, without repacking the arguments of every action
        values, seal = ACTION_LAYOUT.read(msg, core.bounds, agent, key=core.key)
    except WireError as e:
        return core.refused(agent, e)
    return core.on_action(ACTION_LAYOUT.new(*values), seal)


def heartbeat_in(twins: Twins, drops: DropCounter, msg: Any) -> None:
    """A message on our namespace's world/heartbeat, decoded without the key (a twin of another launch has a key
    of its own): its Heartbeat to `twins`; one that fails the checks is counted in `drops` (the core's)."""
    hb = drops.guard(decode_heartbeat, msg, source=HEARTBEAT_TOPIC)
    if hb is not None:
        twins.heard(hb)

"""The agent node's side of the payload boundary; and for the drivers, the map's reading of a cell and a stamp's
gap named as msgs_spec names it (stale_*, future_*).

The node decodes each message (msgs_spec.arrays, the one codec) with what it knows before any step: the map's
bounds, the topic's agent, and with the run's key the MAC and the seal. It hands the driver (agent_node.driver)
the `Feedback`, `Position` or `Heartbeat`, and counts a refusal in the driver's one DropCounter under the topic
it came on, as the driver counted it when it decoded. What needs the driver's state, it judges: the stamps
(stale_*, future_*, far_ahead: agent_node.world_link, agent_node.peer_view), a heartbeat's beat (replayed), and
whether a position's peer is still listened to (one delivered after its subscription was dropped is counted, not
read). No ROS here: tests/test_driver.py feeds the drivers wire messages through it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable

from cq_ros.gridmap import GridMap
from msgs_spec import (
    HEARTBEAT_TOPIC, Bounds, DropCounter, WireError, check_sequence, decode_feedback, decode_heartbeat,
    decode_position, feedback_topic, position_topic,
)

if TYPE_CHECKING:
    from .driver import AgentDriver, CentralDriver
    from .effects import Effects

__all__ = ["bounds_of", "cell_of", "record_sequence", "feedback_in", "position_in", "heartbeat_in"]


def bounds_of(gridmap: GridMap) -> Bounds:
    return Bounds(gridmap.n_agents, gridmap.height, gridmap.width)


def cell_of(gridmap: GridMap, drops: DropCounter, row: int, col: int, source: str) -> int | None:
    """The cell index of (row, col); a '#' square inside the grid is refused like one outside it."""
    try:
        return gridmap.index(row, col)
    except KeyError:
        drops.record(WireError("cell_out_of_range", f"({row}, {col}) is not a cell of map {gridmap.name}"),
                     source)
        return None


def record_sequence(drops: DropCounter, stamp: tuple[int, int], expected: tuple[int, int], source: str) -> None:
    """Count a message stamped `stamp` where `expected` was due, as msgs_spec names the gap (stale_*, future_*)."""
    try:
        check_sequence(*stamp, *expected)
    except WireError as e:
        drops.record(e, source)


def feedback_in(driver: AgentDriver | CentralDriver, agent: int, msg: Any) -> Effects:
    """A message on agv<agent>/feedback (its serialized bytes, or a message object): the driver's effects for
    its Feedback, none for one refused."""
    fb = _decoded(decode_feedback, feedback_topic, driver, agent, msg)
    return [] if fb is None else driver.on_feedback(fb)


def position_in(driver: AgentDriver | CentralDriver, peer: int, msg: Any) -> Effects:
    """A message on agv<peer>/position: the driver's effects for its Position, none for one refused or of a
    peer no longer listened to (counted as delivered all the same: PeerView.delivered)."""
    if not driver.peers.delivered(peer):
        return []
    pos = _decoded(decode_position, position_topic, driver, peer, msg)
    return [] if pos is None else driver.on_position(pos)


def heartbeat_in(driver: AgentDriver | CentralDriver, msg: Any) -> Effects:
    """A message on world/heartbeat: the driver's effects for its Heartbeat, none for one refused."""
    hb = driver.drops.guard(decode_heartbeat, msg, key=driver.key, source=HEARTBEAT_TOPIC)
    return [] if hb is None else driver.on_heartbeat(hb)


def _decoded(decode: Callable[..., Any], topic: Callable[[int], str], driver: AgentDriver | CentralDriver,
             agent: int, msg: Any) -> Any:
    """`msg` decoded as a message on topic(agent), or None for one refused (logged and counted):
    DropCounter.guard's work, without repacking the arguments of every message, the topic's name made only for
    one refused."""
    try:
        return decode(msg, bounds=driver.bounds, agent=agent, key=driver.key)
    except WireError as e:
        driver.drops.record(e, topic(agent))
        return None

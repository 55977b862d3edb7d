"""Plain-Python payloads of the wire contract (no ROS import here): nodes build and read these, `msgs_spec.codec`
turns them into standard ROS messages and back. What each field holds: the layouts' `meanings` (msgs_spec.arrays)
and the statistics' keys (msgs_spec.stats), tabled in msgs_spec/README.md. Agents 1..N as in the map file; cells
(row, col) from 0, row 0 at the top; episodes and steps from 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

__all__ = [
    "NORTH", "EAST", "SOUTH", "WEST", "ACTIONS", "ACTION_NAMES", "NO_ACTION", "INT32_MAX",
    "Bounds", "Feedback", "Position", "Action", "Heartbeat", "MarkedJointState", "AgentStats", "WorldStats",
]

NORTH, EAST, SOUTH, WEST = 0, 1, 2, 3
ACTIONS = (NORTH, EAST, SOUTH, WEST)
ACTION_NAMES = ("NORTH", "EAST", "SOUTH", "WEST")
NO_ACTION = -1  # Feedback.applied when the world applied no action of this agent
INT32_MAX = 2**31 - 1
# An int32 in decimal in a name or a text: at most 10 digits. The patterns that read ids, cells and counts from
# text take no more, so no text reaches int() longer than it reads (Python's int() refuses more than 4,300
# digits with a ValueError, not a WireError).
DIGITS, ID_DIGITS = "[0-9]{1,10}", "[1-9][0-9]{0,9}"


@dataclass(frozen=True, slots=True)
class Bounds:
    """What a receiver knows about the world, to validate against: N agents (ids 1..N), an H x W grid."""

    n_agents: int
    rows: int
    cols: int

    def __post_init__(self) -> None:
        for name in ("n_agents", "rows", "cols"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"Bounds.{name} must be a positive int, got {v!r}")


@dataclass(frozen=True, slots=True)
class Feedback:
    """World -> one agent, once per step: the agent's observation at (episode, step) and the outcome of the
    transition that led there; an agent learns from a step only when its own action was `applied`."""

    agent: int
    episode: int
    step: int
    row: int
    col: int
    reward: float
    done: bool = False  # the agent is at its goal (absorbing): it sends no more actions this episode
    truncated: bool = False  # the episode hit the step cap at this step (never together with done)
    applied: int = NO_ACTION  # the action applied for this agent into this step, 0..3, or NO_ACTION


@dataclass(frozen=True, slots=True)
class Position:
    """World -> anyone (latched): where `agent` is at (episode, step)."""

    agent: int
    episode: int
    step: int
    row: int
    col: int


@dataclass(frozen=True, slots=True)
class Action:
    """Agent (or the JSA central node) -> world: `agent`'s action answering the feedback of (episode, step)."""

    agent: int
    episode: int
    step: int
    action: int  # 0..3 = NORTH, EAST, SOUTH, WEST


@dataclass(frozen=True, slots=True)
class Heartbeat:
    """World -> agents and other worlds, every heartbeat_period whether or not anyone acts: the world is alive,
    and collects the actions of (episode, step); `stepping`, `started` and `ticket` say who the world is to a
    second world in its namespace (world_node.twin)."""

    beat: int
    episode: int
    step: int
    stepping: int = 1  # 1 once the world has begun stepping, 0 while it waits for its agents
    started: int = 0  # the second the world node started, Unix time (as builtin_interfaces/Time.sec)
    ticket: int = 0  # drawn at the world's start, 0..2**31-1: orders two worlds started in the same second


@dataclass(frozen=True, slots=True)
class MarkedJointState:
    """One joint state a CQ agent has marked: its own cell together with one peer's cell, and the confidence."""

    row: int
    col: int
    peer: int
    peer_row: int
    peer_col: int
    confidence: float


@dataclass(frozen=True)
class AgentStats:
    """Agent -> tools, once per episode (published when the agent's episode ends). `counters` holds any further
    monotonic counts, e.g. DropCounter.as_counters() -> {"dropped.stale_step": 2}."""

    agent: int
    episode: int
    algorithm: str
    joint_plays: int = 0  # times this episode the agent acted on global information (CQ) / chose COORDINATE (LoC)
    heard: int = 0  # peer positions the learner's decisions took in this episode (cq_ros.episode: `heard`)
    local_states: int = 0  # local states in use
    joint_states: int = 0  # joint states in use (CQ: marked joint states; JS: all joint states seen)
    subscriptions_created: int = 0  # peer position subscriptions created since start (communication cost)
    subscriptions_active: int = 0  # peer position subscriptions alive now
    peer_messages: int = 0  # peer position messages delivered since start (the cost is `heard`, what it used)
    marked: tuple[MarkedJointState, ...] = ()
    counters: Mapping[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class WorldStats:
    """World -> tools, once per episode (published when the episode ends)."""

    episode: int
    steps: int  # joint steps taken in this episode
    truncated: bool  # ended by the step cap, not by every agent reaching its goal
    collisions: int  # collisions in this episode, as the world counts them
    missed_actions: int  # actions that did not arrive before the step timeout (the agent stayed)
    returns: tuple[float, ...]  # undiscounted return of agent k at index k-1
    duration_s: float = 0.0  # wall-clock length of the episode
    counters: Mapping[str, int] = field(default_factory=dict)

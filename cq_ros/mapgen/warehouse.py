"""Generated warehouses in the map format of ``cq_ros.gridmap``: AGVs that start at docks on the cross-aisles
and each bring a load to a pick station of its own.

Laid out as real ones are (rows from the top)::

    2 rows   top cross-aisle, two lanes, open between them: AGVs going opposite ways pass each other
    1 row    one one-lane entrance per aisle (above its left lane): the paper's corridor-entrance conflict
    L rows   the aisles, two lanes each, between shelf racks ('#'); pick stations are bays cut into the
             racks, each a dead end open only to the lane beside it, so an AGV parked at its goal blocks nobody
    1 row    one one-lane entrance per aisle (below its right lane): in at the top, down the left lane, up the
             right lane and out at the bottom is right-hand traffic
    2 rows   bottom cross-aisle, as the top one

With ``blocks`` above 1, that band of aisles repeats below itself, each band's bottom cross-aisle the next
one's top: a warehouse for a large fleet grows down as well as across.

Each aisle has one bay per row, on its left rack in odd rows and its right rack in even ones (counted from
the aisle's first row), so the rack between two aisles serves both without a bay open to both.
Starts (distinct cross-aisle cells) and goals (distinct bays) are drawn by ``random.Random(seed)``, and the
result is checked, not assumed: every agent reaches its goal from its start while every other agent stands
parked at its own goal (``GridMap.goal_blocked_by_parked``).

Generated maps carry three defaults of their own (``set`` lines, see ``cq_ros.gridmap``), each said why in
MAP_DEFAULTS: steps cost (reward_step=-1), a longer discount (gamma=0.98), for goals that lie 15 to 35 steps
from the docks, and exploration that falls to 0 by episode 1,500 (epsilon_decay_episodes=1500), so that what
is learnt last is the timing of the greedy policy.
"""

from __future__ import annotations

import math
import textwrap

from ..gridmap import GridMap, _render, _STEPS, parse_map
from ..settings import Settings, SettingsError
from .draw import check_sizes, draw_starts_and_goals

__all__ = ["DEFAULT_AISLE_LENGTH", "DELAY_DEFAULTS", "DELAYED_COLLISION", "MAP_DEFAULTS", "default_aisles",
           "warehouse_command", "warehouse_map", "warehouse_text"]

DEFAULT_AISLE_LENGTH = 6
# Setting -> (value, why). On warehouse_16, indep with reward_step=-1 and gamma 0.9 ran 924 of 1,000 episodes
# to the 5,000-step cap; with gamma 0.98, 17 of 3,000, and every greedy policy got all home (docs/warehouses.md,
# "The maps").
MAP_DEFAULTS = {
    "reward_step": ("-1", "steps cost: with free steps, learners wander in the safe cross-aisles rather than "
                          "cross an entrance where they have collided"),
    "gamma": ("0.98", "a goal 30 steps away is discounted by 0.9^30 = 0.04 at the paper's gamma, too little to "
                      "tell arriving from wandering for ever; by 0.98^30 = 0.55 here"),
    # Measured on warehouse_16, 10 runs x 2,000 episodes per seed (docs/warehouses.md): CQ's greedy policies were
    # collision-free in 17 of 20 runs at a fixed 0.1 (seeds 0, 1), in 48 of 50 with epsilon at 0 by episode 2,000
    # (seeds 0-4), and in 50 of 50 by episode 1,500.
    "epsilon_decay_episodes": ("1500", "exploration falls to 0 by episode 1,500, so that the last 500 of 2,000 "
                                       "episodes learn the greedy policy's own timing: at the paper's fixed "
                                       "epsilon 0.1, at least one of 16 AGVs moves at random at 81% of steps, and "
                                       "the greedy policy's first meetings collide"),
}

Cell = tuple[int, int]


def default_aisles(agents: int, blocks: int = 1) -> int:
    """Aisles when none are asked for: 2 + ceil(agents / (4 blocks)), two to three AGVs per aisle (4 for 8
    AGVs, 6 for 16, 10 for 32, 18 for 64, 34 for 128; 10 for 128 in 4 blocks), so that conflicts stay at
    entrances and the map stays small for tabular learners."""
    return 2 + math.ceil(agents / (4 * blocks))


def _layout(aisles: int, aisle_length: int,
            blocks: int = 1) -> tuple[int, int, set[frozenset[Cell]], list[Cell], list[Cell]]:
    """Height, width, the open passages (pairs of cells), the docks (cross-aisle cells) and the bays."""
    band = aisle_length + 4  # from one cross-aisle's first row to the next one's
    height, width = blocks * band + 2, 3 * aisles + 1
    tops = [k * band for k in range(blocks + 1)]  # each cross-aisle's first row
    docks = [(row, col) for top in tops for row in (top, top + 1) for col in range(width)]
    passages: set[frozenset[Cell]] = set()

    def join(a: Cell, b: Cell) -> None:
        passages.add(frozenset((a, b)))

    for top in tops:  # each cross-aisle: two full rows, open everywhere between them
        for col in range(width):
            join((top, col), (top + 1, col))
            if col + 1 < width:
                join((top, col), (top, col + 1))
                join((top + 1, col), (top + 1, col + 1))
    bays = []
    for top in tops[:-1]:
        first, last = top + 3, top + 3 + aisle_length - 1  # the aisles' rows
        for aisle in range(aisles):
            left, right = 3 * aisle + 1, 3 * aisle + 2
            join((top + 1, left), (top + 2, left))  # the top entrance
            join((top + 2, left), (first, left))
            join((last, right), (last + 1, right))  # the bottom entrance
            join((last + 1, right), (top + band, right))
            for row in range(first, last + 1):
                join((row, left), (row, right))
                if row < last:
                    join((row, left), (row + 1, left))
                    join((row, right), (row + 1, right))
                lane, rack = (left, left - 1) if (row - first) % 2 else (right, right + 1)
                join((row, lane), (row, rack))
                bays.append((row, rack))
    return height, width, passages, docks, sorted(bays)


# Setting -> why, for the delays a generated map may carry (cq_ros.world, "Delays"); written only when asked for.
# With any delay the map also carries DELAYED_COLLISION: following an AGV directly costs, in expectation, the
# slip times the collision penalty (the one ahead is delayed and rear-ended), against one step lost by waiting;
# with the default -10 at slip 0.1 the two are equal, and no learner learns to keep its distance.
DELAYED_COLLISION = ("-30", "collisions cost -30, not -10: behind an AGV that may be delayed with probability p, "
                            "moving on costs p times the penalty in expectation and waiting one step, so waiting "
                            "pays only where the penalty exceeds 1/p steps; -30 makes it pay for slips down to "
                            "0.04 (at 0.1 and -10 the two are even)")
DELAY_DEFAULTS = {
    "slip": "AGVs are delayed: at every step an AGV's move fails with this probability and it stays (a person "
            "in the aisle, a wheel slipping), so a meeting's timing is not known in advance",
    "start_hold": "each AGV waits 0 to this many steps at its dock before its first move (a slow load), drawn "
                  "anew every episode",
}


def warehouse_command(agents: int, aisles: int, aisle_length: int, seed: int, slip: float = 0.0,
                      start_hold: int = 0, blocks: int = 1) -> str:
    """The `cq-ros generate` command line that makes this warehouse (written in the map's header)."""
    delays = (f" --slip {slip:g}" if slip else "") + (f" --start-hold {start_hold}" if start_hold else "")
    return (f"cq-ros generate warehouse --agents {agents} --aisles {aisles} --aisle-length {aisle_length} "
            f"{f'--blocks {blocks} ' if blocks != 1 else ''}--seed {seed}{delays}")


def _sizes(agents: int, aisles: int | None, aisle_length: int | None, blocks: int = 1) -> tuple[int, int]:
    """(aisles, aisle_length) with the defaults filled in; ValueError for a size below 1."""
    check_sizes(blocks=blocks)
    aisles = default_aisles(agents, blocks) if aisles is None else aisles
    aisle_length = DEFAULT_AISLE_LENGTH if aisle_length is None else aisle_length
    check_sizes(agents=agents, aisles=aisles, aisle_length=aisle_length)
    return aisles, aisle_length


def warehouse_text(agents: int, aisles: int | None = None, aisle_length: int | None = None, seed: int = 0,
                   slip: float = 0.0, start_hold: int = 0, blocks: int = 1) -> str:
    """A generated warehouse as map text. ``aisles`` defaults to ``default_aisles(agents, blocks)``,
    ``aisle_length`` to DEFAULT_AISLE_LENGTH; ``blocks`` bands of aisles stand one below the other; ``slip`` and
    ``start_hold``, when not 0, become map defaults (DELAY_DEFAULTS). ValueError names what does not fit (too
    few bays or docks for the agents, a delay out of range)."""
    aisles, aisle_length = _sizes(agents, aisles, aisle_length, blocks)
    delays = {"slip": slip, "start_hold": start_hold}
    try:
        Settings().with_overrides(delays)
    except SettingsError as e:
        raise ValueError(str(e)) from None
    height, width, passages, docks, bays = _layout(aisles, aisle_length, blocks)
    band = f"{aisles} aisles of length {aisle_length}" + (f" in {blocks} blocks" if blocks != 1 else "")
    starts, goals = draw_starts_and_goals(agents, seed, ("dock cells on the cross-aisles", docks),
                                          ("pick stations (one per aisle row)", bays), band, "give more aisles")

    def is_open(row: int, col: int, action: int) -> bool:
        d_row, d_col = _STEPS[action]
        return frozenset(((row, col), (row + d_row, col + d_col))) in passages

    world = {cell for pair in passages for cell in pair}
    header = [
        f"# Generated warehouse, {agents} AGVs: {aisles} two-lane aisles of {aisle_length} cells between shelf racks",
        "# ('#'), each joined to the two-lane cross-aisles (top and bottom) by one-lane entrances.",
        *([f"# {blocks} such blocks stand one below the other, each sharing its cross-aisles with its neighbours."]
          if blocks != 1 else []),
        f"# Generated by: {warehouse_command(agents, aisles, aisle_length, seed, slip, start_hold, blocks)}",
        "# Starts on the cross-aisles (docks); each goal is a bay cut into a rack (a pick station), open only to",
        "# its aisle, where a parked AGV blocks nobody.",
    ]
    agent_lines = [f"agent {k}: start {s[0]},{s[1]}  goal {g[0]},{g[1]}"
                   for k, (s, g) in enumerate(zip(starts, goals), start=1)]
    set_lines = ["# Map defaults (`--set` overrides them)."]
    chosen = {**MAP_DEFAULTS, **{k: (f"{v:g}", DELAY_DEFAULTS[k]) for k, v in delays.items() if v}}
    if slip or start_hold:
        chosen["reward_collision"] = DELAYED_COLLISION
    for key, (value, why) in chosen.items():
        set_lines += [f"# {line}" for line in textwrap.wrap(f"{why[0].upper()}{why[1:]}.", 100)]
        set_lines.append(f"set {key}={value}")
    drawing = _render(height, width, dict.fromkeys(world, "."), is_open)
    text = "\n".join(header + agent_lines + set_lines + [""] + drawing) + "\n"
    _check_parked(parse_map(text, name="warehouse"), seed)
    return text


def _check_parked(gridmap: GridMap, seed: int) -> None:
    """The generator's promise, checked on the parsed map (the layout makes it hold; this says so if not)."""
    blocked = gridmap.goal_blocked_by_parked()
    if blocked:
        raise RuntimeError(f"generated warehouse (seed {seed}) breaks its promise: agent(s) "
                           f"{', '.join(str(i + 1) for i in blocked)} cannot reach their goal with the others "
                           "parked at theirs")


def warehouse_map(agents: int, aisles: int | None = None, aisle_length: int | None = None, seed: int = 0,
                  name: str | None = None, slip: float = 0.0, start_hold: int = 0, blocks: int = 1) -> GridMap:
    """The generated warehouse, parsed (named ``warehouse_<agents>`` unless ``name`` is given)."""
    aisles, aisle_length = _sizes(agents, aisles, aisle_length, blocks)
    return parse_map(warehouse_text(agents, aisles, aisle_length, seed, slip, start_hold, blocks),
                     name=name or f"warehouse_{agents}",
                     source=f"<{warehouse_command(agents, aisles, aisle_length, seed, slip, start_hold, blocks)}>")

"""A centralised multi-agent path planner under the world's own rules: the yardstick the learners are
measured against, not a learner.

The rules are those of `cq_ros.world`: every agent that has not arrived moves every step; it stays put only
by bumping into a wall, the edge or a '#' cell, so it can wait only in a cell with a blocked direction; two
agents may not end a step in one cell unless it is a goal of both, nor swap cells; an agent that reaches its
goal stays there for good (and an agent bound for the same goal may still enter it). The MAPF packages on
PyPI (cbs-mapf, unchanged since 2020, and course projects) give every agent a free wait action, so plans
they find can fail in this world; the search here is small enough to own.

Two searches share one space-time A* (`find_path`), which obeys a set of `Rules` (cells and moves forbidden
at given steps, goals of others held for good from their arrival):
- conflict-based search (Sharon et al. 2015), ties broken by conflicts: optimal sum of costs, within a
  budget of search nodes (enough for 8 and 16 AGVs, not for 32);
- prioritized planning: each agent in turn avoids the paths of those before it, over a few deterministic
  priority orders (farthest first, then the agent that failed first, then shuffles drawn from the seed),
  then improved by large neighbourhood search (replanning a few agents at a time around the others).
`plan` tries the first and falls back on the second. `validate` replays a plan through `GridWorld.step_joint`,
so a plan is checked against the world, not against the planner's model of it.

Sum of costs = the sum over agents of the step at which each arrives, as the world counts them.
"""

from __future__ import annotations

import heapq
import random
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import count
from math import factorial

from ..gridmap import GridMap
from ..world import GridWorld

_NEVER = float("inf")


class NoPlan(Exception):
    """No plan was found within the search budget (the instance may still be solvable)."""


class OutOfTime(NoPlan):
    """The time limit passed before a plan was found."""


def _check(deadline: float) -> None:
    if time.monotonic() > deadline:
        raise OutOfTime


class PlanError(ValueError):
    """A plan that the world does not carry out: a collision, an agent left short of its goal, a mismatch."""


@dataclass(frozen=True)
class Plan:
    """Each agent's cells at steps 0..arrival (it stays at its goal afterwards) and the actions that take it
    there; `method` says which search found it, `lower_bound` what the least sum of costs is proven to be at
    least (the planner's search, or each agent's shortest path alone)."""

    paths: tuple[tuple[int, ...], ...]
    actions: tuple[tuple[int, ...], ...]
    method: str
    lower_bound: int

    @property
    def arrivals(self) -> tuple[int, ...]:
        return tuple(len(path) - 1 for path in self.paths)

    @property
    def makespan(self) -> int:
        return max(self.arrivals)

    @property
    def sum_of_costs(self) -> int:
        return sum(self.arrivals)

    @property
    def optimal(self) -> bool:
        return self.sum_of_costs == self.lower_bound


# --- the rules one agent's search obeys ------------------------------------------------------------------


@dataclass
class Rules:
    """What one agent may not do: be in `cells` (step, cell), make `moves` (step, from, to) ending at that
    step, or be in a cell of `held` at or after the step given (another agent's goal, occupied for good)."""

    cells: set = field(default_factory=set)
    moves: set = field(default_factory=set)
    held: dict = field(default_factory=dict)

    def __post_init__(self):
        self.last_at: dict[int, int] = {}
        for t, cell in self.cells:
            self.last_at[cell] = max(t, self.last_at.get(cell, -1))
        # After this step nothing changes any more, so states later than it differ only in their step.
        self.horizon = max([t for t, _ in self.cells] + [m[0] for m in self.moves] + list(self.held.values()),
                           default=0)

    def forbids(self, t: int, here: int, there: int) -> bool:
        return (t, there) in self.cells or (t, here, there) in self.moves or self.held.get(there, _NEVER) <= t

    def may_arrive(self, goal: int, t: int) -> bool:
        """Arriving at step t means staying for good, so nothing may forbid the goal at t or later."""
        return self.last_at.get(goal, -1) < t

    @classmethod
    def from_constraints(cls, constraints: frozenset) -> "Rules":
        """Rules from conflict-based search's constraints ("at", t, cell) and ("move", t, from, to)."""
        cells = {c[1:] for c in constraints if c[0] == "at"}
        moves = {c[1:] for c in constraints if c[0] == "move"}
        return cls(cells, moves, {})

    @classmethod
    def avoiding(cls, paths: list[tuple[int, ...]], goals: list[int], goal: int) -> "Rules":
        """Rules for an agent bound for `goal` that must keep clear of agents following `paths` to `goals`."""
        cells, moves, held = set(), set(), {}
        for path, their_goal in zip(paths, goals):
            shared = their_goal == goal
            cells.update((t, cell) for t, cell in enumerate(path) if not (shared and cell == goal))
            moves.update((t, path[t], path[t - 1]) for t in range(1, len(path)) if path[t] != path[t - 1])
            if not shared:
                held[their_goal] = min(len(path) - 1, held.get(their_goal, _NEVER))
        return cls(cells, moves, held)


# --- one agent: space-time A* -----------------------------------------------------------------------------


def distances_to(gridmap: GridMap, goal: int) -> list[float]:
    """Fewest moves from every cell to `goal` on the empty map (inf where it cannot be reached)."""
    into: list[list[int]] = [[] for _ in range(gridmap.n_cells)]
    for cell, targets in enumerate(gridmap.neighbours):
        for there in set(targets) - {cell}:
            into[there].append(cell)
    dist = [_NEVER] * gridmap.n_cells
    dist[goal] = 0
    frontier = deque([goal])
    while frontier:
        cell = frontier.popleft()
        for before in into[cell]:
            if dist[before] == _NEVER:
                dist[before] = dist[cell] + 1
                frontier.append(before)
    return dist


def find_path(gridmap: GridMap, start: int, goal: int, dist: list[float], rules: Rules,
              busy: frozenset = frozenset()) -> tuple[int, ...] | None:
    """The earliest-arriving path from `start` to `goal` under `rules` (cells at steps 0..arrival), or None;
    among the earliest, one through the fewest (step, cell) of `busy` (where the other agents are).

    A state is (cell, step), with steps past the last of `rules` and `busy` merged, so the search is finite.
    Successors are the cells the four actions lead to; the cell itself only where an action bumps (that is
    how one waits).
    """
    if start == goal:
        return (start,) if rules.may_arrive(goal, 0) else None
    settle = max([rules.horizon] + [t for t, _ in busy])
    best = {(start, 0): (0, 0)}
    parent: dict[tuple[int, int], tuple[int, int]] = {}
    heap = [(dist[start], 0, 0, start)]  # (f, conflicts, -step, cell): then the deepest first
    closed = set()
    while heap:
        _, crossed, minus_t, cell = heapq.heappop(heap)
        t = -minus_t
        key = (cell, min(t, settle))
        if key in closed:
            continue
        closed.add(key)
        if cell == goal:
            return _walk_back(parent, key, t)
        for there in dict.fromkeys(gridmap.neighbours[cell]):
            if dist[there] == _NEVER or rules.forbids(t + 1, cell, there):
                continue
            if there == goal and not rules.may_arrive(goal, t + 1):
                continue  # reaching one's goal ends the journey, so no passing through it
            nxt, cost = (there, min(t + 1, settle)), (t + 1, crossed + ((t + 1, there) in busy))
            if cost < best.get(nxt, (_NEVER,)):
                best[nxt], parent[nxt] = cost, key
                heapq.heappush(heap, (t + 1 + dist[there], cost[1], -(t + 1), there))
    return None


def _walk_back(parent: dict, key: tuple[int, int], length: int) -> tuple[int, ...]:
    cells = [key[0]]
    for _ in range(length):
        key = parent[key]
        cells.append(key[0])
    return tuple(reversed(cells))


# --- many agents ------------------------------------------------------------------------------------------


def conflicts(paths: list[tuple[int, ...]], goals: tuple[int, ...]):
    """The conflicts in the world's terms, earliest first: ("at", t, cell, i, j) where agents i and j end
    step t in one cell that is not a goal of both, ("move", t, a, b, i, j) where i moves a->b as j moves b->a."""
    length = max(len(p) for p in paths)
    padded = [path + path[-1:] * (length - len(path)) for path in paths]  # at their goals for good
    for t in range(1, length):
        here: dict[int, int] = {}
        moving: dict[tuple[int, int], int] = {}
        for i, path in enumerate(padded):
            cell = path[t]
            j = here.setdefault(cell, i)
            if j != i and not goals[i] == goals[j] == cell:
                yield ("at", t, cell, j, i)
            move = (path[t - 1], cell)
            if move[0] != move[1]:
                if (move[1], move[0]) in moving:
                    yield ("move", t, *move, i, moving[(move[1], move[0])])
                moving[move] = i


def conflict_based_search(gridmap: GridMap, dists: list[list[float]], max_nodes: int,
                          progress: Callable[[int], None] | None = None,
                          deadline: float = _NEVER) -> tuple[list | None, int]:
    """(paths with the least sum of costs, that sum), or (None, a lower bound on it) if none was found within
    `max_nodes` search nodes or by `deadline` (time.monotonic()).

    Among nodes of equal cost the one with the fewest conflicts goes first, a replanned agent takes, among
    its earliest paths, one through the fewest cells the others occupy, and a node adopts a child as cheap as
    itself with fewer conflicts instead of branching: all three only speed the search."""
    starts, goals, n = gridmap.starts, gridmap.goals, gridmap.n_agents
    constraints = [frozenset()] * n
    paths = [find_path(gridmap, starts[i], goals[i], dists[i], Rules()) for i in range(n)]
    if any(p is None for p in paths):
        return None, 0
    tie = count()
    rank = _rank(paths, goals)
    open_nodes = [(rank, next(tie), constraints, paths)]
    for expanded in range(max_nodes):
        if not open_nodes or time.monotonic() > deadline:
            break
        if progress and expanded % 100 == 0:
            progress(expanded)
        rank, _, constraints, paths = heapq.heappop(open_nodes)
        conflict = next(conflicts(paths, goals), None)
        if conflict is None:
            return paths, rank[0]
        children = []
        for agent, constraint in _split(conflict):
            mine = constraints[agent] | {constraint}
            busy = frozenset((t, cell) for j, p in enumerate(paths) if j != agent for t, cell in enumerate(p))
            path = find_path(gridmap, starts[agent], goals[agent], dists[agent], Rules.from_constraints(mine), busy)
            if path is None:
                continue
            child_paths = paths[:agent] + [path] + paths[agent + 1:]
            child_rank = _rank(child_paths, goals)
            if child_rank[0] == rank[0] and child_rank[1] < rank[1]:
                # Bypass (Boyarski et al. 2015): as cheap and fewer conflicts, and the new path obeys this
                # node's constraints too, so this node takes it instead of branching.
                children = [(child_rank, constraints, child_paths)]
                break
            children.append((child_rank, constraints[:agent] + [mine] + constraints[agent + 1:], child_paths))
        for child in children:
            heapq.heappush(open_nodes, (child[0], next(tie), *child[1:]))
    # Best first: every node left costs at least the cheapest, and so does every plan below them.
    return None, min(open_nodes)[0][0] if open_nodes else rank[0]


def _rank(paths: list[tuple[int, ...]], goals: tuple[int, ...]) -> tuple[int, int]:
    """Which node conflict-based search expands first: the least sum of costs, then the fewest conflicts."""
    return sum(len(p) - 1 for p in paths), sum(1 for _ in conflicts(paths, goals))


def _cost(paths: list[tuple[int, ...]]) -> tuple[int, int]:
    return sum(len(p) - 1 for p in paths), max(len(p) - 1 for p in paths)


def _split(conflict: tuple) -> list[tuple[int, tuple]]:
    """The two ways out of a conflict: one agent or the other is forbidden its part in it."""
    if conflict[0] == "at":
        _, t, cell, i, j = conflict
        return [(i, ("at", t, cell)), (j, ("at", t, cell))]
    _, t, a, b, i, j = conflict
    return [(i, ("move", t, a, b)), (j, ("move", t, b, a))]


def prioritized(gridmap: GridMap, dists: list[list[float]], order: list[int],
                paths: list | None = None, deadline: float = _NEVER) -> tuple[list | None, int | None]:
    """Plan the agents in `order` one by one, each avoiding every agent that has a path by then (those of
    `paths` not in `order` keep theirs): (paths, None), or (None, the agent that found no path); OutOfTime
    once `deadline` (time.monotonic()) has passed."""
    paths = [None if i in order else path for i, path in enumerate(paths or [None] * gridmap.n_agents)]
    goals = gridmap.goals
    for agent in order:
        _check(deadline)
        others = [j for j, path in enumerate(paths) if path is not None]
        rules = Rules.avoiding([paths[j] for j in others], [goals[j] for j in others], goals[agent])
        paths[agent] = find_path(gridmap, gridmap.starts[agent], goals[agent], dists[agent], rules)
        if paths[agent] is None:
            return None, agent
    return paths, None


def improve(gridmap: GridMap, dists: list[list[float]], paths: list, rounds: int, rng: random.Random,
            progress: Callable[[int], None] | None = None, group: int = 8,
            deadline: float = _NEVER) -> tuple[list, int]:
    """Large neighbourhood search (MAPF-LNS, Li et al. 2021): each round takes a few agents drawn by `rng`,
    replans them in a random order around the others' paths, and keeps the result if the sum of costs does
    not grow. Conflicts are symmetric, so paths that avoid every kept path leave the plan conflict-free.
    (the improved paths, the rounds done: fewer than `rounds` where `deadline` came first)."""
    n = len(paths)
    for done in range(rounds):
        if progress and done % 10 == 0:
            progress(done)
        try:
            new, _ = prioritized(gridmap, dists, rng.sample(range(n), min(group, n)), paths, deadline)
        except OutOfTime:
            return paths, done
        if new is not None and _cost(new) <= _cost(paths):
            paths = new
    return paths, rounds


def priority_orders(gridmap: GridMap, dists: list[list[float]], rng: random.Random):
    """Priority orders to try, endlessly: farthest from its goal first; then, after an order fails, the same
    order with the agent that failed put first (unless tried before), else a shuffle drawn from `rng`.
    Agents that start at their goals always come first: they hold those cells from step 0.

    A generator that is sent the agent that failed in the order it last gave."""
    n = gridmap.n_agents
    parked = [i for i in range(n) if gridmap.starts[i] == gridmap.goals[i]]
    moving = sorted(set(range(n)) - set(parked), key=lambda i: (-dists[i][gridmap.starts[i]], i))
    tried = set()
    order = parked + moving
    while True:
        tried.add(tuple(order))
        failed = yield order
        nxt = parked + [failed] + [i for i in order if i != failed and i not in parked]
        while tuple(nxt) in tried and len(tried) < factorial(len(moving)):
            rng.shuffle(moving)
            nxt = parked + moving
        order = nxt


def plan(gridmap: GridMap, seed: int = 0, cbs_nodes: int = 1000, orders: int = 20, rounds: int = 300,
         progress: Callable[[str, int, int], None] | None = None, time_limit: float | None = None) -> Plan:
    """A collision-free plan: conflict-based search (optimal) within `cbs_nodes` search nodes; else prioritized
    planning over up to `orders` priority orders, improved by `rounds` rounds of `improve`. NoPlan if neither
    search finds one. Every random choice comes from `seed`.

    `time_limit` (seconds, wall clock) bounds the whole search: conflict-based search stops at half of it,
    prioritized planning raises OutOfTime at the end of it, and the rounds of improvement stop there, the
    plan kept as improved so far (the method says how many rounds were done); a search that ends before half
    the limit is the one made without a limit.

    `progress(phase, done, total)` is called as the search goes: "cbs" nodes, priority "orders", "rounds"."""
    started = time.monotonic()
    deadline = _NEVER if time_limit is None else started + time_limit
    dists = [distances_to(gridmap, goal) for goal in gridmap.goals]
    bound = sum(int(dist[start]) for dist, start in zip(dists, gridmap.starts))
    if cbs_nodes:
        paths, searched = conflict_based_search(gridmap, dists, cbs_nodes, _phase(progress, "cbs", cbs_nodes),
                                                (started + deadline) / 2)
        bound = max(bound, searched)
        if paths is not None:
            return _with_actions(gridmap, paths, "conflict-based search", bound)
    rng = random.Random(seed)
    chooser = priority_orders(gridmap, dists, rng)
    order = next(chooser)
    for k in range(1, orders + 1):
        if progress:
            progress("orders", k - 1, orders)
        try:
            paths, failed = prioritized(gridmap, dists, order, deadline=deadline)
        except OutOfTime:
            raise OutOfTime(f"no plan found for {gridmap.name} within the time limit of {time_limit:g} s "
                            f"(prioritized planning was at priority order {k} of {orders})") from None
        if paths is not None:
            paths, done = improve(gridmap, dists, paths, rounds, rng, _phase(progress, "rounds", rounds),
                                  deadline=deadline)
            lns = f"{rounds} rounds of LNS" if done == rounds else (
                f"{done} of {rounds} rounds of LNS (stopped at the time limit of {time_limit:g} s)")
            return _with_actions(gridmap, paths, f"prioritized planning (priority order {k} of {orders} tried), "
                                                 f"then {lns}", bound)
        order = chooser.send(failed)
    raise NoPlan(f"no plan found for {gridmap.name}: conflict-based search ran out of its {cbs_nodes} nodes and "
                 f"prioritized planning failed with {orders} priority orders; the instance may have no plan at all")


def _phase(progress: Callable[[str, int, int], None] | None, phase: str, total: int):
    return (lambda done: progress(phase, done, total)) if progress else None


def _with_actions(gridmap: GridMap, paths: list[tuple[int, ...]], method: str, lower_bound: int) -> Plan:
    """The plan with the action of every step: the one that moves there, or for a wait the first that bumps."""
    nbr = gridmap.neighbours
    actions = tuple(tuple(nbr[a].index(b) for a, b in zip(path, path[1:])) for path in paths)
    return Plan(tuple(paths), actions, method, lower_bound)


# --- the check against the world --------------------------------------------------------------------------


def _at(path: tuple[int, ...], t: int) -> int:
    return path[min(t, len(path) - 1)]


def validate(gridmap: GridMap, the_plan: Plan) -> list[int]:
    """Replay the plan's actions through `GridWorld.step_joint`; return the arrival step of every agent as the
    world counts them. PlanError if a step has a collision, the world puts an agent elsewhere than the plan
    says, an agent runs out of actions before its goal, or some agent is not at its goal at the end."""
    world = GridWorld(gridmap)
    world.reset_joint()
    for t in range(max((len(a) for a in the_plan.actions), default=0)):
        joint = []
        for i, acts in enumerate(the_plan.actions):
            if world.done[i]:
                joint.append(None)
            elif t < len(acts):
                joint.append(acts[t])
            else:
                raise PlanError(f"agv{i + 1} has no action for step {t + 1} but is not at its goal")
        world.step_joint(joint)
        if world.last_collisions:
            raise PlanError(f"step {t + 1}: {world.last_collisions} collision(s) in the world")
        for i, path in enumerate(the_plan.paths):
            if world.cells[i] != _at(path, t + 1):
                raise PlanError(f"step {t + 1}: the world put agv{i + 1} in cell {world.cells[i]}, "
                                f"the plan in {_at(path, t + 1)}")
    missing = [f"agv{i + 1}" for i, step in enumerate(world.arrival) if step is None]
    if missing:
        raise PlanError(f"{', '.join(missing)} not at the goal when the plan ends")
    return list(world.arrival)

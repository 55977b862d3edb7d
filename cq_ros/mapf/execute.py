"""The planner's plan carried out in the delayed world by a fixed rule, not a learner: the yardstick under
the learners' own delays.

The rule is the action dependency graph (ADG) of Hönig et al., "Persistent and robust execution of MAPF
schedules in warehouses" (RA-L 2019): an AGV moves into its next planned cell only once every AGV that the
plan sends through that cell before it has left it. The plan's clock is dropped and only the order of
visits at each cell is kept, so a delayed AGV holds up just the AGVs the plan sends after it through its
cells, and those only there. An AGV's route is its plan path without the plan's waits; the visits of one
cell are ordered by the step the plan enters them; each visit waits on the one before it (two AGVs sharing
a goal may both stay in it, as the world allows, so their arrivals there do not wait on each other).

Waiting within the world's rules. The world has no wait action: an AGV stays only by bumping into a blocked
direction of its cell (reward_wall), or when delayed. A cell with a blocked direction is a *wait cell*, and
about half the aisle cells of a warehouse are not. So an AGV in a wait cell, or at its start, moves on only
when every cell of its route up to and including the next wait cell (or its goal) is released; until then
it waits there by bumping. Between wait cells it moves every step and never has to stop: those cells are
released, and every AGV the plan sends through them later waits for it to leave. A delay there is
involuntary and the ADG keeps the others behind it. Where an AGV must stay in a cell without a wall, it
sends no action (the world keeps it, as it keeps any AGV whose action did not come, and it pays
reward_step), counted as `held`: at its start, when that has no wall and its first stretch is not yet
released (it is not dispatched yet), and after a stall (below).

When no move can fail (slip 0 and start_hold 0), the plan's own clock keeps every order (the world carries
the plan out: `cq_ros.mapf.planner.validate`), so the AGVs follow the plan step by step and send nothing: with no
delays an execution is exactly the plan. As soon as a move can fail, following an AGV into the cell it
leaves in the same step would collide whenever that move fails, so the ADG is used.

Messages: one per cross-agent dependency, sent by the earlier AGV when it leaves the shared cell, to the
AGV the plan sends in next; the later AGV moves on when it holds the messages of its stretch. Over ROS that
would be a std_msgs/UInt32MultiArray (cell, visit) on the later AGV's own topic, reliable, so none is lost:
with the plan shared in advance, nothing else needs to travel (an AGV's own progress is its own).

Stalls: waiting for a whole stretch can make AGVs wait on each other in a cycle (each needs a cell of its
stretch that the next must leave first; on warehouse_32 a loop of AGVs round a two-lane cross-aisle does).
When AGVs wait on each other in a cycle (each for a cell that the next must leave first), none of them will
move again by itself, whatever the others do: then, among the AGVs waiting on such a cycle, the one whose
next move comes first in the plan and whose next cell alone is released sets out (the bare ADG) and holds
where its next cell is not yet released; that is counted in `stalls`. The bare ADG has a cycle only where the plan
moves AGVs round a loop of cells all in one step (which the world allows and no move that can fail survives); an
execution that meets one stops, recorded as `stuck`, with the AGVs not home counted, rather than wait for ever.
`stall_risk` finds the cycles of stretches in a plan before any execution; where it finds none, no execution stalls.

Every random choice is the world's (`GridWorld`, seeded with `cq_ros.engine.world_seed(seed, run)`), so
execution `run` meets exactly the delays a learner's run `run` meets.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from statistics import fmean

from ..engine import world_seed
from ..gridmap import GridMap
from .planner import Plan
from ..settings import Settings
from ..world import GridWorld


@dataclass(frozen=True)
class Dependencies:
    """The ADG of a plan, per AGV and per index of its route (its cells without the plan's waits).

    `after[i][k]` is the visit (agent, route index) that must have left the cell before AGV i enters
    `routes[i][k]`, or None; `entered[i][k]` the step the plan enters it; `stretch_end[i][k]` the route index
    at which AGV i can next stop, after k: the next wait cell or its goal."""

    routes: tuple[tuple[int, ...], ...]
    entered: tuple[tuple[int, ...], ...]
    after: tuple[tuple[tuple[int, int] | None, ...], ...]
    stretch_end: tuple[tuple[int, ...], ...]
    can_wait: tuple[bool, ...]


def dependencies(gridmap: GridMap, the_plan: Plan, stop_anywhere: bool = False) -> Dependencies:
    """The plan's ADG; with `stop_anywhere` every stretch is one cell long (see `execute`)."""
    can_wait = tuple(any(there == cell for there in nbr) for cell, nbr in enumerate(gridmap.neighbours))
    routes, entered, visits = [], [], []  # visits: (step the plan enters the cell, agent, route index)
    for i, path in enumerate(the_plan.paths):
        steps = [t for t in range(len(path)) if t == 0 or path[t] != path[t - 1]]
        routes.append(tuple(path[t] for t in steps))
        entered.append(tuple(steps))
        visits += [(t, i, k) for k, t in enumerate(steps)]
    goals = gridmap.goals
    last_visit: dict[int, tuple[int, int]] = {}  # cell -> the visit that the next one there waits on
    after = [[None] * len(route) for route in routes]
    for _, i, k in sorted(visits):
        cell = routes[i][k]
        before = last_visit.get(cell)
        if before is not None and _arrives(routes, goals, (i, k)) and _arrives(routes, goals, before):
            # Two AGVs sharing a goal both stay in it, as the world allows: the second arrival waits on what
            # the first waited on, and whoever shares it next waits on the same.
            after[i][k] = after[before[0]][before[1]]
        else:
            after[i][k] = before
            last_visit[cell] = (i, k)
    stretch_end = []
    for route in routes:
        ends, nxt = [0] * len(route), len(route) - 1
        for k in range(len(route) - 1, -1, -1):
            ends[k] = nxt
            if can_wait[route[k]] or stop_anywhere:
                nxt = k
        stretch_end.append(tuple(ends))
    return Dependencies(tuple(routes), tuple(entered), tuple(tuple(a) for a in after), tuple(stretch_end),
                        can_wait)


def stall_risk(deps: Dependencies) -> list[int]:
    """The AGVs whose stretches (from a wait cell or the start to the next wait cell or the goal) wait on
    each other in a cycle; none: no execution of the plan can stall, whatever the delays.

    Why: an AGV that sets out on a stretch moves until its end (its cells are released and stay so), so when
    no AGV is under way, one whose next stretch waits only on stretches before it in an order without cycles
    finds them all done, and sets out."""
    starts = []  # per AGV, the route indices its stretches start from
    for ends in deps.stretch_end:
        ks, k = [], 0
        while k < len(ends) - 1:
            ks.append(k)
            k = ends[k]
        starts.append(ks)
    stretch_of = {}  # (agent, route index entered) -> (agent, the index its stretch starts from)
    for i, ks in enumerate(starts):
        for k in ks:
            for m in range(k + 1, deps.stretch_end[i][k] + 1):
                stretch_of[(i, m)] = (i, k)
    waits_on = {(i, k): set() for i, ks in enumerate(starts) for k in ks}
    for i, ks in enumerate(starts):
        for before, k in zip(ks, ks[1:]):
            waits_on[(i, k)].add((i, before))
        for k in ks:
            for m in range(k + 1, deps.stretch_end[i][k] + 1):
                dep = deps.after[i][m]
                if dep is not None and dep[0] != i:
                    # met when that AGV enters its next cell, on the stretch that holds that move; a visit
                    # that never leaves (none in a plan the world carries out) holds the stretch for ever
                    waits_on[(i, k)].add(stretch_of.get((dep[0], dep[1] + 1), (i, k)))
    return sorted({i for i, _ in _waiting_in_cycles(waits_on)})


def _arrives(routes, goals, visit: tuple[int, int]) -> bool:
    i, k = visit
    return k == len(routes[i]) - 1 and routes[i][k] == goals[i]


@dataclass(frozen=True)
class Execution:
    """One execution of a plan in the world: each AGV's cell at every step (`paths`, as `Plan.paths`, up to
    its arrival or the end), the step each arrived (None: not home), and what it took."""

    paths: tuple[tuple[int, ...], ...]
    arrivals: tuple[int | None, ...]
    collisions: int  # colliding pairs, summed over steps
    waits: int  # wall bumps spent waiting
    held: int  # steps an AGV stayed in a cell without a wall, sending no action
    delays: int  # moves the world's delays failed
    messages: int  # dependency messages sent
    stalls: int  # steps AGVs waited on each other in a cycle, so one set out under the bare ADG
    stuck: bool  # no AGV could move any more, even under the bare ADG (see the module's docstring)
    truncated: bool  # the step cap came first

    @property
    def home(self) -> bool:
        return all(a is not None for a in self.arrivals)

    @property
    def makespan(self) -> int | None:
        return max(self.arrivals) if self.home else None

    @property
    def sum_of_costs(self) -> int | None:
        return sum(self.arrivals) if self.home else None


def moves_can_fail(settings: Settings) -> bool:
    return settings.slip > 0 or settings.start_hold > 0


def execute(the_plan: Plan, gridmap: GridMap, settings: Settings, seed: int, run: int,
            stop_anywhere: bool = False) -> Execution:
    """Execution `run` of `the_plan` in the world of `settings`, drawing run `run`'s delays of `seed`.

    `stop_anywhere` measures what the world's lack of a wait action costs: an AGV sets out as soon as its
    next cell is released and, where it must wait in a cell without a wall, sends no action (`held`), a
    stay the learners do not have."""
    world = GridWorld(gridmap, settings, seed=world_seed(seed, run))
    world.reset_joint()
    deps = dependencies(gridmap, the_plan, stop_anywhere)
    if moves_can_fail(settings):
        choose = _AdgRule(gridmap, deps)
    else:
        choose = _Clock(the_plan)
    paths = [[cell] for cell in world.cells]
    collisions = waits = delays = 0
    stuck = False
    held = 0
    while not world.over:
        joint, moving = choose(world)
        if not moving:
            stuck = True
            break
        held += sum(a is None and not done for a, done in zip(joint, world.done))
        world.step_joint(joint)
        collisions += world.last_collisions
        waits += world.last_bumps
        delays += world.last_delays
        choose.moved(world)
        for i, path in enumerate(paths):
            if world.arrival[i] is None or len(path) <= world.arrival[i]:
                path.append(world.cells[i])
    return Execution(tuple(map(tuple, paths)), tuple(world.arrival), collisions, waits, held, delays,
                     choose.messages, choose.stalls, stuck, world.truncated)


class _Clock:
    """Every AGV takes the plan's action of the step: right when no move can fail."""

    def __init__(self, the_plan: Plan):
        self.actions = the_plan.actions
        self.messages = self.stalls = 0

    def __call__(self, world: GridWorld) -> tuple[list[int | None], bool]:
        """The joint action, and whether anyone moves (always, by the plan's clock)."""
        return [None if world.done[i] else acts[world.t] for i, acts in enumerate(self.actions)], True

    def moved(self, world: GridWorld) -> None:
        pass


class _AdgRule:
    """The ADG with whole stretches between wait cells (the module's docstring): the action of every AGV."""

    def __init__(self, gridmap: GridMap, deps: Dependencies):
        self.nbr = gridmap.neighbours
        self.deps = deps
        self.at = [0] * gridmap.n_agents  # each AGV's index on its route
        self.messages = self.stalls = 0
        # how many AGVs wait on each visit's leaving: the messages its AGV sends then
        self.waiting_on = [[0] * len(route) for route in deps.routes]
        for j, waits in enumerate(deps.after):
            for dep in waits:
                if dep is not None and dep[0] != j:
                    self.waiting_on[dep[0]][dep[1]] += 1

    def released(self, i: int, k: int) -> bool:
        dep = self.deps.after[i][k]
        return dep is None or self.at[dep[0]] > dep[1]

    def __call__(self, world: GridWorld) -> tuple[list[int | None], bool]:
        """The joint action (None: held in a cell without a wall), and whether any AGV moves."""
        deps, at, nbr = self.deps, self.at, self.nbr
        joint: list[int | None] = [None] * len(at)
        moving = False
        waits_on: dict[int, set[int]] = {}  # AGV that waits -> the AGVs whose leaving it waits for
        for i, k in enumerate(at):
            if world.done[i]:
                continue
            cell = deps.routes[i][k]
            # under way: its cells were released when it set out, unless it set out to break a stall
            ahead = deps.stretch_end[i][k] if k == 0 or deps.can_wait[cell] else k + 1
            blocking = {deps.after[i][m][0] for m in range(k + 1, ahead + 1) if not self.released(i, m)}
            if not blocking:
                joint[i] = self.move(i)
                moving = True
                continue
            waits_on[i] = blocking
            if deps.can_wait[cell]:
                joint[i] = next(a for a, there in enumerate(nbr[cell]) if there == cell)  # a bump: the wait
        stalled = _waiting_in_cycles(waits_on)
        ready = [(deps.entered[i][at[i] + 1], i) for i in stalled if self.released(i, at[i] + 1)]
        if ready:
            self.stalls += 1
            first = min(ready)[1]
            joint[first] = self.move(first)
            moving = True
        return joint, moving

    def move(self, i: int) -> int:
        k = self.at[i]
        return self.nbr[self.deps.routes[i][k]].index(self.deps.routes[i][k + 1])

    def moved(self, world: GridWorld) -> None:
        deps, at = self.deps, self.at
        for i, k in enumerate(at):
            route = deps.routes[i]
            if k + 1 < len(route) and world.cells[i] == route[k + 1]:
                at[i] = k + 1
                self.messages += self.waiting_on[i][k]
            elif world.cells[i] != route[k]:
                raise AssertionError(f"agv{i + 1} left its route at step {world.t} (an executor bug)")



def _waiting_in_cycles(waits_on: dict) -> set:
    """Those of `waits_on` (what waits -> what it waits on) that wait, directly or not, on a cycle of waits:
    none of them will move by itself (each needs all it waits on to move first)."""
    stalled = set(waits_on)
    while True:
        free = {i for i in stalled if not waits_on[i] & stalled}
        if not free:
            return stalled
        stalled -= free


def execute_many(the_plan: Plan, gridmap: GridMap, settings: Settings, seed: int, runs: int,
                 progress: Callable[[int], None] | None = None, stop_anywhere: bool = False) -> list[Execution]:
    """Executions 0..runs-1 (execution r draws the delays a learner's run r draws)."""
    out = []
    for run in range(runs):
        if progress:
            progress(run)
        out.append(execute(the_plan, gridmap, settings, seed, run, stop_anywhere))
    return out


FIGURES = ("collisions", "makespan", "sum_of_costs", "waits", "held", "stalls", "delays", "messages")


@dataclass(frozen=True)
class Spread:
    mean: float
    low: float
    high: float


def spread(executions: Sequence[Execution]) -> dict[str, Spread | None]:
    """Mean and range of every figure over the executions (makespan and sum of costs over those that
    brought every AGV home; None where there is none)."""
    out = {}
    for name in FIGURES:
        values = [getattr(e, name) for e in executions if getattr(e, name) is not None]
        out[name] = Spread(fmean(values), min(values), max(values)) if values else None
    return out

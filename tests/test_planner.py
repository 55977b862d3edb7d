"""Tests of cq_ros.mapf.planner: instances solved by hand (inline maps), optimality against a brute-force search of
the world's joint states, the validator's verdicts, every shipped map, and `cq-ros plan`."""

import heapq
import itertools
import random

import pytest

from cq_ros.cli.main import main
from cq_ros.cli.plan import PlanProgress
from cq_ros.gridmap import available_maps, load_map, parse_map
from cq_ros.mapf.planner import (
    NoPlan, Plan, PlanError, conflict_based_search, distances_to, improve, plan, prioritized, validate,
)
from cq_ros.mapgen.warehouse import warehouse_map
from cq_ros.world import N_ACTIONS, GridWorld

PRIORITIZED = {"cbs_nodes": 0}  # plan() options that skip conflict-based search
BOTH = pytest.mark.parametrize("options", [{}, PRIORITIZED], ids=["cbs", "prioritized"])

# A corridor (0,0)-(0,1)-(0,2) with a dead-end cell (1,1) below its middle.
CORRIDOR_WITH_SIDE_CELL = """\
agent 1: start 0,0  goal 0,2
agent 2: start 1,1  goal 0,0
+-+-+-+
|. . .|
+-+ +-+
 #|.|#
+ +-+ +
"""

# A corridor of five cells with a passing bay (1,2) below its middle; the agents swap ends.
BAY = """\
agent 1: start 0,0  goal 0,4
agent 2: start 0,4  goal 0,0
+-+-+-+-+-+
|. . . . .|
+-+-+ +-+-+
 # #|.|# #
+ + +-+ + +
"""

# A loop (0,3) (0,4) (1,4) (1,3) with a tail (1,2)-(1,1) off (1,3).
LOOP_WITH_TAIL = """\
agent 1: start 1,4  goal 1,2
agent 2: start 1,2  goal 0,3
+ + + +-+-+
 # # #|. .|
+ +-+-+ + +
 #|. . . .|
+ +-+-+-+-+
"""

# A 3x3 room without its top-right cell; the middle cell (1,1) has no wall at all.
OPEN_MIDDLE = """\
agent 1: start 0,0  goal 1,0
agent 2: start 2,0  goal 2,2
agent 3: start 1,1  goal 2,1
+-+-+-+
|. .|#
+ + +-+
|. . .|
+ + + +
|. . .|
+-+-+-+
"""


def solved(gridmap, **options):
    """A plan that the world carries out, with the world's arrival steps equal to the plan's."""
    result = plan(gridmap, **options)
    assert validate(gridmap, result) == list(result.arrivals)
    return result


@BOTH
def test_an_agent_waits_in_the_corridor_by_bumping_into_a_wall(options):
    # Agent 2 cannot enter the corridor at step 1 (agent 1 passes), nor later go west while agent 1 comes
    # east (a swap), so the only least-cost plan has agent 2 bump once in its side cell: 2 + 3 steps.
    m = parse_map(CORRIDOR_WITH_SIDE_CELL)
    result = solved(m, **options)
    assert result.arrivals == (2, 3) and result.makespan == 3 and result.sum_of_costs == 5
    side = m.index(1, 1)
    assert result.paths[1][:2] == (side, side)
    assert m.neighbours[side][result.actions[1][0]] == side  # the wait is a bump


def test_an_agent_in_a_cell_without_walls_cannot_wait_so_it_steps_out_and_back():
    # Agent 2's only way is (2,0)-(2,1)-(2,2) ((1,0) is agent 1's goal from step 1), so agent 3 may not sit on
    # its goal (2,1) before agent 2 has crossed it at step 1. Arriving at step 2 would need agent 3 in (1,1)
    # at step 1, the only neighbour of (2,1) it can be in, and (1,1) has no wall to bump into: it steps out
    # and back and arrives at 3. Sum of costs 1 + 2 + 3 = 6, where a free wait would give 5.
    m = parse_map(OPEN_MIDDLE)
    result = solved(m)
    assert result.arrivals == (1, 2, 3)
    middle = m.index(1, 1)
    assert result.paths[2][0] == result.paths[2][2] == middle != result.paths[2][1]
    assert least_sum_of_costs(m) == 6


def test_a_swap_through_a_passing_bay():
    # Agent 2 reaches the bay at step 3 at the earliest (via (0,2) at step 2), so agent 1 may take (0,2) at
    # step 3 at the earliest: it bumps once at (0,1) and arrives at 5; agent 2 leaves the bay behind it and
    # arrives at 6. The mirror plan costs the same; 11 is the least (each agent alone: 4).
    m = parse_map(BAY)
    result = solved(m)
    assert result.optimal and result.sum_of_costs == 11 and result.makespan == 6
    assert sorted(result.arrivals) == [5, 6]
    bay = m.index(1, 2)
    assert sum(bay in path for path in result.paths) == 1


def test_prioritized_planning_alone_cannot_swap_through_a_bay():
    # Whichever agent goes first walks straight through; the other has no way round it. This is why plan()
    # tries conflict-based search first.
    with pytest.raises(NoPlan, match="prioritized planning failed with 3 priority orders"):
        plan(parse_map(BAY), cbs_nodes=0, orders=3)


@BOTH
def test_a_shared_goal_at_the_end_of_a_tunnel(options):
    # tunnel_to_goal: both agents need 10 steps alone, and every 10-step path is at the tunnel mouth (2,4) at
    # step 6, so one agent bumps once (at (1,4) or (3,4), both against the edge) and follows the other in:
    # 10 + 11 = 21, makespan 11. They may end in one cell because it is the goal of both.
    m = load_map("tunnel_to_goal")
    result = solved(m, **options)
    assert sorted(result.arrivals) == [10, 11] and result.sum_of_costs == 21
    assert result.paths[0][-1] == result.paths[1][-1] == m.index(2, 0)


def test_a_failed_priority_order_is_followed_by_one_that_works():
    # Farthest first (a tie, so by number) puts agent 1 first: it parks on (1,2) at step 2 and walls agent 2
    # into the dead end (1,1). With agent 2 first, agent 1 bumps once at (1,4) and follows it: 3 + 2 steps.
    m = parse_map(LOOP_WITH_TAIL)
    dists = [distances_to(m, goal) for goal in m.goals]
    assert prioritized(m, dists, [0, 1]) == (None, 1)
    result = solved(m, cbs_nodes=0)
    assert "priority order 2 of" in result.method
    assert result.arrivals == (3, 2)


def test_the_validator_rejects_a_plan_with_a_collision():
    m = parse_map(CORRIDOR_WITH_SIDE_CELL)
    a, b, c, side = m.index(0, 0), m.index(0, 1), m.index(0, 2), m.index(1, 1)
    east, north, west = 1, 0, 3
    clash = Plan(paths=((a, b, c), (side, b, a)), actions=((east, east), (north, west)), method="", lower_bound=0)
    with pytest.raises(PlanError, match="step 1: 1 collision"):
        validate(m, clash)


def test_the_validator_rejects_a_plan_that_stops_short_or_that_the_world_does_not_follow():
    m = parse_map(CORRIDOR_WITH_SIDE_CELL)
    a, b, c, side = m.index(0, 0), m.index(0, 1), m.index(0, 2), m.index(1, 1)
    east, north, south, west = 1, 0, 2, 3
    short = Plan(paths=((a, b, c), (side, side)), actions=((east, east), (south,)), method="", lower_bound=0)
    with pytest.raises(PlanError, match="agv2 has no action for step 2"):
        validate(m, short)
    # The paths claim agent 2 waits in (0,1) at step 2 though the action moves it on: the world disagrees.
    wrong = Plan(paths=((a, b, c), (side, side, b, b)), actions=((east, east), (south, north, west)),
                 method="", lower_bound=0)
    with pytest.raises(PlanError, match="step 3: the world put agv2"):
        validate(m, wrong)


@pytest.mark.parametrize("name", available_maps())
def test_every_shipped_map_gets_a_plan_the_world_carries_out(name):
    m = load_map(name)
    result = solved(m, cbs_nodes=300, rounds=10)  # small budgets: validity is the point here, not the figures
    alone = [distances_to(m, goal)[start] for start, goal in zip(m.starts, m.goals)]
    assert all(arrival >= lone for arrival, lone in zip(result.arrivals, alone))


# --- optimality, against a search of the world's own joint states -----------------------------------------


def least_sum_of_costs(gridmap) -> int | None:
    """Dijkstra over joint positions with `GridWorld.step_joint` as the only model: a step costs one per
    agent not yet at its goal, and joint actions with a collision are not taken. None: no plan exists."""
    world = GridWorld(gridmap)
    goals = gridmap.goals
    start = tuple(gridmap.starts)
    best = {start: 0}
    frontier = [(0, start)]
    while frontier:
        cost, cells = heapq.heappop(frontier)
        if cells == goals:
            return cost
        if cost > best[cells]:
            continue
        acting = [i for i, (c, g) in enumerate(zip(cells, goals)) if c != g]
        for choice in itertools.product(range(N_ACTIONS), repeat=len(acting)):
            joint = [None] * len(cells)
            for i, a in zip(acting, choice):
                joint[i] = a
            world.cells, world.done = list(cells), [c == g for c, g in zip(cells, goals)]
            world.step_joint(joint)
            nxt = tuple(world.cells)
            if not world.last_collisions and cost + len(acting) < best.get(nxt, float("inf")):
                best[nxt] = cost + len(acting)
                heapq.heappush(frontier, (best[nxt], nxt))
    return None


def random_instance(rng: random.Random, height: int, width: int, agents: int):
    """A small map with a few '#' cells and agents at random starts and goals (a goal may be shared), or None
    if some goal cannot be reached."""
    world = {(r, c) for r in range(height) for c in range(width) if rng.random() > 0.2}
    cells = sorted(world)
    if len(cells) < agents + 1:
        return None
    starts = rng.sample(cells, agents)
    goals = [rng.choice(cells) for _ in range(agents)]
    lines = [f"agent {k}: start {s[0]},{s[1]}  goal {g[0]},{g[1]}" for k, (s, g) in enumerate(zip(starts, goals), 1)]
    # No wall drawn anywhere: a move into a '#' cell or off the grid is a bump all the same.
    for row in range(height):
        lines += ["+" + " +" * width, " " + " ".join("." if (row, col) in world else "#" for col in range(width))]
    try:
        return parse_map("\n".join(lines + ["+" + " +" * width]) + "\n")
    except ValueError:
        return None


@pytest.mark.parametrize("seed", range(20))
def test_conflict_based_search_finds_the_least_sum_of_costs_the_world_allows(seed):
    # 3x3 maps have a middle cell without walls, where an agent cannot wait: the no-wait rule is in play.
    rng = random.Random(seed)
    m = None
    while m is None:
        m = random_instance(rng, 3, 3, rng.choice((2, 3)))
    optimum = least_sum_of_costs(m)
    if optimum is None:
        with pytest.raises(NoPlan):
            plan(m, cbs_nodes=300, orders=3)
    else:
        result = solved(m, cbs_nodes=20_000)
        assert result.optimal and result.sum_of_costs == optimum
        # cut short, the search's frontier still bounds the optimum from below ...
        dists = [distances_to(m, goal) for goal in m.goals]
        assert conflict_based_search(m, dists, 1, None)[1] <= optimum
        # ... and so does the plan that prioritized planning then finds, where it finds one (it cannot solve
        # every instance CBS can, e.g. a swap that needs one agent to step aside first)
        try:
            cut_short = plan(m, cbs_nodes=1, orders=5, rounds=5)
        except NoPlan:
            return
        assert cut_short.lower_bound <= optimum <= cut_short.sum_of_costs


@pytest.mark.parametrize("seed", range(20))
def test_prioritized_plans_with_neighbourhood_search_are_carried_out_by_the_world(seed):
    # Denser instances than above (18 of these 20 get a plan), for the planner the larger maps rely on;
    # `solved` replays the plan through the world.
    rng = random.Random(seed)
    m = None
    while m is None:
        m = random_instance(rng, 4, 4, 5)
    try:
        result = solved(m, cbs_nodes=0, orders=5, rounds=20, seed=seed)
    except NoPlan:
        return
    alone = sum(distances_to(m, goal)[start] for start, goal in zip(m.starts, m.goals))
    assert result.sum_of_costs >= result.lower_bound == alone


def test_the_same_seed_gives_the_same_plan():
    m = load_map("warehouse_8")
    plans = [plan(m, seed=seed, cbs_nodes=0, rounds=30) for seed in (1, 1, 2)]
    assert plans[0] == plans[1]
    assert all(validate(m, p) == list(p.arrivals) for p in plans)


# --- the command ------------------------------------------------------------------------------------------


def test_plan_command_prints_the_figures(tmp_path, capsys):
    path = tmp_path / "corridor.txt"
    path.write_text(CORRIDOR_WITH_SIDE_CELL)
    assert main(["plan", "--map", str(path), "--show"]) == 0
    out = capsys.readouterr().out
    assert "makespan 3, sum of costs 5 (the least possible; each agent alone: 4)" in out
    assert "arrival steps: agv1 2, agv2 3" in out
    assert "planning time" in out
    assert "agv2 (1, 1) -> (0, 0): eNW" in out  # lower case: the bump that is a wait


def test_plan_command_without_a_plan_exits_1_and_with_bad_arguments_2(tmp_path, capsys):
    path = tmp_path / "bay.txt"
    path.write_text(BAY)
    assert main(["plan", "--map", str(path), "--cbs-nodes", "0", "--orders", "2"]) == 1
    assert "no plan found for bay" in capsys.readouterr().err
    for args, phrase in ((["--map", "nowhere"], "no such map"), (["--map", "isr", "--orders", "0"], "at least 1")):
        with pytest.raises(SystemExit) as exit_:
            main(["plan", *args])
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and phrase in err
        assert len(err.strip().splitlines()) == 1


def test_plan_progress_off_a_terminal_is_a_plain_line_at_most_every_30_s(capsys):
    progress = PlanProgress()
    progress("cbs", 100, 2000)
    assert capsys.readouterr().err == ""  # not yet 30 s
    progress.last_line -= 30
    progress("rounds", 10, 300)
    assert capsys.readouterr().err == "cq-ros plan: rounds 10/300\n"


def test_the_time_limit_ends_the_search_with_one_line(tmp_path, capsys):
    path = tmp_path / "bay.txt"
    path.write_text(BAY)
    assert main(["plan", "--map", str(path), "--time-limit", "1e-9"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["cq-ros plan: no plan found for bay within the time limit of 1e-09 s (prioritized planning was "
                   "at priority order 1 of 20) (--time-limit gives it longer)"]


def test_improvement_past_its_deadline_keeps_the_plan_it_has():
    m = warehouse_map(6, seed=2)
    dists = [distances_to(m, goal) for goal in m.goals]
    paths, _ = prioritized(m, dists, list(range(m.n_agents)))
    assert improve(m, dists, paths, 50, random.Random(0), deadline=0.0) == (paths, 0)
    assert improve(m, dists, paths, 5, random.Random(0))[1] == 5

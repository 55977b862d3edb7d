"""Tests of cq_ros.mapf.execute: the planner's plan carried out under delays by its action dependency graph, on
hand-made maps (a corridor, an entrance, an open aisle), on warehouse_8, and through `cq-ros plan`."""

import pytest

from cq_ros.cli.main import main
from cq_ros.mapf.execute import dependencies, execute, execute_many, spread, stall_risk
from cq_ros.gridmap import load_map, parse_map
from cq_ros.mapf.planner import Plan, plan, validate
from cq_ros.settings import Settings

# AGV 2 follows AGV 1 east through a one-lane corridor (every cell walled north and south).
CORRIDOR = """\
agent 1: start 0,1  goal 0,5
agent 2: start 0,0  goal 0,4
+-+-+-+-+-+-+
|. . . . . .|
+-+-+-+-+-+-+
"""

# AGV 2 comes up a one-lane corridor into a lane that AGV 1 crosses: they share the entrance (0,2) and (0,3).
ENTRANCE = """\
agent 1: start 0,0  goal 0,4
agent 2: start 2,2  goal 0,3
+-+-+-+-+-+
|. . . . .|
+-+-+ +-+-+
 # #|.|# #
+ + + + + +
 # #|.|# #
+ + +-+ + +
"""

# A two-lane aisle between walled edges: rows 1 and 2 have no wall at all in columns 1-4, so an AGV there
# cannot wait; four AGVs pass each other through it.
OPEN_AISLE = """\
agent 1: start 0,0  goal 3,5
agent 2: start 3,0  goal 0,5
agent 3: start 0,5  goal 3,0
agent 4: start 3,5  goal 0,0
+-+-+-+-+-+-+
|. . . . . .|
+ + + + + + +
|. . . . . .|
+ + + + + + +
|. . . . . .|
+ + + + + + +
|. . . . . .|
+-+-+-+-+-+-+
"""

MAPS = {"corridor": CORRIDOR, "entrance": ENTRANCE, "open aisle": OPEN_AISLE}
DELAYS = [{"slip": 0.1}, {"slip": 0.3}, {"start_hold": 3}, {"slip": 0.2, "start_hold": 2}]


def visit_order(paths):
    """Cell -> the AGVs in the order they enter it (a start counts as entering at step 0)."""
    entries = []
    for i, path in enumerate(paths):
        entries += [(t, i, cell) for t, cell in enumerate(path) if t == 0 or path[t - 1] != cell]
    order = {}
    for _, i, cell in sorted(entries):
        order.setdefault(cell, []).append(i)
    return order


def cross_agent_dependencies(paths):
    """What each execution sends: one message per pair of consecutive visits of a cell by different AGVs."""
    return sum(sum(a != b for a, b in zip(agents, agents[1:])) for agents in visit_order(paths).values())


@pytest.mark.parametrize("delays", DELAYS, ids=lambda d: ",".join(f"{k}={v}" for k, v in d.items()))
@pytest.mark.parametrize("name", MAPS)
def test_under_delays_no_collision_every_agv_home_and_the_plan_order_kept_at_every_cell(name, delays):
    m = parse_map(MAPS[name])
    the_plan = plan(m)
    settings = Settings(**delays)
    shared = [cell for cell, agents in visit_order(the_plan.paths).items() if len(set(agents)) > 1]
    assert shared  # the plan sends several AGVs through some cell: there is an order to keep
    executions = execute_many(the_plan, m, settings, seed=7, runs=10)
    for e in executions:
        assert e.collisions == e.stalls == 0 and e.home and not e.stuck and not e.truncated
        assert visit_order(e.paths) == visit_order(the_plan.paths)
        assert e.messages == cross_agent_dependencies(the_plan.paths) > 0
        assert [path[-1] for path in e.paths] == list(m.goals)
        assert all(e.arrivals[i] == len(path) - 1 for i, path in enumerate(e.paths))
    assert sum(e.delays for e in executions) > 0  # the delays did happen
    # the delays cost time: never less than the plan, sometimes more
    assert min(e.sum_of_costs for e in executions) >= the_plan.sum_of_costs
    assert max(e.sum_of_costs for e in executions) > the_plan.sum_of_costs


def test_an_agv_stops_only_in_a_cell_where_it_can_wait():
    # With start holds alone, no move fails once an AGV has left its start: from then on it stays only by
    # bumping into a wall, so never in a cell without one (rows 1 and 2 of the open aisle, columns 1-4).
    m = parse_map(OPEN_AISLE)
    the_plan = plan(m)
    no_wait = {c for c, nbr in enumerate(m.neighbours) if all(there != c for there in nbr)}
    assert len(no_wait) == 8 and any(no_wait & set(path) for path in the_plan.paths)
    for e in execute_many(the_plan, m, Settings(start_hold=4), seed=3, runs=20):
        for i, path in enumerate(e.paths):
            left = next(t for t, cell in enumerate(path) if cell != path[0])
            assert all(not (path[t] == path[t + 1] and path[t] in no_wait) for t in range(left, len(path) - 1))


def test_an_agv_that_starts_where_it_cannot_wait_is_held_there_until_its_stretch_is_released():
    # AGV 2 starts in (1,3), without a wall, and goes west through (1,1), which AGV 1 leaves at step 1 by the
    # plan's clock. Under the ADG it may set out only once AGV 1 has left: it sends no action meanwhile.
    m = parse_map("agent 1: start 1,1  goal 1,5\nagent 2: start 1,3  goal 1,0\n" + OPEN_AISLE.split("\n", 4)[4])
    the_plan = plan(m)
    start = m.index(1, 3)
    assert the_plan.paths[1][:2] == (start, m.index(1, 2)) and m.index(1, 1) in the_plan.paths[1]
    for e in execute_many(the_plan, m, Settings(slip=0.1), seed=0, runs=10):
        assert e.held >= 1 and e.paths[1][:2] == (start, start)
        assert e.collisions == 0 and e.home


def test_stopping_anywhere_sets_out_on_the_next_cell_alone_and_holds_where_no_wall_is():
    # The stalling plan under stop_anywhere: AGV 1 sets out at once (its next cell (1,2) is released), no
    # stall, and where a delay of AGV 2 keeps (2,1) occupied AGV 1 holds in a cell without a wall.
    m, by_hand = stalling_plan()
    assert stall_risk(dependencies(m, by_hand, stop_anywhere=True)) == []
    executions = execute_many(by_hand, m, Settings(slip=0.3), seed=2, runs=10, stop_anywhere=True)
    for e in executions:
        assert e.stalls == e.waits == e.collisions == 0 and e.home
        assert visit_order(e.paths) == visit_order(by_hand.paths)
    assert any(e.held for e in executions)
    # on the open aisle it waits less than the rule that stops only at walls, at the same delays
    m = parse_map(OPEN_AISLE)
    the_plan = plan(m)
    walls, anywhere = (execute_many(the_plan, m, Settings(slip=0.2), 4, 20, stop_anywhere=flag)
                       for flag in (False, True))
    assert sum(e.sum_of_costs for e in anywhere) < sum(e.sum_of_costs for e in walls)
    assert all(e.collisions == 0 and e.home for e in walls + anywhere)


@pytest.mark.parametrize("name", MAPS)
def test_with_no_delays_the_execution_is_exactly_the_plan(name):
    m = parse_map(MAPS[name])
    the_plan = plan(m)
    e = execute(the_plan, m, Settings(), seed=0, run=0)
    assert e.paths == the_plan.paths and e.arrivals == the_plan.arrivals
    assert (e.makespan, e.sum_of_costs, e.collisions, e.messages, e.delays) == (
        the_plan.makespan, the_plan.sum_of_costs, 0, 0, 0)


def test_the_same_seed_gives_the_same_execution_and_runs_draw_their_own_delays():
    m = parse_map(OPEN_AISLE)
    the_plan = plan(m)
    settings = Settings(slip=0.2)
    assert execute(the_plan, m, settings, 5, 1) == execute(the_plan, m, settings, 5, 1)
    assert len({execute(the_plan, m, settings, 5, run).paths for run in range(6)}) > 1
    assert execute_many(the_plan, m, settings, 5, 3)[2] == execute(the_plan, m, settings, 5, 2)


STALLING_MAP = """\
agent 1: start 1,1  goal 2,1
agent 2: start 2,1  goal 1,1
+-+-+-+-+
|. . . .|
+ +-+ + +
|. . . .|
+ + + + +
|. . . .|
+ + + + +
|. . . .|
+-+-+-+-+
"""


def plan_by_hand(m, paths):
    actions = tuple(tuple(m.neighbours[a].index(b) for a, b in zip(path, path[1:])) for path in paths)
    return Plan(tuple(paths), actions, "by hand", 0)


def stalling_plan():
    """A plan that the world carries out by the clock but that stalls the ADG's stretches: a 4x4 room."""
    m = parse_map(STALLING_MAP)
    paths = ((m.index(1, 1), m.index(1, 2), m.index(2, 2), m.index(2, 1)), (m.index(2, 1), m.index(1, 1)))
    return m, plan_by_hand(m, paths)


def test_a_stall_is_broken_by_the_bare_adg():
    # AGV 1 waits in (1,1) (walled north) for its whole stretch (1,2) (2,2) (2,1) to be released, the last
    # by AGV 2 leaving (2,1); AGV 2, starting in (2,1) where it cannot wait, may enter (1,1) only once AGV 1
    # has left it. The plan is fine by the clock (AGV 2 moves in as AGV 1 moves out), but once a move can fail
    # neither AGV sets out: a cycle of stretches. AGV 1's next cell (1,2) alone is released, so it sets out,
    # and holds (no action) in (2,2) if AGV 2 has not yet left (2,1) by then.
    m, by_hand = stalling_plan()
    assert validate(m, by_hand) == [3, 1]
    assert execute(by_hand, m, Settings(), 0, 0).home
    executions = execute_many(by_hand, m, Settings(slip=0.3), seed=2, runs=10)
    for e in executions:
        assert e.stalls >= 1 and e.home and not e.stuck and e.collisions == 0
        assert visit_order(e.paths) == visit_order(by_hand.paths)
    assert any(e.held for e in executions)


def test_a_cycle_is_broken_at_once_while_other_agvs_still_move():
    # The stalling plan with a third AGV walking along the bottom row: AGVs 1 and 2 will not move by
    # themselves whatever AGV 3 does, so AGV 1 sets out at the first step, not once AGV 3 has arrived.
    _, by_hand = stalling_plan()
    m3 = parse_map(STALLING_MAP.replace("agent 2: start 2,1  goal 1,1\n",
                                        "agent 2: start 2,1  goal 1,1\nagent 3: start 3,0  goal 3,3\n"))
    row = tuple(m3.index(3, col) for col in range(4))
    paths = (*by_hand.paths, row)
    three = plan_by_hand(m3, paths)
    assert validate(m3, three) == [3, 1, 3]
    e = execute(three, m3, Settings(slip=1e-9), 0, 0)
    assert e.delays == 0 and e.stalls == 1 and e.home and e.collisions == 0
    assert e.paths[0][1] == paths[0][1] and e.paths[2] == row  # AGV 1 set out at step 1, beside AGV 3


def test_agvs_moving_round_a_loop_in_one_step_are_stuck_once_a_move_can_fail():
    # Four AGVs turn round a 2x2 room all in one step: the world allows it (no two end in one cell, none
    # swap), but each must wait for the AGV ahead to leave, and that one for the next: the bare ADG's cycle.
    m = parse_map("""\
agent 1: start 0,0  goal 0,1
agent 2: start 0,1  goal 1,1
agent 3: start 1,1  goal 1,0
agent 4: start 1,0  goal 0,0
+-+-+
|. .|
+ + +
|. .|
+-+-+
""")
    paths = tuple((start, goal) for start, goal in zip(m.starts, m.goals))
    turn = plan_by_hand(m, paths)
    assert validate(m, turn) == [1, 1, 1, 1]
    e = execute(turn, m, Settings(slip=0.1), 0, 0)
    assert e.stuck and not e.home and e.collisions == 0 and e.paths == tuple((start,) for start in m.starts)


def test_agvs_sharing_a_goal_both_arrive_without_waiting_on_each_other_there():
    # tunnel_to_goal: both AGVs end in (2,0), the goal of both, one following the other through the tunnel.
    m = load_map("tunnel_to_goal")
    the_plan = plan(m)
    goal = m.goals[0]
    deps = dependencies(m, the_plan)
    arrivals = [(i, len(route) - 1) for i, route in enumerate(deps.routes)]
    assert m.goals[1] == goal and deps.after[1][-1] != arrivals[0] and deps.after[0][-1] != arrivals[1]
    for e in execute_many(the_plan, m, Settings(slip=0.2, start_hold=3), seed=11, runs=10):
        assert e.collisions == 0 and e.home and [path[-1] for path in e.paths] == [goal, goal]


def test_warehouse_8_under_slip_is_collision_free_and_every_agv_home():
    m = load_map("warehouse_8")
    the_plan = plan(m)
    executions = execute_many(the_plan, m, Settings(slip=0.1), seed=0, runs=5)
    assert all(e.collisions == e.stalls == 0 and e.home and not e.stuck for e in executions)
    assert all(visit_order(e.paths) == visit_order(the_plan.paths) for e in executions)
    figures = spread(executions)
    assert figures["makespan"].low >= the_plan.makespan and figures["collisions"].high == 0


def test_plan_command_prints_the_executions(tmp_path, capsys):
    path = tmp_path / "entrance.txt"
    path.write_text(ENTRANCE)
    assert main(["plan", "--map", str(path), "--slip", "0.2", "--executions", "5", "--seed", "3"]) == 0
    out = capsys.readouterr().out
    assert "5 executions (seed 3, runs 0-4) with slip 0.2, start_hold 0: the action dependency graph" in out
    assert "collisions         0.00      0      0" in out
    assert "every AGV home in 5 of 5; stuck 0" in out
    assert "wait on each other in no cycle: no execution stalls" in out
    m = parse_map(ENTRANCE)
    e = execute_many(plan(m, seed=3), m, Settings(slip=0.2), 3, 5)
    assert f"{'messages':<14} {spread(e)['messages'].mean:>8.2f}" in out
    # the map's own slip applies when --slip is not given; --set changes any other setting of the world
    path.write_text("set slip=0.3\n" + ENTRANCE)
    assert main(["plan", "--map", str(path), "--executions", "2", "--set", "start_hold=1"]) == 0
    assert "with slip 0.3, start_hold 1:" in capsys.readouterr().out
    assert main(["plan", "--map", str(path), "--executions", "2", "--stop-anywhere"]) == 0
    assert "and an AGV may wait where no wall is (sending no action)" in capsys.readouterr().out


@pytest.mark.parametrize("args, phrase", [
    (["--slip", "1.5"], "argument --slip: must be at least 0 and at most 1"),
    (["--start-hold", "-1"], "argument --start-hold: must be at least 0"),
    (["--executions", "x"], "argument --executions: expected a whole number"),
    (["--set", "slop=1"], "unknown setting 'slop'"),
])
def test_plan_command_with_bad_delay_options_exits_2_with_one_line(args, phrase, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["plan", "--map", "tunnel_to_goal", *args])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and phrase in err and len(err.strip().splitlines()) == 1


def test_the_shipped_warehouses_plans_cannot_stall_and_the_hand_made_cycle_is_found():
    for name in ("warehouse_8", "warehouse_16"):
        m = load_map(name)
        the_plan = plan(m)
        assert stall_risk(dependencies(m, the_plan)) == []
        assert stall_risk(dependencies(m, the_plan, stop_anywhere=True)) == []  # the bare ADG: never a cycle
    for text in MAPS.values():
        m = parse_map(text)
        assert stall_risk(dependencies(m, plan(m))) == []
    m, by_hand = stalling_plan()
    assert stall_risk(dependencies(m, by_hand)) == [0, 1]

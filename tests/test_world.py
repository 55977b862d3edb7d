"""Tests of cq_ros.world: GridWorld's joint step and the collision resolver `resolve_moves`.

Hand cases on tiny inline maps, then hypothesis properties over random maps (and the shipped ones) with
2-5 agents placed at random and random joint actions, then the PettingZoo-style dict API.
"""

import dataclasses
import itertools
import random
from collections import deque

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from cq_ros.gridmap import available_maps, load_map, parse_map
from cq_ros.settings import Settings
from cq_ros.world import N_ACTIONS, GridWorld, Rewards, resolve_moves

NORTH, EAST, SOUTH, WEST = range(4)
R = Rewards()  # the defaults: step 0, wall -1, collision -10, goal 10

# Two rows of three open cells:  0 1 2 / 3 4 5
GRID_2X3 = """\
+-+-+-+
|. . .|
+ + + +
|. . .|
+-+-+-+
"""
# One row of four open cells: 0 1 2 3
ROW_4 = """\
+-+-+-+-+
|. . . .|
+-+-+-+-+
"""


def make_map(drawing: str, *agents: tuple[tuple[int, int], tuple[int, int]]):
    lines = [f"agent {k}: start {s[0]},{s[1]}  goal {g[0]},{g[1]}" for k, (s, g) in enumerate(agents, start=1)]
    return parse_map("\n".join(lines) + "\n\n" + drawing)


def world(drawing, *agents, **overrides):
    return GridWorld(make_map(drawing, *agents), Settings(**overrides) if overrides else Settings())


# --- hand cases ---------------------------------------------------------------------------------------


def test_wall_bump_stays_with_wall_penalty():
    w = world(GRID_2X3, ((0, 0), (1, 2)), ((1, 1), (0, 2)))
    start = list(w.cells)
    rewards = w.step_joint([WEST, SOUTH])  # both bump: off the grid west, and the south edge
    assert w.cells == start
    assert rewards == [R.wall, R.wall]
    assert w.last_collisions == 0 and w.last_bumps == 2
    assert w.t == 1 and not any(w.done)


def test_interior_wall_and_hash_cell_are_bumps():
    text = """\
+-+-+-+
|. .|.|
+ +-+ +
|. # .|
+-+-+-+
"""
    w = world(text, ((0, 0), (1, 0)), ((1, 0), (0, 1)))
    # cells: (0,0)=0 (0,1)=1 (0,2)=2 (1,0)=3 (1,2)=4
    assert w.map.neighbours[1][EAST] == 1 and w.map.neighbours[1][SOUTH] == 1
    w.step_joint([EAST, EAST])  # agent 1 to (0,1); agent 2 into the '#' cell
    assert w.cells == [1, 3]
    rewards = w.step_joint([EAST, NORTH])  # agent 1 through the '|' wall; agent 2 into agent 1's old cell
    assert w.cells == [1, 0] and rewards == [R.wall, R.step]


def test_same_cell_collision_both_stay():
    w = world(GRID_2X3, ((0, 0), (1, 2)), ((0, 2), (1, 0)))
    rewards = w.step_joint([EAST, WEST])  # both into (0,1)
    assert w.cells == [0, 2]
    assert rewards == [R.collision, R.collision]
    assert w.last_collisions == 1 and w.last_bumps == 0


def test_swap_collision():
    w = world(GRID_2X3, ((0, 0), (1, 2)), ((0, 1), (1, 0)))
    rewards = w.step_joint([EAST, WEST])
    assert w.cells == [0, 1]
    assert rewards == [R.collision, R.collision]
    assert w.last_collisions == 1


def test_vertical_swap_collision():
    w = world(GRID_2X3, ((0, 1), (1, 2)), ((1, 1), (0, 0)))
    rewards = w.step_joint([SOUTH, NORTH])
    assert w.cells == [1, 4] and rewards == [R.collision, R.collision] and w.last_collisions == 1


def test_following_into_a_vacated_cell_is_no_collision():
    w = world(ROW_4, ((0, 0), (0, 3)), ((0, 1), (0, 3)))
    rewards = w.step_joint([EAST, EAST])
    assert w.cells == [1, 2] and rewards == [R.step, R.step] and w.last_collisions == 0


def test_chain_into_an_agent_that_bumped():
    # A moves into B's cell; B bumps the north wall and stays, so A collides with B.
    w = world(GRID_2X3, ((0, 0), (1, 2)), ((0, 1), (1, 0)))
    rewards = w.step_joint([EAST, NORTH])
    assert w.cells == [0, 1]
    assert rewards == [R.collision, R.collision]
    assert w.last_collisions == 1
    assert w.last_bumps == 0  # B's bump is reported as its collision


def test_three_agent_chain_blocked_at_the_front():
    # A -> B's cell, B -> C's cell, C bumps the east wall: C stays, so B stays, so A stays.
    w = world(ROW_4, ((0, 1), (0, 0)), ((0, 2), (0, 0)), ((0, 3), (0, 0)))
    rewards = w.step_joint([EAST, EAST, EAST])
    assert w.cells == [1, 2, 3]
    assert rewards == [R.collision] * 3
    assert w.last_collisions == 2
    assert resolve_moves([1, 2, 3], [2, 3, 3], w.map.goals) == ([1, 2, 3], {(0, 1), (1, 2)})


def test_three_agent_chain_with_a_free_front_moves_together():
    w = world(ROW_4, ((0, 0), (0, 3)), ((0, 1), (0, 3)), ((0, 2), (0, 3)))
    rewards = w.step_joint([EAST, EAST, EAST])
    assert w.cells == [1, 2, 3]
    assert rewards == [R.step, R.step, R.goal]
    assert w.last_collisions == 0 and w.done == [False, False, True]


def test_chain_behind_a_collision():
    # B and C collide head-on over cell 2; A followed B into cell 1 and must go back too.
    w = world(ROW_4, ((0, 0), (0, 3)), ((0, 1), (0, 3)), ((0, 3), (0, 0)))
    rewards = w.step_joint([EAST, EAST, WEST])
    assert w.cells == [0, 1, 3]
    assert rewards == [R.collision] * 3
    assert w.last_collisions == 2


def test_shared_goal_two_arrive_together():
    w = world(ROW_4, ((0, 0), (0, 1)), ((0, 2), (0, 1)))
    rewards = w.step_joint([EAST, WEST])
    assert w.cells == [1, 1]
    assert rewards == [R.goal, R.goal]
    assert w.last_collisions == 0
    assert w.done == [True, True] and w.finished and not w.truncated


def test_arriving_at_a_shared_goal_already_occupied():
    w = world(ROW_4, ((0, 0), (0, 2)), ((0, 3), (0, 2)))
    w.step_joint([EAST, WEST])  # agent 2 arrives at the goal (0,2)
    assert w.done == [False, True]
    rewards = w.step_joint([EAST, None])  # agent 1 joins it there
    assert w.cells == [2, 2] and rewards == [R.goal, 0.0] and w.last_collisions == 0 and w.finished


def test_a_goal_of_only_one_agent_is_a_collision_cell():
    w = world(ROW_4, ((0, 0), (0, 1)), ((0, 2), (0, 3)))
    rewards = w.step_joint([EAST, WEST])
    assert w.cells == [0, 2]
    assert rewards == [R.collision, R.collision]
    assert w.last_collisions == 1 and w.done == [False, False]


def test_moving_onto_an_agent_resting_at_its_goal_collides():
    w = world(ROW_4, ((0, 0), (0, 3)), ((0, 2), (0, 1)))
    w.step_joint([NORTH, WEST])  # agent 2 reaches its goal (0,1)
    assert w.done == [False, True] and w.cells == [0, 1]
    rewards = w.step_joint([EAST, EAST])  # agent 1 into agent 2's goal cell; agent 2's action is ignored
    assert w.cells == [0, 1]
    assert rewards == [R.collision, 0.0]
    assert w.last_collisions == 1


def test_agent_at_goal_never_moves_and_gets_zero():
    w = world(GRID_2X3, ((0, 0), (0, 1)), ((1, 2), (1, 0)))
    rewards = w.step_joint([EAST, NORTH])
    assert rewards == [R.goal, R.step] and w.done == [True, False] and w.cells == [1, 2]
    for a in range(N_ACTIONS):
        rewards = w.step_joint([a, WEST if a % 2 else EAST])
        assert w.cells[0] == 1 and rewards[0] == 0.0 and w.done[0]
    # and in the dict API it is no longer a live agent
    assert w.live_agents() == [("agv2", 1)]
    obs, rew, term, trunc, infos = w.step({"agv2": WEST})
    assert set(obs) == set(rew) == set(term) == set(trunc) == set(infos) == {"agv2"}


def test_agent_starting_at_its_goal_is_done_from_the_start():
    w = world(ROW_4, ((0, 0), (0, 0)), ((0, 2), (0, 3)))
    assert w.done == [True, False]
    obs, infos = w.reset()
    assert set(obs) == set(infos) == {"agv2"}
    assert w.step_joint([EAST, EAST]) == [0.0, R.goal] and w.cells == [0, 3] and w.finished


def test_arrival_is_the_step_each_agent_reached_its_goal():
    w = world(ROW_4, ((0, 0), (0, 0)), ((0, 1), (0, 3)), ((0, 3), (0, 2)))
    assert w.arrival == [0, None, None]  # agent 1 starts at its goal
    w.step_joint([None, EAST, WEST])  # agents 2 and 3 both want (0, 2): they collide
    assert w.arrival == [0, None, None]
    w.step_joint([None, WEST, WEST])  # agent 2 into agent 1's goal: collides; agent 3 arrives at step 2
    assert w.arrival == [0, None, 2]
    w.step_joint([None, EAST, None])
    w.step_joint([None, EAST, None])  # (0, 2) is agent 3's goal, not agent 2's: stays
    assert w.arrival == [0, None, 2] and not w.finished
    w.reset_joint()
    assert w.arrival == [0, None, None]


def test_truncation_at_step_cap():
    w = world(ROW_4, ((0, 0), (0, 3)), ((0, 2), (0, 1)), step_cap=3)
    for t in range(3):
        assert not w.truncated
        obs, rew, term, trunc, infos = w.step({"agv1": WEST, "agv2": EAST})
        assert trunc == {"agv1": t == 2, "agv2": t == 2}
        assert term == {"agv1": False, "agv2": False}
    assert w.t == 3 and w.truncated and not w.finished


def test_finishing_on_the_last_allowed_step_is_not_truncation():
    w = world(ROW_4, ((0, 0), (0, 1)), ((0, 3), (0, 2)), step_cap=1)
    obs, rew, term, trunc, infos = w.step({"agv1": EAST, "agv2": WEST})
    assert w.finished and not w.truncated
    assert term == {"agv1": True, "agv2": True} and trunc == {"agv1": False, "agv2": False}


def test_reset_restores_the_start():
    w = world(GRID_2X3, ((0, 0), (0, 1)), ((1, 2), (1, 0)))
    w.step_joint([EAST, NORTH])
    w.step_joint([None, WEST])
    assert w.t == 2
    cells = w.reset_joint()
    assert cells == list(w.map.starts) and w.t == 0 and w.done == [False, False] and w.last_collisions == 0


def random_walk(w: GridWorld, actions_seed: int, steps: int):
    rng = random.Random(actions_seed)
    w.reset_joint()
    trace = []
    for _ in range(steps):
        if w.finished:
            w.reset_joint()
        rewards = w.step_joint([rng.randrange(N_ACTIONS) for _ in range(w.n)])
        trace.append((tuple(w.cells), tuple(rewards), w.last_collisions))
    return trace


def test_slip_zero_is_deterministic():
    m = load_map("tunnel_to_goal")
    a = random_walk(GridWorld(m, Settings(), seed=1), 5, 300)
    b = random_walk(GridWorld(m, Settings(), seed=2), 5, 300)
    assert a == b  # the world seed does not matter without slip
    # and every move is the map's move
    w = GridWorld(m, Settings(), seed=3)
    for _ in range(50):
        before = list(w.cells)
        w.step_joint([SOUTH, NORTH])
        if w.last_collisions == 0:
            for i in range(2):
                assert w.cells[i] == m.neighbours[before[i]][SOUTH if i == 0 else NORTH] or w.done[i]


def test_delays_are_reproducible_from_the_seed():
    m = load_map("tunnel_to_goal")
    for s in (Settings(slip=0.3), Settings(start_hold=4), Settings(slip=0.1, start_hold=2)):
        a = random_walk(GridWorld(m, s, seed=11), 5, 400)
        b = random_walk(GridWorld(m, s, seed=11), 5, 400)
        c = random_walk(GridWorld(m, s, seed=12), 5, 400)
        plain = random_walk(GridWorld(m, Settings(), seed=11), 5, 400)
        assert a == b
        assert a != c
        assert a != plain  # delays do change some moves


def test_reset_with_a_seed_reseeds_the_delays():
    m = load_map("tunnel_to_goal")
    w = GridWorld(m, Settings(slip=0.5, start_hold=3), seed=0)
    traces = []
    for _ in range(2):
        w.reset(seed=42)
        traces.append([(w.step_joint([EAST, EAST]), tuple(w.cells), tuple(w.delayed)) for _ in range(30)
                       if not w.finished])
    assert traces[0] == traces[1]


def test_a_slip_near_one_holds_every_agent_where_it_is_at_the_cost_of_a_step():
    m = load_map("tunnel_to_goal")  # slip 1 is refused (tests/test_settings.py); at seed 0 every draw here fails
    w = GridWorld(m, Settings(slip=0.9999), seed=0)
    for _ in range(20):
        rewards = w.step_joint([EAST, WEST])
        assert w.cells == list(m.starts) and rewards == [R.step, R.step] and w.delayed == [True, True]
    assert w.last_delays == 2 and w.last_bumps == 0


def test_start_hold_delays_only_the_first_moves_and_is_drawn_each_episode():
    m = load_map("tunnel_to_goal")
    w = GridWorld(m, Settings(start_hold=5), seed=3)
    seen = set()
    for _ in range(40):
        w.reset_joint()
        holds = list(w.hold)
        assert all(0 <= h <= 5 for h in holds)
        seen.add(tuple(holds))
        for t in range(6):
            w.step_joint([None if d else EAST for d in w.done])
            assert w.delayed == [t < h for h in holds]  # exactly the first h moves of each agent fail
    assert len(seen) > 10  # drawn anew at every reset


def test_an_acting_agent_without_an_action_stays_and_draws_what_the_offline_step_draws():
    m = load_map("tunnel_to_goal")
    s = Settings(slip=0.4)
    a, b = GridWorld(m, s, seed=5), GridWorld(m, s, seed=5)
    for _ in range(30):
        before = list(b.cells)
        a.step_joint([EAST, WEST])
        rewards = b.step_joint([None, WEST])
        assert a.delayed == b.delayed  # the stream does not depend on the actions
        assert b.cells[0] == before[0] and rewards[0] in (R.step, R.collision)


# --- resolve_moves, directly -----------------------------------------------------------------------


def conflicts(cells, final, goals):
    """The pairs that break the rules in `final` (same cell not a shared goal, or a swap)."""
    bad = set()
    for i, j in itertools.combinations(range(len(cells)), 2):
        same = final[i] == final[j] and not (goals[i] == goals[j] == final[i])
        swap = final[i] == cells[j] and final[j] == cells[i] and cells[i] != cells[j]
        if same or swap:
            bad.add((i, j))
    return bad


@st.composite
def resolver_inputs(draw):
    n = draw(st.integers(2, 5))
    n_cells = draw(st.integers(n, 9))
    goals = draw(st.lists(st.integers(0, n_cells - 1), min_size=n, max_size=n))
    # distinct cells, except that agents sharing a goal may stand on it together
    cells = draw(st.lists(st.integers(0, n_cells - 1), min_size=n, max_size=n, unique=True))
    for i in range(n):
        if draw(st.integers(0, 3)) == 0:
            cells[i] = goals[i]
    assume(not conflicts(cells, cells, goals))
    targets = [draw(st.one_of(st.just(c), st.integers(0, n_cells - 1))) for c in cells]
    return cells, targets, goals


@settings(max_examples=400, deadline=None)
@given(resolver_inputs())
def test_resolve_moves_properties(args):
    cells, targets, goals = args
    final, pairs = resolve_moves(list(cells), list(targets), goals)
    n = len(cells)
    assert len(final) == n
    assert not conflicts(cells, final, goals)
    collided = {i for p in pairs for i in p}
    for i in range(n):
        assert final[i] in (cells[i], targets[i])
        if i in collided:
            assert final[i] == cells[i]
        else:
            assert final[i] == targets[i]  # nobody is sent back without a collision
    for i, j in pairs:
        assert 0 <= i < j < n
    if not conflicts(cells, targets, goals):
        assert final == targets and pairs == set()
    # idempotent: resolving its own output changes nothing
    assert resolve_moves(list(cells), list(final), goals) == (final, set())
    assert resolve_moves(list(final), list(final), goals) == (final, set())
    # inputs are not modified
    assert resolve_moves(list(cells), list(targets), goals) == (final, pairs)


def pairwise_resolver(cells, targets, goals):
    """The resolver as it was before it was made linear in the agents (every pair checked each round,
    colliders sent back, until no collider is away from its cell): the semantics resolve_moves keeps."""
    final = list(targets)
    pairs = set()
    n = len(cells)
    while True:
        clash = set()
        for i in range(n):
            for j in range(i + 1, n):
                same_cell = final[i] == final[j] and not (goals[i] == goals[j] == final[i])
                swap = final[i] == cells[j] and final[j] == cells[i] and cells[i] != cells[j]
                if same_cell or swap:
                    pairs.add((i, j))
                    clash.update((i, j))
        moved_back = [i for i in clash if final[i] != cells[i]]
        if not moved_back:
            return final, pairs
        for i in moved_back:
            final[i] = cells[i]


@st.composite
def any_joint_moves(draw):
    """Up to 24 agents on few cells, so chains, swaps, crowds and shared goals are common; cells may
    repeat (more than the world allows), so the two resolvers are compared beyond the world's states."""
    n = draw(st.integers(1, 24))
    n_cells = draw(st.integers(1, 2 * n + 1))
    cell = st.integers(0, n_cells - 1)
    shared = draw(st.lists(cell, min_size=1, max_size=3))  # a few goals many agents share
    goals = tuple(draw(st.lists(st.one_of(cell, st.sampled_from(shared)), min_size=n, max_size=n)))
    cells = draw(st.lists(cell, min_size=n, max_size=n))
    moves = draw(st.lists(st.one_of(st.none(), cell), min_size=n, max_size=n))  # None: stays
    return cells, [c if m is None else m for c, m in zip(cells, moves)], goals


@settings(max_examples=300, deadline=None)
@given(st.one_of(resolver_inputs(), any_joint_moves()))
def test_resolve_moves_is_the_pairwise_resolver(args):
    cells, targets, goals = args
    assert resolve_moves(list(cells), list(targets), goals) == pairwise_resolver(cells, targets, goals)


@pytest.mark.parametrize("map_name", ["warehouse_8", "warehouse_32"])
def test_resolve_moves_is_the_pairwise_resolver_on_a_warehouse(map_name):
    # a whole fleet walking at random from its starts (crowded at first), some standing still each step
    gm = load_map(map_name)
    rng = random.Random(7)
    cells, clashes = list(gm.starts), 0
    for _ in range(300):
        targets = [c if rng.random() < 0.2 else gm.neighbours[c][rng.randrange(N_ACTIONS)] for c in cells]
        final, pairs = resolve_moves(cells, targets, gm.goals)
        assert (final, pairs) == pairwise_resolver(cells, targets, gm.goals)
        cells, clashes = final, clashes + len(pairs)
    assert clashes > 0  # the walk did meet collisions


def test_resolve_moves_does_not_mutate_its_arguments():
    cells, targets, goals = [0, 1, 2], [1, 2, 2], (5, 5, 5)
    resolve_moves(cells, targets, goals)
    assert cells == [0, 1, 2] and targets == [1, 2, 2]


def test_resolve_moves_three_into_a_goal_shared_by_two():
    # Agents 0 and 1 share the goal 1 but agent 2 does not: everybody collides and stays.
    final, pairs = resolve_moves([0, 2, 5], [1, 1, 1], (1, 1, 4))
    assert final == [0, 2, 5] and pairs == {(0, 2), (1, 2)}


# --- GridWorld under random joint actions ----------------------------------------------------------


def _components(height, width, blocked):
    open_cells = [(r, c) for r in range(height) for c in range(width) if (r, c) not in blocked]
    comp, label = {}, 0
    for cell in open_cells:
        if cell in comp:
            continue
        comp[cell] = label
        todo = deque([cell])
        while todo:
            r, c = todo.popleft()
            for nb in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
                if nb in comp or nb in blocked or not (0 <= nb[0] < height and 0 <= nb[1] < width):
                    continue
                comp[nb] = label
                todo.append(nb)
        label += 1
    return comp


def _drawing(height, width, blocked):
    lines = ["+" + "-+" * width]
    for r in range(height):
        lines.append("|" + " ".join("#" if (r, c) in blocked else "." for c in range(width)) + "|")
        lines.append("+" + ("-+" * width if r == height - 1 else " +" * width))
    return "\n".join(lines)


@st.composite
def random_maps(draw):
    """A small open grid with a few '#' cells and 2-5 agents at distinct cells, goals reachable."""
    height, width = draw(st.integers(1, 4)), draw(st.integers(2, 5))
    grid = [(r, c) for r in range(height) for c in range(width)]
    blocked = set(draw(st.lists(st.sampled_from(grid), max_size=len(grid) // 3, unique=True)))
    comp = _components(height, width, blocked)
    assume(len(comp) >= 2)
    n = draw(st.integers(2, min(5, len(comp))))
    starts = draw(st.lists(st.sampled_from(sorted(comp)), min_size=n, max_size=n, unique=True))
    goals = []
    for s in starts:
        same_comp = sorted(c for c in comp if comp[c] == comp[s])
        # sometimes a goal shared with an earlier agent, if reachable
        shared = [g for g in goals if comp[g] == comp[s]]
        if shared and draw(st.booleans()):
            goals.append(draw(st.sampled_from(shared)))
        else:
            goals.append(draw(st.sampled_from(same_comp)))
    return make_map(_drawing(height, width, blocked), *zip(starts, goals))


@st.composite
def shipped_maps_with_agents(draw):
    """A shipped map with 2-5 agents placed at random distinct cells and random goals."""
    gm = load_map(draw(st.sampled_from(available_maps())))
    n = draw(st.integers(2, 5))
    cells = st.integers(0, gm.n_cells - 1)
    starts = tuple(draw(st.lists(cells, min_size=n, max_size=n, unique=True)))
    goals = tuple(draw(st.lists(cells, min_size=n, max_size=n)))
    return dataclasses.replace(gm, starts=starts, goals=goals)


def check_random_play(gm, actions_seed, slip, start_hold=0):
    w = GridWorld(gm, Settings(slip=slip, start_hold=start_hold, step_cap=10_000), seed=actions_seed)
    rng = random.Random(actions_seed)
    goals = gm.goals
    assert w.done == [c == g for c, g in zip(w.cells, goals)]
    for _ in range(150):
        if w.finished:
            w.reset_joint()
        before, done_before = list(w.cells), list(w.done)
        actions = [None if d else rng.randrange(N_ACTIONS) for d in done_before]
        rewards = w.step_joint(actions)
        after = w.cells
        # nobody stands outside the world
        assert all(0 <= c < gm.n_cells for c in after)
        # no two agents share a cell that is not a goal of both
        assert not conflicts(before, after, goals)
        # each final position is the agent's own cell or a cell next to it
        for i in range(w.n):
            assert after[i] == before[i] or after[i] in gm.neighbours[before[i]]
            if done_before[i]:
                assert after[i] == before[i] and rewards[i] == 0.0 and w.done[i]
        # idempotent on its own output
        assert resolve_moves(before, list(after), goals) == (after, set())
        assert w.done == [c == g for c, g in zip(after, goals)]
        # the step is resolve_moves of the moves that did not fail
        delayed = w.delayed
        assert slip > 0 or not any(delayed)
        assert not any(d and done for d, done in zip(delayed, done_before))  # an agent at its goal draws nothing
        targets = [c if d or late else gm.neighbours[c][a]
                   for c, d, late, a in zip(before, done_before, delayed, actions)]
        final, pairs = resolve_moves(before, targets, goals)
        assert final == after
        assert w.last_collisions == len(pairs)
        collided = {i for p in pairs for i in p}
        for i in range(w.n):
            assert after[i] in (before[i], targets[i])
            if done_before[i]:
                continue
            bumped = targets[i] == before[i] and not delayed[i]
            if bumped or delayed[i] or i in collided:
                assert after[i] == before[i]  # a bumped, delayed or colliding agent is where it was
            if i in collided:
                assert rewards[i] == R.collision
            elif delayed[i]:
                assert rewards[i] == R.step  # a delay costs a step, never a wall penalty
            elif bumped:
                assert rewards[i] == R.wall
            elif after[i] == goals[i]:
                assert rewards[i] == R.goal and w.done[i]
            else:
                assert rewards[i] == R.step and after[i] == targets[i]
        assert w.last_bumps == sum(
            1 for i in range(w.n) if not done_before[i] and not delayed[i] and targets[i] == before[i]
            and i not in collided
        )
        assert w.last_delays == sum(delayed)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(random_maps(), st.integers(0, 2**32 - 1))
def test_random_play_on_random_maps(gm, actions_seed):
    check_random_play(gm, actions_seed, slip=0.0)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(shipped_maps_with_agents(), st.integers(0, 2**32 - 1))
def test_random_play_on_shipped_maps(gm, actions_seed):
    check_random_play(gm, actions_seed, slip=0.0)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(random_maps(), st.integers(0, 2**32 - 1))
def test_random_play_with_delays_keeps_the_invariants(gm, actions_seed):
    check_random_play(gm, actions_seed, slip=0.5)
    check_random_play(gm, actions_seed, slip=0.1, start_hold=3)


def test_crowded_corridor_many_steps():
    """Five agents in a 1x6 corridor, thousands of random joint actions: the invariants hold throughout."""
    gm = make_map(
        "+-+-+-+-+-+-+\n|. . . . . .|\n+-+-+-+-+-+-+",
        ((0, 0), (0, 5)), ((0, 1), (0, 5)), ((0, 2), (0, 0)), ((0, 4), (0, 3)), ((0, 5), (0, 3)),
    )
    for seed in range(20):
        check_random_play(gm, seed, slip=0.0)


# --- the dict API ----------------------------------------------------------------------------------


def test_reset_returns_obs_for_all_agents():
    gm = load_map("tunnel_to_goal")
    w = GridWorld(gm)
    w.step_joint([SOUTH, NORTH])
    obs, infos = w.reset()
    assert obs == {"agv1": gm.starts[0], "agv2": gm.starts[1]}
    assert infos == {"agv1": {}, "agv2": {}}
    assert w.agents == ["agv1", "agv2"] and w.t == 0


def test_step_with_missing_or_unknown_agent_raises_keyerror():
    w = GridWorld(load_map("tunnel_to_goal"))
    w.reset()
    with pytest.raises(KeyError, match="agv2"):
        w.step({"agv1": SOUTH})
    with pytest.raises(KeyError, match="agv9"):
        w.step({"agv1": SOUTH, "agv2": NORTH, "agv9": EAST})
    with pytest.raises(KeyError):
        w.step({})
    assert w.t == 0 and w.cells == list(w.map.starts)  # a refused step changes nothing


def test_step_dicts_are_keyed_by_live_agents():
    gm = make_map(GRID_2X3, ((0, 0), (0, 1)), ((1, 2), (1, 0)))
    w = GridWorld(gm)
    w.reset()
    obs, rew, term, trunc, infos = w.step({"agv1": EAST, "agv2": WEST})
    assert set(obs) == set(rew) == set(term) == set(trunc) == set(infos) == {"agv1", "agv2"}
    assert rew == {"agv1": R.goal, "agv2": R.step}
    assert term == {"agv1": True, "agv2": False}
    assert obs == {"agv1": 1, "agv2": 4}
    assert infos["agv1"]["collisions"] == 0
    # agv1 is done: it is no longer needed, and no longer reported
    obs, rew, term, trunc, infos = w.step({"agv2": WEST})
    assert set(rew) == set(obs) == set(term) == set(trunc) == {"agv2"}
    assert rew == {"agv2": R.goal} and term == {"agv2": True} and w.finished


def test_dict_step_reports_collisions_in_infos():
    w = GridWorld(make_map(GRID_2X3, ((0, 0), (1, 2)), ((0, 2), (1, 0))))
    w.reset()
    obs, rew, term, trunc, infos = w.step({"agv1": EAST, "agv2": WEST})
    assert rew == {"agv1": R.collision, "agv2": R.collision}
    assert infos == {"agv1": {"collisions": 1}, "agv2": {"collisions": 1}}
    assert obs == {"agv1": 0, "agv2": 2}


def test_dict_step_matches_step_joint():
    gm = load_map("isr")
    a, b = GridWorld(gm), GridWorld(gm)
    a.reset()
    b.reset_joint()
    rng = random.Random(4)
    for _ in range(300):
        if a.finished:
            break
        acts = {name: rng.randrange(4) for name, _ in a.live_agents()}
        _, rew, _, _, _ = a.step(acts)
        joint = [acts.get(name) for name in b.agents]
        rewards = b.step_joint(joint)
        assert a.cells == b.cells
        assert rew == {name: rewards[i] for i, name in enumerate(b.agents) if name in rew}

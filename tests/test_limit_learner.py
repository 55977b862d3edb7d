"""The limit learner (cq_ros.learners.limit): it hears a peer exactly where the world's rules let that peer
collide with it this step, and its unit of the held-out study is the same again from the same seed."""

import itertools

import pytest

from cq_ros.gridmap import load_map, parse_map
from cq_ros.lab.held_out import Unit, config_settings, play_unit
from cq_ros.lab.held_out_protocol import Config
from cq_ros.lab.limit import LimitLearning
from cq_ros.learners import limit
from cq_ros.mapgen.warehouse import warehouse_text
from cq_ros.settings import Settings
from cq_ros.world import resolve_moves


# Two rows joined only at columns 3 and 4: row 0 and row 1 are walled apart under columns 0-2.
WALLED = """\
agent 1: start 0,1  goal 1,4
agent 2: start 1,1  goal 1,0
agent 3: start 1,3  goal 0,3

+-+-+-+-+-+
|. . . . .|
+-+-+-+ + +
|. . . . .|
+-+-+-+-+-+
"""


def test_it_looks_at_a_peer_that_can_collide_and_not_at_one_within_range_that_cannot():
    gm = parse_map(WALLED)
    at = {cell: i for i, cell in enumerate(gm.cells)}
    learner = limit.LimitQ(0, gm, Settings(), seed=0)
    s = at[0, 1]
    # agent 2 one cell away across the wall: near (range 2) would hear it; it cannot collide with agent 1
    assert gm.distance(s, at[1, 1]) == 1 and not learner.could_collide(s, 1, at[1, 1])
    # agent 2 two cells along the row: both can move into (0, 2)
    assert learner.could_collide(s, 1, at[0, 3])
    # agent 3 in the same cell, but at its goal: it never moves again, and agent 1 cannot reach it in one move
    assert not learner.could_collide(s, 2, at[0, 3])
    assert learner.could_collide(s, 2, at[0, 2])  # ... one cell away it can: agent 1 runs into it
    learner.observe(s)
    learner.act({1: at[1, 1], 2: at[0, 3]})
    assert learner.heard == 0 and learner.q_near == {}  # nobody who can collide: its own cell's row
    learner.learn(-1.0, s, False)
    learner.observe(s)
    learner.act({1: at[0, 3], 2: at[1, 3]})
    assert learner.heard == 1 and list(learner.q_near) == [(s, ((1, at[0, 3]),))]


@pytest.mark.parametrize("name", ["warehouse", "grid_game_2"])
def test_its_rule_is_the_worlds_one_step_collisions(name):
    """For every pair of cells up to 3 apart, the rule says yes exactly where some joint move of the two (either
    may stay: a delay) makes them a colliding pair by cq_ros.world.resolve_moves; on a warehouse, and on
    grid_game_2, whose two agents share their goal (the one cell two agents may both end in)."""
    gm = parse_map(warehouse_text(4, seed=1001, slip=0.1)) if name == "warehouse" else load_map(name)
    learner = limit.LimitQ(0, gm, Settings(), seed=0)
    reach = [{c, *gm.neighbours[c]} for c in range(gm.n_cells)]
    checked = 0
    for peer in range(1, gm.n_agents):
        for s, c in itertools.product(range(gm.n_cells), repeat=2):
            if s == c or gm.distance(s, c) > 3:
                continue
            moves = (c,) if c == gm.goals[peer] else reach[c]
            goals = (gm.goals[0], gm.goals[peer])
            world = any(resolve_moves([s, c], [t, u], goals)[1] for t in reach[s] for u in moves)
            assert learner.could_collide(s, peer, c) == world, (s, peer, c)
            checked += 1
    assert checked > (500 if name == "warehouse" else 40)


def test_its_cq_twin_acts_on_the_least_of_the_rows_of_the_peers_that_can_collide_and_updates_each():
    gm = parse_map(WALLED)
    at = {cell: i for i, cell in enumerate(gm.cells)}
    learner = limit.LimitCQ(0, gm, Settings(), seed=0)
    s = at[0, 2]
    learner.q_local[s] = [0.0, 1.0, 2.0, 3.0]
    learner.observe(s)
    learner.act({1: at[0, 4], 2: at[1, 2]})  # agent 2 can reach (0, 3); agent 3 is walled off
    assert learner.heard == 1 and list(learner.q_near) == [(s, 1, at[0, 4])]
    learner.learn(-1.0, s, False)
    learner.q_near[(s, 1, at[0, 4])][:] = [5.0, 0.0, 5.0, 0.0]
    learner.observe(s)
    learner.epsilon = 0.0
    peers = {1: at[0, 4], 2: at[0, 1]}  # now both can collide with it: the elementwise least of their rows
    first = list(learner.q_near[(s, 1, at[0, 4])])
    assert learner.act(peers) == 2  # min([5, 0, 5, 0], [0, 1, 2, 3]) = [0, 0, 2, 0]
    assert learner.heard == 3 and set(learner.q_near) == {(s, 1, at[0, 4]), (s, 2, at[0, 1])}
    assert learner.q_near[(s, 1, at[0, 4])] != first  # the waiting step's update landed in the row acted on
    learner.learn(-30.0, s, False)
    learner.observe(s)
    learner.act(peers)
    rows = [learner.q_near[(s, 1, at[0, 4])], learner.q_near[(s, 2, at[0, 1])]]
    assert rows[0][2] < 5.0 and rows[1][2] < 2.0  # the collision is learnt in both rows it acted on


@pytest.mark.parametrize("learner", ["limit", "limit_cq"])
def test_a_unit_is_the_same_again_from_its_seed(tmp_path, learner):
    path = tmp_path / "warehouse_4_gen1001.txt"
    path.write_text(warehouse_text(4, seed=1001, slip=0.1))
    gm = parse_map(path.read_text())
    settings = config_settings(Config(learner, "near"), gm, ["step_cap=60"], 3)
    unit = Unit(str(path), learner, 1, 20, 0, settings, learner, 4, 1001, 3, 10, 2)

    def row():
        result = play_unit({str(path): gm}, unit, lambda: None, LimitLearning)
        return {k: v for k, v in result["row"].items() if k != "seconds"}, result["curve"]

    first = row()
    assert first == row()
    assert first[0]["states"] > gm.n_cells  # it met peers that could collide, and kept rows for them

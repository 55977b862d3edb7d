"""Tests of cq_ros.learners (one test per rule, hand-fed observe/act/learn on tiny maps) and of the
offline engine's determinism (cq_ros.engine).

A step, as the engine drives it: `need = observe(cell)`, `act({j: cell_j for j in need})`,
`learn(reward, next_cell, done)`. With epsilon = 0 a learner is greedy; ties are broken by its rng, so the
tests make the preferred action strictly best where they need to know it.
"""

import math
import pickle
import random

import numpy as np
import pytest
import scipy.stats

from cq_ros import engine
from cq_ros.engine import Team, make_learner, make_learners
from cq_ros.episode import COLUMNS
from cq_ros.gridmap import load_map, parse_map
from cq_ros.learners import ALGORITHMS, LEARNERS, decode_joint_action
from cq_ros.learners.base import N_MOVES
from cq_ros.learners.cq import CQLearner
from cq_ros.learners.cq_paper import CQPaperLearner, Step
from cq_ros.learners.indep import IndependentQ
from cq_ros.learners.js import JointStateQ
from cq_ros.learners.jsa import MAX_AGENTS, JointStateActionQ
from cq_ros.learners.loc import COORDINATE, LearningOfCoordination
from cq_ros.learners.near import NearQ
from cq_ros.settings import CONF_INIT, Settings
from cq_ros.world import GridWorld
from helpers import OUR_RULES, ours_without, run_as, with_rules

NORTH, EAST, SOUTH, WEST = range(4)
GREEDY = dict(epsilon=0.0)


def make_map(width, *agents, height=1):
    """An open height x width grid; agents are ((row, col), (row, col)) start/goal pairs."""
    lines = [f"agent {k}: start {s[0]},{s[1]}  goal {g[0]},{g[1]}" for k, (s, g) in enumerate(agents, start=1)]
    drawing = ["+" + "-+" * width]
    for r in range(height):
        drawing.append("|" + " ".join("." * width) + "|")
        drawing.append("+" + ("-+" * width if r == height - 1 else " +" * width))
    return parse_map("\n".join(lines) + "\n\n" + "\n".join(drawing))


# Three agents in one row of six cells: cell index == column.
ROW3 = make_map(6, ((0, 0), (0, 5)), ((0, 3), (0, 0)), ((0, 5), (0, 1)))
# Two agents in one row of six cells.
ROW2 = make_map(6, ((0, 0), (0, 5)), ((0, 5), (0, 0)))


def cq(gridmap=ROW3, **overrides):
    """The paper's CQ on `gridmap`, with each rule of ours named cq_<rule>=1 in `overrides`."""
    rules = [r for r in OUR_RULES if overrides.pop(f"cq_{r}", 0)]
    learner = with_rules(*rules)(0, gridmap, Settings(**{**GREEDY, "window": 5, **overrides}), seed=1)
    learner.q_local[0] = [-100.0, 5.0, -100.0, -100.0]  # at cell 0 the greedy move is EAST
    return learner


def step(learner, cell, peer_cells, reward, next_cell, done=False):
    """One observe/act/learn; `peer_cells` holds every peer's cell, the learner is shown what it asks for."""
    need = learner.observe(cell)
    action = learner.act({j: peer_cells[j] for j in need})
    learner.learn(reward, next_cell, done)
    return need, action


ELSEWHERE = {1: 4, 2: 5}  # the peers' cells whenever they do not matter


def conflict_rewards(last_high=False):
    """W1 = five 0s; W2 = 0, -10, -10, -10 and a last reward of -10 (low) or 0 (high): always a drop."""
    w2 = [-10.0, -10.0, -10.0, -10.0, 0.0] if last_high else [0.0, -10.0, -10.0, -10.0, -10.0]
    rewards = [0.0] * 5 + w2
    # guard the premise with scipy: W2 dropped, and the last reward is (not) significantly above W2
    assert scipy.stats.ttest_ind(w2, rewards[:5], alternative="less").pvalue < 0.05
    above = scipy.stats.ttest_1samp(w2, rewards[-1], alternative="less").pvalue < 0.05
    assert above == last_high
    return rewards


def conflict_at(learner):
    """The cell of a conflict found at the last step and not marked yet (at the learner's next act), or None."""
    waiting = learner.waiting
    return waiting.cell if waiting is not None and waiting.conflict else None


def cq_with_conflict(**overrides):
    """A CQ learner that has just detected a conflict at cell 0 (marked at its next act)."""
    learner = cq(**overrides)
    for r in conflict_rewards():
        need, action = step(learner, 0, ELSEWHERE, r, 0)
        assert need == () and action == EAST
    assert conflict_at(learner) == 0 and not learner.q_joint
    return learner


# --- CQ ----------------------------------------------------------------------------------------------


def test_cq_w1_fills_first_then_w2_slides():
    learner = cq()
    rewards = [float(-k) for k in range(13)]
    for k, r in enumerate(rewards, start=1):
        step(learner, 0, ELSEWHERE, r, 1)
        w = learner.windows[0 * N_MOVES + EAST]
        assert w.n1 == min(k, 5)
        assert math.isclose(w.sum1, sum(rewards[: min(k, 5)]))
        assert sorted(w.w2) == sorted(rewards[5:k][-5:])
    # no other (state, action) pair saw a reward
    assert all(w.n1 == 0 for i, w in enumerate(learner.windows) if i != EAST)


def test_cq_drop_and_low_reward_marks_a_joint_state_per_peer_where_the_peers_are_then():
    learner = cq()
    rewards = conflict_rewards()
    for k, r in enumerate(rewards, start=1):
        step(learner, 0, ELSEWHERE, r, 0)
        assert (conflict_at(learner) is not None) == (k == 10)  # tests run only once W2 is full
    assert learner.q_joint == {} and learner.watch == {}
    # Detected: at its next step the agent looks at every peer, and marks where they are now.
    now = {1: 1, 2: 3}
    assert learner.observe(2) == (1, 2)
    learner.act(now)
    assert set(learner.q_joint) == {(0, 1, 1), (0, 2, 3)}
    assert learner.marked == {0: [(0, 1, 1), (0, 2, 3)]}
    assert learner.watch == {0: (1, 2)}
    assert learner.confidence == {(0, 1, 1): 1.0, (0, 2, 3): 1.0}
    assert conflict_at(learner) is None
    assert learner.keys[0] is None  # cell 2 has no joint state: it acted on Q_k
    assert learner.state_count() == ROW3.n_cells + 2
    assert sorted(learner.joint_states()) == [(0, 1, 1, 1.0), (0, 2, 3, 1.0)]


def test_cq_drop_with_a_high_last_reward_marks_nothing():
    learner = cq()
    for r in conflict_rewards(last_high=True):
        step(learner, 0, ELSEWHERE, r, 0)
    assert conflict_at(learner) is None
    for cell in range(ROW3.n_cells):
        assert learner.observe(cell) == ()
        learner.act({})
    assert learner.q_joint == {} and learner.marked == {} and learner.watch == {}


def test_cq_no_conflict_when_the_step_ends_the_episode():
    learner = cq()
    rewards = conflict_rewards()
    for r in rewards[:-1]:
        step(learner, 0, ELSEWHERE, r, 0)
    step(learner, 0, ELSEWHERE, rewards[-1], 1, done=True)
    assert conflict_at(learner) is None


def test_cq_new_joint_state_starts_as_a_copy_of_q_local():
    learner = cq_with_conflict()
    q0 = list(learner.q_local[0])
    learner.observe(0)
    learner.act({1: 1, 2: 3})  # cell 0 again: the joint states are met at once
    for js in ((0, 1, 1), (0, 2, 3)):
        assert learner.q_joint[js] == q0
        assert learner.q_joint[js] is not learner.q_local[0]
    assert learner.q_joint[(0, 1, 1)] is not learner.q_joint[(0, 2, 3)]
    learner.learn(-1.0, 1, False)
    assert learner.q_local[0] == q0  # the update went to Q^j, not Q_k
    assert learner.q_joint[learner.keys[0]] != q0


@pytest.mark.parametrize("bootstrap_acted", [0, 1])
def test_cq_new_joint_state_has_learnt_the_conflict_step_as_q_local_has(bootstrap_acted):
    """The step that revealed the conflict (its -10) is in Q^j as in Q_k, whether Q_k learnt it at once (the
    paper) or waits for the next act (cq_bootstrap_acted): else the agent repeats the move that collided."""
    learner = cq_with_conflict(cq_bootstrap_acted=bootstrap_acted)
    learner.observe(2)
    learner.act({1: 1, 2: 3})  # marks (0, 1, 1) and (0, 2, 3) from elsewhere; any pending update lands now
    assert learner.waiting is None
    assert learner.q_local[0][EAST] < 5.0  # Q_k has learnt the conflict rewards
    for js in ((0, 1, 1), (0, 2, 3)):
        assert learner.q_joint[js] == learner.q_local[0]


def test_cq_marking_an_existing_joint_state_keeps_its_table():
    learner = cq_with_conflict()
    step(learner, 0, {1: 1, 2: 3}, -1.0, 1)
    js = learner.keys[0]
    table = list(learner.q_joint[js])
    learner.waiting = Step(0, [], EAST, 0.0, 0, done=False, conflict=True)  # a conflict found at cell 0 again
    learner.observe(3)
    learner.act({1: 1, 2: 3})
    assert learner.q_joint[js] == table
    assert learner.confidence[js] >= CONF_INIT
    assert len(learner.marked[0]) == 2


def test_cq_joint_update_bootstraps_from_q_local_of_the_next_cell():
    s = Settings(**GREEDY, window=5)
    learner = cq_with_conflict()
    learner.observe(1)
    learner.act({1: 1, 2: 3})  # marks (0, 1, 1) and (0, 2, 3)
    learner.learn(0.0, 0, False)
    learner._mark(1, {1: 2, 2: 4}, None)  # a joint state at the next cell too, with a large Q^j
    for js in learner.marked[1]:
        learner.q_joint[js] = [100.0] * 4
    learner.q_local[1] = [1.0, 2.0, 3.0, 4.0]
    need = learner.observe(0)
    assert need == (1, 2)
    action = learner.act({1: 1, 2: 3})
    js = learner.keys[0]
    assert js is not None and js[0] == 0 and action == EAST
    old = learner.q_joint[js][EAST]
    q_local_0 = list(learner.q_local[0])
    learner.learn(-1.0, 1, False)
    assert learner.q_joint[js][EAST] == pytest.approx(old + s.alpha * (-1.0 + s.gamma * 4.0 - old))
    assert learner.q_local[0] == q_local_0
    # and at the episode's end, no bootstrap at all
    learner.observe(0)
    learner.act({1: 1, 2: 3})
    js, old = learner.keys[0], learner.q_joint[learner.keys[0]][EAST]
    learner.learn(10.0, 1, True)
    assert learner.q_joint[js][EAST] == pytest.approx(old + s.alpha * (10.0 - old))


def test_cq_bootstrap_acted_waits_for_the_row_acted_on_next():
    """cq_bootstrap_acted=1: the update of a step is made at the next act, from the row acted on there
    (Q^j of the joint state met), so waiting in a joint state is valued by that joint state."""
    s = Settings(**GREEDY, window=5)
    learner = cq_with_conflict(cq_bootstrap_acted=1)  # its last update is pending
    learner.observe(0)
    learner.act({1: 1, 2: 3})  # marks (0, 1, 1) and (0, 2, 3) and meets one of them
    js = learner.keys[0]
    for row in learner.q_joint.values():  # in these joint states the best row value is -6
        row[:] = [-8.0, -6.0, -9.0, -7.0]
    learner.q_local[0] = [-100.0, 5.0, -100.0, -100.0]  # alone, the road is free: best is 5
    learner.learn(-1.0, 0, False)  # a wall bump: it stays at cell 0
    assert learner.q_joint[js] == [-8.0, -6.0, -9.0, -7.0]  # nothing applied yet
    learner.observe(0)
    learner.act({1: 1, 2: 3})  # the same joint state met again: the pending update uses its row
    assert learner.keys[0] == js
    # the act chose EAST on [-8, -6, -9, -7] after the update of EAST: -6 + 0.1 * (-1 + 0.9 * -6 + 6)
    assert learner.q_joint[js][EAST] == pytest.approx(-6.0 + s.alpha * (-1.0 + s.gamma * -6.0 + 6.0))
    # the paper's rule would have bootstrapped from Q_k's 5 and made waiting look good
    assert learner.q_joint[js][EAST] < -6.0


def test_cq_bootstrap_acted_applies_at_once_on_arrival_and_from_q_local_when_the_episode_is_cut():
    s = Settings(**GREEDY, window=5)
    learner = cq(cq_bootstrap_acted=1)
    learner.q_local[1] = [0.0, 3.0, 0.0, 0.0]
    step(learner, 0, ELSEWHERE, 10.0, 1, done=True)  # arrival: no bootstrap, no wait
    assert learner.q_local[0][EAST] == pytest.approx(5.0 + s.alpha * (10.0 - 5.0))
    before = learner.q_local[0][EAST]
    step(learner, 0, ELSEWHERE, -1.0, 1)  # pending ...
    assert learner.q_local[0][EAST] == before
    learner.end_episode()  # ... until the episode is cut: Q_k of the next cell, the only row known
    assert learner.q_local[0][EAST] == pytest.approx(before + s.alpha * (-1.0 + s.gamma * 3.0 - before))
    assert learner.waiting is None


def test_cq_all_met_acts_on_the_most_wary_of_the_joint_states_met_and_updates_each():
    s = Settings(**GREEDY, window=5)
    learner = cq_with_conflict(cq_all_met=1)
    learner.observe(0)
    learner.act({1: 1, 2: 3})  # marks and meets (0, 1, 1) and (0, 2, 3)
    learner.learn(0.0, 0, False)
    learner.q_joint[(0, 1, 1)][:] = [-5.0, 4.0, -5.0, 1.0]  # peer 1's joint state: EAST is fine
    learner.q_joint[(0, 2, 3)][:] = [-5.0, -9.0, -5.0, 0.0]  # peer 2's: EAST collides
    learner.confidence[(0, 1, 1)] = 9.0  # and peer 1's is the more confident
    learner.observe(0)
    assert learner.act({1: 1, 2: 3}) == WEST  # min of the rows: [-5, -9, -5, 0]
    assert learner.keys[0] == (0, 1, 1)  # the most confident is still the one named
    learner.learn(-1.0, 1, True)
    assert learner.q_joint[(0, 1, 1)][WEST] == pytest.approx(1.0 + s.alpha * (-1.0 - 1.0))
    assert learner.q_joint[(0, 2, 3)][WEST] == pytest.approx(0.0 + s.alpha * (-1.0 - 0.0))
    # the paper's reading: the most confident alone, blind to peer 2
    learner.__class__ = CQPaperLearner
    learner.observe(0)
    assert learner.act({1: 1, 2: 3}) == EAST


def test_cq_all_met_chooses_on_the_rows_after_the_waiting_update():
    """cq_bootstrap_acted with several joint states met: the last step's update lands in their rows first,
    and the action is chosen on their minimum as it stands then, as with a single row."""
    learner = cq_with_conflict(cq_all_met=1, cq_bootstrap_acted=1)
    learner.observe(0)
    learner.act({1: 1, 2: 3})  # marks and meets (0, 1, 1) and (0, 2, 3)
    for js in ((0, 1, 1), (0, 2, 3)):
        learner.q_joint[js][:] = [-5.0, 4.0, -5.0, 3.5]
    learner.a = EAST
    learner.learn(-10.0, 0, False)  # a collision: EAST's update waits, then lowers it to 2.96
    learner.observe(0)
    assert learner.act({1: 1, 2: 3}) == WEST  # not EAST, the best of the rows before the update
    assert learner.q_joint[(0, 1, 1)][EAST] == pytest.approx(4.0 + 0.1 * (-10.0 + 0.9 * 4.0 - 4.0))


def cq_marked_at_0(**overrides):
    """A greedy CQ learner with the joint states (0, 1, 1) and (0, 2, 3) marked from cell 1, now at cell 3."""
    learner = cq_with_conflict(**overrides)
    learner.observe(1)
    learner.act({1: 1, 2: 3})
    learner.learn(0.0, 2, False)
    learner.observe(2)
    learner.act({})
    learner.learn(0.0, 3, False)
    assert learner.watch == {0: (1, 2)}
    return learner


def test_cq_look_if_decisive_does_not_look_where_every_row_picks_the_same_action():
    learner = cq_marked_at_0(cq_look_if_decisive=1)
    learner.q_local[0] = [-100.0, 5.0, -100.0, -100.0]
    learner.q_joint[(0, 1, 1)][:] = [0.0, 3.0, -1.0, 2.0]  # EAST is best in every row
    learner.q_joint[(0, 2, 3)][:] = [-5.0, -4.0, -5.0, -9.0]
    confidence, plays, heard = dict(learner.confidence), learner.joint_plays, learner.heard
    assert learner.observe(0) == ()
    assert learner.act({}) == EAST and learner.keys[0] is None
    assert (learner.confidence, learner.joint_plays, learner.heard) == (confidence, plays, heard)  # no _meet
    joint = {js: list(row) for js, row in learner.q_joint.items()}
    learner.learn(-1.0, 1, False)  # the update goes to Q_k, as at an unmarked cell
    assert learner.q_local[0][EAST] == pytest.approx(5.0 + 0.1 * (-1.0 + 0.9 * max(learner.q_local[1]) - 5.0))
    assert learner.q_joint == joint
    # one row that disagrees, or ties, and it looks (and meets) as today
    for js, row in (((0, 2, 3), [-5.0, -4.0, -5.0, 0.0]), ((0, 1, 1), [0.0, 3.0, -1.0, 3.0])):
        before = list(learner.q_joint[js])
        learner.q_joint[js][:] = row
        assert learner.observe(0) == (1, 2)
        learner.act({1: 1, 2: 3})
        assert learner.keys[0] is not None and learner.heard == heard + 2
        learner.learn(0.0, 1, False)
        learner.q_joint[js][:] = before
        heard = learner.heard
    learner.q_local[0] = [0.0, 5.0, 0.0, 5.0]  # Q_k ties
    assert learner.observe(0) == (1, 2)
    learner.act({1: 1, 2: 3})
    learner.learn(0.0, 1, False)
    learner.q_local[0] = [-100.0, 5.0, -100.0, -100.0]
    assert learner.observe(0) == ()  # all agree again
    learner.act({})
    learner.learn(0.0, 1, False)
    learner.epsilon = 0.1  # not greedy: it looks
    assert learner.observe(0) == (1, 2)


def test_cq_look_if_decisive_off_always_looks_at_a_marked_cell():
    learner = cq_marked_at_0(cq_look_if_decisive=0)
    learner.q_local[0] = [-100.0, 5.0, -100.0, -100.0]
    for row in learner.q_joint.values():
        row[:] = [0.0, 3.0, -1.0, 2.0]
    for _ in range(3):
        assert learner.observe(0) == (1, 2)
        learner.act({1: 1, 2: 4})
        learner.learn(0.0, 1, False)


def test_cq_look_if_decisive_looks_when_a_waiting_update_lands_in_the_cell():
    """cq_bootstrap_acted: an agent that stayed in the cell has its last update waiting to land in one of the
    cell's rows, from the row it acts on now, which depends on looking: it looks."""
    learner = cq_marked_at_0(cq_look_if_decisive=1, cq_bootstrap_acted=1, cq_all_met=1)
    learner.q_local[0] = [-100.0, 5.0, -100.0, -100.0]
    for row in learner.q_joint.values():
        row[:] = [0.0, 3.0, -1.0, 2.0]
    learner.waiting = None
    assert learner.observe(0) == ()
    learner.act({})
    learner.learn(-1.0, 0, False)  # a wall bump: it stays at cell 0, the update waits
    assert learner.waiting is not None
    assert learner.observe(0) == (1, 2)
    learner.act({1: 1, 2: 3})
    learner.learn(0.0, 1, False)  # it moves on: the update waits for cell 1's row
    learner.observe(1)
    learner.act({})
    learner.learn(0.0, 0, False)  # and back, from cell 1: nothing waits in cell 0's rows
    assert learner.observe(0) == ()


@pytest.mark.parametrize("map_name", ["tunnel_to_goal", "grid_game_2"])
def test_cq_look_if_decisive_changes_no_greedy_action_of_a_frozen_copy(map_name):
    """A frozen greedy copy of a trained team plays the same steps with the rule as without, hearing less.
    (On these two runs, skipping a look where Q_k alone is decisive, whatever the Q^j say, changes the steps.)"""
    gm = load_map(map_name)
    settings = Settings(slip=0.1, eval_learning=0, step_cap=400)
    team = Team(GridWorld(gm, settings, seed=engine.world_seed(0, 0)), make_learners("cq", gm, settings, 0, 0))
    for _ in range(500):
        team.episode()
    assert any(learner.q_joint for learner in team.learners)
    played, heard = {}, {}
    for look in (0, 1):
        greedy = engine.greedy_team(team)
        for learner in greedy.learners:
            learner.__class__ = CQLearner if look else ours_without("look_if_decisive")
        actions, inner = [], greedy.choose
        greedy.choose = lambda: actions.append(tuple(inner())) or actions[-1]
        episodes = [greedy.episode() for _ in range(5)]
        played[look] = (actions, [(e.steps, e.collisions, e.ret, e.truncated) for e in episodes])
        heard[look] = (sum(learner.heard for learner in greedy.learners)
                       - sum(learner.heard for learner in team.learners))
    assert played[1] == played[0]
    assert 0 <= heard[1] < heard[0]


@pytest.mark.slow
def test_cq_look_if_decisive_run_is_reproducible():
    gm = load_map("tunnel_to_goal_3")
    on = Settings(slip=0.1, epsilon_decay_episodes=100, step_cap=400, eval_episodes=3)
    first = engine.run("cq", gm, on, seed=0, run_index=1, episodes=200)
    again = engine.run("cq", gm, on, seed=0, run_index=1, episodes=200)
    off = run_as(ours_without("look_if_decisive"), gm, on, 0, 1, 200)
    assert np.array_equal(first.episodes, again.episodes) and np.array_equal(first.greedy, again.greedy)
    assert first.joint_states == again.joint_states
    # the rule acts once epsilon is 0 (episode 100 on): fewer plays on joint states than without it
    assert np.array_equal(first.episodes[:100], off[:100])
    assert first.episodes["joint_plays"][100:].sum() < off["joint_plays"][100:].sum()


def test_cq_paper_marks_every_peer():
    learner = cq_with_conflict()
    learner.observe(0)
    learner.act({1: 2, 2: 5})
    assert set(learner.q_joint) == {(0, 1, 2), (0, 2, 5)}


def cq_conflict_at(cell, moved=False, **overrides):
    """A CQ learner that has just detected a conflict at `cell` moving EAST, having stayed there at every step
    (a collision) or, at the last one, moved on (no collision)."""
    learner = cq(**overrides)
    learner.q_local[cell] = [-100.0, 5.0, -100.0, -100.0]
    rewards = conflict_rewards()
    for k, r in enumerate(rewards, start=1):
        step(learner, cell, ELSEWHERE, r, cell + 1 if moved and k == len(rewards) else cell)
    assert conflict_at(learner) == cell and not learner.q_joint
    return learner


@pytest.mark.parametrize("colliders, marked", [(1, {(2, 1, 4), (2, 2, 1)}), (0, {(2, 1, 4), (2, 2, 1), (2, 2, 0)})])
def test_cq_mark_colliders_marks_only_the_peers_that_could_have_collided(colliders, marked):
    """At cell 2 moving EAST (toward cell 3), an agent that stayed can have collided with a peer within 1 cell of
    cell 3 (cell 4: both moved into 3) or of cell 2 (cell 1: the peer ran into it); not with one at cell 0, two
    cells behind it, which the paper marks too. Two peers, each met where one of them is."""
    found = set()
    for peer_cells in ({1: 4, 2: 1}, {1: 4, 2: 0}):
        learner = cq_conflict_at(2, cq_mark_colliders=colliders)
        learner.observe(2)
        learner.act(peer_cells)
        found |= set(learner.q_joint)
    assert found == marked


def test_cq_mark_colliders_marks_no_one_where_the_agent_moved():
    """A collision leaves the agent in its cell: a conflict found at a step it moved has no peer to blame."""
    for colliders, marked in ((1, set()), (0, {(0, 1, 2), (0, 2, 5)})):
        learner = cq_conflict_at(0, moved=True, cq_mark_colliders=colliders)
        assert learner.observe(1) == (1, 2)  # it must look at everyone to mark, as without the rule
        learner.act({1: 2, 2: 5})
        assert set(learner.q_joint) == marked and learner.watch == ({0: (1, 2)} if marked else {})


@pytest.mark.parametrize("algo", ["cq_paper", "cq"])
@pytest.mark.slow
def test_cq_greedy_deadlock_on_the_tunnel_is_the_papers(algo):
    """A regression test on the one run in ten (seed 0, run 6, 10,000 episodes) whose greedy policy the
    paper's CQ leaves stuck at the step cap on tunnel_to_goal; ours gets both agents home in the same run.
    Both halves are asserted, so the test shows it can tell the two apart."""
    gm = load_map("tunnel_to_goal")
    result = engine.run(algo, gm, Settings(eval_episodes=2, step_cap=300), seed=0, run_index=6, episodes=10_000)
    stuck = result.greedy["truncated"].any()
    assert stuck == (algo == "cq_paper")
    if not stuck:
        assert not result.greedy["collisions"].any() and result.greedy["steps"].max() <= 20


def test_cq_local_update_is_equation_3():
    s = Settings(**GREEDY, window=5)
    learner = cq()
    learner.q_local[1] = [0.0, 7.0, -1.0, 2.0]
    step(learner, 0, ELSEWHERE, -1.0, 1)
    assert learner.q_local[0][EAST] == pytest.approx(5.0 + s.alpha * (-1.0 + s.gamma * 7.0 - 5.0))


def test_cq_confidence_rises_on_a_match_up_to_conf_max():
    s = Settings()
    learner = cq_with_conflict()
    learner.observe(1)
    learner.act({1: 1, 2: 3})
    learner.learn(0.0, 0, False)
    js = (0, 1, 1)
    seen = [learner.confidence[js]]
    for _ in range(30):
        step(learner, 0, {1: 1, 2: 4}, 0.0, 1)  # peer 1 where marked; peer 2 elsewhere
        seen.append(learner.confidence[js])
    assert seen[1] == pytest.approx(CONF_INIT + s.conf_up)
    assert all(b >= a for a, b in zip(seen, seen[1:]))
    assert max(seen) == s.conf_max and seen[-1] == s.conf_max
    # peer 2's joint state lost confidence on each of those visits
    assert learner.confidence[(0, 2, 3)] == pytest.approx(CONF_INIT - 30 * s.conf_down)


def test_cq_confidence_falls_and_the_joint_state_is_dropped():
    learner = cq_with_conflict(conf_down=0.4)
    learner.observe(1)
    learner.act({1: 1, 2: 3})
    learner.learn(0.0, 0, False)
    assert learner.observe(0) == (1, 2)
    learner.act({1: 2, 2: 3})  # peer 2 matches, peer 1 does not
    learner.learn(0.0, 1, False)
    assert learner.confidence[(0, 1, 1)] == pytest.approx(0.6)
    for _ in range(2):
        step(learner, 0, {1: 2, 2: 3}, 0.0, 1)
    # 1.0 - 3 * 0.4 < CONF_DROP = 0: peer 1's joint state is gone; peer 2 is still watched
    assert (0, 1, 1) not in learner.q_joint and (0, 1, 1) not in learner.confidence
    assert learner.marked == {0: [(0, 2, 3)]}
    assert learner.confidence[(0, 2, 3)] == pytest.approx(2.5)  # three matches
    for miss in range(1, 8):  # peer 2 elsewhere now: 2.5 - 7 * 0.4 < 0
        assert (0, 2, 3) in learner.q_joint
        assert learner.observe(0) == (2,)
        learner.act({2: 0})
        learner.learn(0.0, 1, False)
        assert (miss < 7) == ((0, 2, 3) in learner.q_joint)
    assert learner.q_joint == {} and learner.marked == {} and learner.watch == {}
    assert learner.observe(0) == ()  # nobody is watched any more
    assert learner.state_count() == ROW3.n_cells


def test_cq_update_of_a_joint_state_forgotten_while_it_waits_is_dropped():
    """cq_bootstrap_acted: a step acted on Q^j waits for the next act, and that act forgets the joint state (its
    peer is elsewhere, its confidence falls below CONF_DROP). The update has no row to land in: it is dropped
    and counted, and neither Q_k nor the other Q^j learns it in its place."""
    learner = cq_with_conflict(cq_bootstrap_acted=1, conf_down=2.0)
    learner.observe(0)
    learner.act({1: 1, 2: 3})  # marks and meets (0, 1, 1) and (0, 2, 3): confidence 1.5 each
    assert learner.keys == [(0, 1, 1)]  # the first marked among equals (cq_all_met=0)
    learner.learn(-10.0, 0, False)  # it stays at cell 0; the update of (0, 1, 1) waits
    assert learner.waiting.keys == [(0, 1, 1)]
    forgotten = learner.q_joint[(0, 1, 1)]
    before = [list(forgotten), [list(row) for row in learner.q_local], list(learner.q_joint[(0, 2, 3)])]
    assert learner.observe(0) == (1, 2)
    learner.act({1: 2, 2: 3})  # peer 1 is elsewhere: 1.5 - 2.0 < 0, (0, 1, 1) is forgotten; (0, 2, 3) is met
    assert (0, 1, 1) not in learner.q_joint and learner.keys == [(0, 2, 3)]
    assert learner.waiting is None and learner.dropped_updates == 1
    assert [list(forgotten), [list(row) for row in learner.q_local], list(learner.q_joint[(0, 2, 3)])] == before


def test_cq_joint_plays_counts_acting_from_q_joint():
    learner = cq_with_conflict()
    learner.observe(1)
    learner.act({1: 1, 2: 3})
    learner.learn(0.0, 0, False)
    plays = []
    for peers in [{1: 1, 2: 4}, {1: 2, 2: 4}, {1: 2, 2: 3}, {1: 1, 2: 3}, {1: 0, 2: 2}]:
        before = learner.joint_plays
        step(learner, 0, peers, 0.0, 1)
        plays.append(learner.joint_plays - before)
        assert plays[-1] == (learner.keys[0] is not None)
    assert plays == [1, 0, 1, 1, 0]
    before = learner.joint_plays
    step(learner, 2, ELSEWHERE, 0.0, 3)  # a cell without joint states
    assert learner.joint_plays == before


def test_cq_end_episode_clears_a_pending_conflict():
    learner = cq_with_conflict()
    learner.end_episode()
    assert conflict_at(learner) is None
    assert learner.observe(0) == ()
    learner.act({})
    assert learner.q_joint == {} and learner.marked == {}


def test_cq_constant_non_integer_reward_never_marks():
    """A step cost of -0.1 on every step of one (state, action): its rewards never change, so no conflict."""
    learner = cq(window=60)
    for _ in range(1000):
        step(learner, 0, ELSEWHERE, -0.1, 1)
        assert conflict_at(learner) is None
    assert learner.q_joint == {}


def never_asks_before_its_first_conflict(seed: int) -> bool:
    """Play 60 episodes of CQ on tunnel_to_goal; check that no agent asks for a peer before it has met a
    conflict. Returns whether the run met one (and then the agents did look at each other)."""
    gm = load_map("tunnel_to_goal")
    settings = Settings(window=10, step_cap=400)
    learners = make_learners("cq", gm, settings, seed=seed, run=0)
    calls = []  # (episode, had a joint state or a pending conflict, what observe returned)
    episode = 0

    def spy(learner):
        inner = learner.observe

        def observe(cell):
            informed = bool(learner.marked) or conflict_at(learner) is not None
            need = inner(cell)
            calls.append((episode, informed, need))
            return need

        learner.observe = observe

    for learner in learners:
        spy(learner)
    team = Team(GridWorld(gm, settings), learners)
    for episode in range(60):
        team.episode()
    # an agent with nothing marked (and no conflict pending) asks for no one
    assert all(need == () for _, informed, need in calls if not informed)
    informed = [e for e, informed, _ in calls if informed]
    if not informed:
        assert not any(learner.q_joint for learner in learners)
        return False
    assert all(need == () for e, _, need in calls if e < min(informed))
    assert any(need for _, _, need in calls)
    return True


def test_cq_never_asks_for_peers_before_its_first_conflict():
    # whatever the seed; some runs meet no conflict within 60 episodes (their first windows already hold
    # collisions), so several seeds, and at least one must meet a conflict for the test to say anything
    met = [never_asks_before_its_first_conflict(seed) for seed in range(4)]
    assert any(met), met


def test_cq_acts_on_the_most_confident_of_several_joint_states_met_at_once_with_cq_all_met_0():
    learner = cq_with_conflict(cq_all_met=0)
    learner.observe(1)
    learner.act({1: 1, 2: 3})  # marks (0, 1, 1) and (0, 2, 3)
    learner.learn(0.0, 0, False)
    learner.q_joint[(0, 1, 1)] = [0.0, 0.0, 9.0, 0.0]  # greedy: SOUTH
    learner.q_joint[(0, 2, 3)] = [0.0, 0.0, 0.0, 9.0]  # greedy: WEST
    for confident, action in (((0, 1, 1), SOUTH), ((0, 2, 3), WEST)):
        other = (0, 2, 3) if confident == (0, 1, 1) else (0, 1, 1)
        learner.confidence[confident], learner.confidence[other] = 6.0, 3.0
        assert step(learner, 0, {1: 1, 2: 3}, 0.0, 1) == ((1, 2), action)  # both met at once
        assert learner.keys[0] == confident


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_exploration_draws_every_action_alike(algo):
    """At epsilon 1 every decision is exploratory: over many draws each action (LoC: each move and
    COORDINATE; JSA: each joint action) comes up equally often (chi-square goodness of fit)."""
    gm = load_map("tunnel_to_goal")
    settings = Settings(epsilon=1.0)
    team = Team(GridWorld(gm, settings), make_learners(algo, gm, settings, seed=11, run=0))
    learner = team.learners[0]
    n_actions = N_MOVES + 1 if algo == "loc" else N_MOVES ** gm.n_agents if algo == "jsa" else N_MOVES
    counts = np.zeros(n_actions)
    for _ in range(400 * n_actions):
        team.start()  # observe the start again: every draw is a first step's
        team.choose()
        counts[learner.choice if algo == "loc" else learner.a] += 1
    assert counts.min() > 0, counts
    assert scipy.stats.chisquare(counts).pvalue > 1e-3, counts


def test_epsilon_falls_to_zero_on_its_schedule_and_never_rises():
    gm = load_map("tunnel_to_goal")
    for algo in ALGORITHMS:
        learner = make_learner(algo, gm, Settings(epsilon=0.2, epsilon_decay_episodes=4), seed=1, run=0, agent=0)
        seen = [learner.epsilon]
        for _ in range(6):
            learner.end_episode()
            seen.append(learner.epsilon)
        assert seen == pytest.approx([0.2, 0.15, 0.1, 0.05, 0.0, 0.0, 0.0]), algo
        fixed = make_learner(algo, gm, Settings(epsilon=0.2), seed=1, run=0, agent=0)
        fixed.end_episode()
        assert fixed.epsilon == 0.2
    greedy = make_learner("cq", gm, Settings(epsilon_decay_episodes=100), seed=1, run=0, agent=0)
    greedy.epsilon = 0.0  # a greedy copy stays greedy
    greedy.end_episode()
    assert greedy.epsilon == 0.0


@pytest.mark.parametrize("seed", range(5))
def test_cq_learns_to_reach_both_goals_without_collision(seed):
    """End to end: after 1000 episodes on tunnel_to_goal, CQ's greedy policy brings both agents to their
    goal every time, with no collision and no episode running to the step cap."""
    result = engine.run("cq", load_map("tunnel_to_goal"), Settings(), seed, 0, 1000)
    steps, collisions, truncated = (result.greedy[c] for c in ("steps", "collisions", "truncated"))
    assert collisions.sum() == 0 and truncated.sum() == 0
    assert steps.max() <= 20  # the shortest is 12 steps for the second agent through the tunnel


# --- Indep -----------------------------------------------------------------------------------------


def test_indep_update_is_equation_3():
    s = Settings(**GREEDY)
    learner = IndependentQ(0, ROW2, s, seed=0)
    learner.q_local[2] = [1.0, 2.0, 0.0, 0.0]
    learner.q_local[3] = [0.5, 3.0, -1.0, 0.0]
    assert learner.observe(2) == ()
    assert learner.act({}) == EAST
    learner.learn(-1.0, 3, False)
    # Q(s,a) <- Q(s,a) + alpha [r + gamma max_a' Q(s',a') - Q(s,a)]
    assert learner.q_local[2][EAST] == pytest.approx(2.0 + 0.1 * (-1.0 + 0.9 * 3.0 - 2.0))
    assert learner.q_local[2][NORTH] == 1.0 and learner.q_local[3] == [0.5, 3.0, -1.0, 0.0]


def test_indep_terminal_step_does_not_bootstrap():
    learner = IndependentQ(0, ROW2, Settings(**GREEDY), seed=0)
    learner.q_local[4] = [0.0, 2.0, 0.0, 0.0]
    learner.q_local[5] = [50.0] * 4
    learner.observe(4)
    learner.act({})
    learner.learn(10.0, 5, True)
    assert learner.q_local[4][EAST] == pytest.approx(2.0 + 0.1 * (10.0 - 2.0))
    assert learner.state_count() == ROW2.n_cells and learner.joint_plays == 0


# --- JS --------------------------------------------------------------------------------------------


def test_js_observes_all_peers_every_step():
    learners = make_learners("js", ROW3, Settings(step_cap=50), seed=1, run=0)
    seen = []

    def spy(learner):
        inner = learner.observe

        def observe(cell):
            need = inner(cell)
            seen.append((learner.peers, need))
            return need

        learner.observe = observe

    for learner in learners:
        spy(learner)
    Team(GridWorld(ROW3, Settings(step_cap=50)), learners).episode()
    assert len(seen) > 10
    assert all(peers == need and len(need) == 2 for peers, need in seen)


def test_js_update_is_deferred_to_the_next_joint_state():
    s = Settings(**GREEDY)
    learner = JointStateQ(0, ROW2, s, seed=0)
    assert learner.observe(0) == (1,)
    a = learner.act({1: 5})
    assert learner.joint_plays == 1
    learner.learn(-1.0, 1, False)
    assert learner.q_joint[(0, 5)] == [0.0] * 4  # nothing learned yet: the next joint state is unknown
    learner.q_joint[(1, 4)] = [0.0, 5.0, 0.0, 0.0]
    learner.q_joint[(1, 5)] = [0.0, 99.0, 0.0, 0.0]  # not where the peer turns out to be
    learner.observe(1)
    learner.act({1: 4})
    assert learner.q_joint[(0, 5)][a] == pytest.approx(0.1 * (-1.0 + 0.9 * 5.0))
    assert sum(learner.q_joint[(0, 5)]) == pytest.approx(0.1 * (-1.0 + 0.9 * 5.0))


def test_js_done_does_not_bootstrap_and_is_applied_at_once():
    learner = JointStateQ(0, ROW2, Settings(**GREEDY), seed=0)
    learner.q_joint[(4, 0)] = [0.0, 3.0, 0.0, 0.0]
    learner.observe(4)
    assert learner.act({1: 0}) == EAST
    learner.learn(10.0, 5, True)
    assert learner.q_joint[(4, 0)][EAST] == pytest.approx(3.0 + 0.1 * (10.0 - 3.0))
    assert learner.waiting is None


def test_js_end_episode_drops_a_pending_update():
    learner = JointStateQ(0, ROW2, Settings(**GREEDY), seed=0)
    learner.q_joint[(2, 5)] = [0.0, 1.0, 0.0, 0.0]
    learner.observe(2)
    learner.act({1: 5})
    learner.learn(-10.0, 3, False)
    assert learner.waiting is not None
    learner.end_episode()
    assert learner.waiting is None
    learner.observe(0)  # the next episode starts elsewhere
    learner.act({1: 5})
    assert learner.q_joint[(2, 5)] == [0.0, 1.0, 0.0, 0.0]


# --- JSA -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_jsa_decode_joint_action_round_trip(n):
    seen = set()
    for action in range(N_MOVES ** n):
        moves = decode_joint_action(action, n)
        assert len(moves) == n and all(0 <= m < N_MOVES for m in moves)
        assert sum(m * N_MOVES ** i for i, m in enumerate(moves)) == action
        seen.add(tuple(moves))
    assert len(seen) == N_MOVES ** n
    assert decode_joint_action(EAST + N_MOVES * WEST, 2) == [EAST, WEST]


def test_jsa_learns_from_the_sum_of_rewards():
    gm = load_map("grid_game_2")
    settings = Settings(step_cap=200)
    (learner,) = make_learners("jsa", gm, settings, seed=2, run=0)
    assert isinstance(learner, JointStateActionQ) and learner.central
    world = GridWorld(gm, settings)
    team = Team(world, [learner])
    fed, stepped = [], []
    inner_learn, inner_step = learner.learn, world.step_joint

    def learn(reward, cells, done):
        fed.append((reward, cells, done))
        inner_learn(reward, cells, done)

    def step_joint(actions):
        stepped.append(inner_step(actions))
        return stepped[-1]

    learner.learn, world.step_joint = learn, step_joint
    for _ in range(5):
        team.episode()
    assert len(fed) == len(stepped) > 0
    for (reward, cells, done), rewards in zip(fed, stepped):
        assert reward == sum(rewards)
        assert isinstance(cells, tuple) and len(cells) == 2
    assert any(reward != rewards[0] for (reward, _, _), rewards in zip(fed, stepped))


def test_jsa_update_by_hand():
    s = Settings(**GREEDY)
    learner = JointStateActionQ(0, ROW2, s, seed=0)
    assert learner.n_joint == 16
    learner.q_joint[(0, 5)] = [0.0] * 16
    learner.q_joint[(0, 5)][EAST + 4 * WEST] = 1.0
    learner.q_joint[(1, 4)] = [0.0] * 16
    learner.q_joint[(1, 4)][3] = 6.0
    assert learner.observe((0, 5)) == ()
    a = learner.act({})
    assert decode_joint_action(a, 2) == [EAST, WEST]
    learner.learn(-2.0, (1, 4), False)
    assert learner.q_joint[(0, 5)][a] == pytest.approx(1.0 + 0.1 * (-2.0 + 0.9 * 6.0 - 1.0))
    learner.observe((1, 4))
    a = learner.act({})
    learner.learn(20.0, (5, 0), True)
    assert learner.q_joint[(1, 4)][a] == pytest.approx(6.0 + 0.1 * (20.0 - 6.0))


def test_jsa_refuses_too_many_agents():
    agents = [((0, c), (1, c)) for c in range(MAX_AGENTS + 1)]
    gm = make_map(MAX_AGENTS + 1, *agents, height=2)
    with pytest.raises(ValueError, match=rf"at most {MAX_AGENTS} agents.*{MAX_AGENTS + 1}"):
        make_learners("jsa", gm, Settings(), seed=0, run=0)
    ok = make_map(MAX_AGENTS, *agents[:MAX_AGENTS], height=2)
    assert make_learners("jsa", ok, Settings(), seed=0, run=0)[0].n_joint == 4 ** MAX_AGENTS


# --- LoC -------------------------------------------------------------------------------------------


def loc(**overrides):
    s = Settings(**{**GREEDY, **overrides})
    learner = LearningOfCoordination(0, ROW3, s, seed=0)
    return learner, s


def test_loc_coordinate_asks_for_all_peers_and_acts_on_q_c_when_a_peer_is_near():
    learner, s = loc()
    learner.q_local[1] = [0.0, 1.0, 0.0, -1.0, 5.0]  # COORDINATE best; Q*'s best move EAST
    learner.q_local[2] = [0.0, 0.0, 3.0, 0.0, 4.0]
    assert learner.observe(1) == (1, 2)
    move = learner.act({1: 3, 2: 5})  # peer 1 two cells away (within COLLISION_REACH, 2); peer 2 four
    assert move == EAST and learner.joint_plays == 1
    x = (1, ((1, 3),))
    assert learner.x == x
    assert learner.q_coord[x] == [0.0, 1.0, 0.0, -1.0]  # a copy of Q*'s moves
    assert learner.q_coord[x] is not learner.q_local[1]
    learner.learn(-1.0, 2, False)
    future = s.gamma * 4.0  # bootstrap from Q* of the next cell (max over all its actions)
    assert learner.q_coord[x][EAST] == pytest.approx(1.0 + s.alpha * (-1.0 + future - 1.0))
    assert learner.q_local[1][EAST] == pytest.approx(1.0 + s.alpha * (-1.0 + future - 1.0))
    assert learner.q_local[1][COORDINATE] == pytest.approx(5.0 + s.alpha * (-1.0 - s.loc_cost + future - 5.0))
    # next time in the same perceived joint state it follows Q^C, not Q*
    learner.q_coord[x] = [0.0, 0.0, 0.0, 9.0]
    learner.observe(1)
    assert learner.act({1: 3, 2: 5}) == WEST
    assert learner.joint_plays == 2


def test_loc_coordinate_out_of_range_acts_on_q_star():
    learner, s = loc()
    learner.q_local[0] = [0.0, 0.0, 2.0, 0.0, 5.0]
    assert learner.observe(0) == (1, 2)
    move = learner.act({1: 3, 2: 5})  # nobody within 2 cells
    assert move == SOUTH and learner.x is None and learner.joint_plays == 1
    learner.learn(-1.0, 0, False)
    assert learner.q_coord == {}
    future = s.gamma * 5.0
    assert learner.q_local[0][SOUTH] == pytest.approx(2.0 + s.alpha * (-1.0 + future - 2.0))
    assert learner.q_local[0][COORDINATE] == pytest.approx(5.0 + s.alpha * (-1.0 - s.loc_cost + future - 5.0))


def test_loc_plain_move_sees_no_one_and_learns_only_that_move():
    learner, s = loc()
    learner.q_local[2] = [0.0, 0.0, 0.0, 3.0, 1.0]
    learner.q_local[1] = [2.0, 0.0, 0.0, 0.0, 0.0]
    assert learner.observe(2) == ()
    assert learner.act({}) == WEST and learner.joint_plays == 0
    learner.learn(-1.0, 1, False)
    assert learner.q_local[2] == pytest.approx([0.0, 0.0, 0.0, 3.0 + s.alpha * (-1.0 + s.gamma * 2.0 - 3.0), 1.0])
    assert learner.q_coord == {}


def test_loc_terminal_step_does_not_bootstrap():
    learner, s = loc()
    learner.q_local[4] = [0.0, 0.0, 0.0, 0.0, 1.0]
    learner.q_local[5] = [50.0] * 5
    learner.observe(4)
    learner.act({1: 3, 2: 5})  # peer 1 adjacent
    learner.learn(10.0, 5, True)
    x = learner.x
    assert x is not None
    assert learner.q_coord[x][learner.move] == pytest.approx(s.alpha * 10.0)
    assert learner.q_local[4][COORDINATE] == pytest.approx(1.0 + s.alpha * (10.0 - s.loc_cost - 1.0))


# --- all learners ----------------------------------------------------------------------------------


def play(learners, gridmap, settings, episodes):
    """Run a team; return every joint action chosen and the per-episode records."""
    world = GridWorld(gridmap, settings)
    team = Team(world, learners)
    actions = []
    inner = team.choose

    def choose():
        chosen = inner()
        actions.append(tuple(chosen))
        return chosen

    team.choose = choose
    records = [team.episode() for _ in range(episodes)]
    return actions, records


SMALL = Settings(window=10, step_cap=300)


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_same_seed_same_actions(algo):
    gm = load_map("grid_game_2")
    a, ra = play(make_learners(algo, gm, SMALL, seed=7, run=1), gm, SMALL, 15)
    b, rb = play(make_learners(algo, gm, SMALL, seed=7, run=1), gm, SMALL, 15)
    c, _ = play(make_learners(algo, gm, SMALL, seed=8, run=1), gm, SMALL, 15)
    d, _ = play(make_learners(algo, gm, SMALL, seed=7, run=2), gm, SMALL, 15)
    assert a == b and ra == rb
    assert a != c and a != d


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_pickle_round_trip_preserves_behaviour(algo):
    gm = load_map("tunnel_to_goal")
    learners = make_learners(algo, gm, SMALL, seed=4, run=0)
    play(learners, gm, SMALL, 10)
    copies = pickle.loads(pickle.dumps(learners))
    assert [type(c) for c in copies] == [type(learner) for learner in learners]
    a, ra = play(learners, gm, SMALL, 10)
    b, rb = play(copies, gm, SMALL, 10)
    assert a == b and ra == rb
    assert pickle.dumps(learners) == pickle.dumps(copies)  # same tables, same rng state afterwards


def test_pickled_cq_keeps_its_joint_states():
    learner = cq_with_conflict()
    learner.observe(0)
    learner.act({1: 1, 2: 3})
    learner.learn(-1.0, 1, False)
    copy = pickle.loads(pickle.dumps(learner))
    assert copy.q_joint == learner.q_joint and copy.confidence == learner.confidence
    assert copy.marked == learner.marked and copy.watch == learner.watch
    assert copy.observe(0) == learner.observe(0) == (1, 2)
    assert copy.act({1: 1, 2: 3}) == learner.act({1: 1, 2: 3})
    assert copy.keys == learner.keys


def test_learners_draw_only_from_their_own_rng():
    gm = load_map("grid_game_2")
    a, _ = play(make_learners("cq", gm, SMALL, seed=1, run=0), gm, SMALL, 5)
    random.seed(12345)
    np.random.seed(6789)
    b, _ = play(make_learners("cq", gm, SMALL, seed=1, run=0), gm, SMALL, 5)
    assert a == b


# --- engine ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_engine_run_is_reproducible(algo):
    gm = load_map("grid_game_2")
    first = engine.run(algo, gm, SMALL, seed=3, run_index=0, episodes=20)
    again = engine.run(algo, gm, SMALL, seed=3, run_index=0, episodes=20)
    other = engine.run(algo, gm, SMALL, seed=4, run_index=0, episodes=20)
    assert first.episodes.shape == (20,) and first.episodes.dtype.names == COLUMNS
    assert np.array_equal(first.episodes, again.episodes)
    assert first.joint_states == again.joint_states
    assert not np.array_equal(first.episodes, other.episodes)


@pytest.mark.parametrize("eval_learning", [0, 1])
def test_engine_run_plays_its_greedy_episodes_on_its_own_team_as_a_copy_would(eval_learning, monkeypatch):
    """run is done with its team once the greedy episodes come: they play on the team itself (no copy: a copy
    of a CQ team holds every reward window again) and give what a copy of the team gives."""
    gm = load_map("grid_game_2")
    settings = SMALL.with_overrides({"eval_episodes": 3, "eval_learning": eval_learning})
    team = Team(GridWorld(gm, settings, seed=engine.world_seed(3, 0)), make_learners("cq", gm, settings, 3, 0))
    for _ in range(30):
        team.episode()
    copied = engine.greedy_episodes(team, 3)

    def refused(*_):
        raise AssertionError("engine.run copied its team")

    with monkeypatch.context() as patch:
        patch.setattr(engine.copy, "deepcopy", refused)
        played = engine.run("cq", gm, settings, 3, 0, 30)
    assert played.greedy.tobytes() == copied.tobytes()
    assert engine.run("cq", gm, SMALL.with_overrides({"eval_episodes": 0}), 3, 0, 5).greedy.shape == (0,)


def test_make_learners_unknown_algorithm_names_the_algorithms():
    with pytest.raises(ValueError) as info:
        make_learners("dqn", load_map("grid_game_2"), Settings(), seed=0, run=0)
    msg = str(info.value)
    assert "dqn" in msg
    for name in ("indep", "js", "jsa", "loc", "cq"):
        assert name in msg
    with pytest.raises(ValueError, match="cq"):
        make_learner("nope", load_map("grid_game_2"), Settings(), seed=0, run=0, agent=0)


def test_make_learners_one_per_agent_or_one_central():
    gm = load_map("tunnel_to_goal")
    assert set(ALGORITHMS) == {"indep", "js", "jsa", "loc", "cq_paper"}
    for algo in ALGORITHMS:
        learners = make_learners(algo, gm, Settings(), seed=0, run=0)
        assert all(isinstance(learner, LEARNERS[algo]) for learner in learners)
        assert [learner.agent for learner in learners] == ([0] if algo == "jsa" else [0, 1])


# --- near: every peer in range, every step ------------------------------------------------------------


def test_near_conditions_on_the_peers_in_range_only_and_hears_only_them():
    learner = NearQ(0, ROW3, Settings(**GREEDY), seed=1)
    assert learner.observe(0) == (1, 2)  # it must know where everyone is to know who is near
    learner.act({1: 2, 2: 5})  # agent 1 is 2 cells away, agent 2 five
    assert learner.heard == 1 and learner.joint_plays == 1
    assert list(learner.q_near) == [(0, ((1, 2),))]
    learner.learn(-1.0, 1, False)
    learner.observe(1)
    learner.act({1: 4, 2: 5})  # nobody within 2 of cell 1: the cell's own row
    assert learner.heard == 1 and learner.joint_plays == 1 and learner.state_count() == ROW3.n_cells + 1


def test_near_finishes_a_steps_update_from_the_next_state_it_sees():
    learner = NearQ(0, ROW3, Settings(**GREEDY, alpha=1.0, gamma=0.5), seed=1)
    learner.observe(0)
    a = learner.act({1: 1, 2: 5})
    row = learner.q_near[(0, ((1, 1),))]
    learner.learn(-10.0, 0, False)
    assert row[a] == 0.0  # waiting for the next state
    learner.q_local[0] = [4.0, 4.0, 4.0, 4.0]
    learner.observe(0)
    learner.act({1: 4, 2: 5})  # the next state: nobody near, Q of the cell
    assert row[a] == -10.0 + 0.5 * 4.0


# --- CQ's W1 under delays --------------------------------------------------------------------------------


def test_cq_w1_alone_holds_what_acting_alone_earns_a_share_slip_delayed():
    st = dict(GREEDY, window=10, slip=0.2, reward_step=-1.0, reward_wall=-2.0, reward_goal=7.0)
    learner = with_rules("w1_alone")(0, ROW2, Settings(**st), seed=1)
    west_of_0, east_of_0, into_goal = learner.windows[0 * 4 + WEST], learner.windows[0 * 4 + EAST], \
        learner.windows[4 * 4 + EAST]
    assert all(w.n1 == 10 for w in learner.windows)  # W1 full from the start
    assert west_of_0.sum1 == 2 * -1.0 + 8 * -2.0  # a bump, 2 of 10 delayed
    assert east_of_0.sum1 == 10 * -1.0
    assert into_goal.sum1 == 2 * -1.0 + 8 * 7.0  # cell 4 -> 5, agent 0's goal
    plain = CQPaperLearner(0, ROW2, Settings(**st), seed=1)
    assert all(w.n1 == 0 for w in plain.windows)


def test_cq_w1_alone_marks_a_conflict_that_was_there_from_the_start():
    """A collision one step in three from the first episode on: W1 of the first rewards holds it too, so the
    rewards never drop against it; against acting alone they have."""
    marked = {}
    for alone in (0, 1):
        learner = cq(ROW3, window=10, cq_w1_alone=alone)
        for k in range(60):
            step(learner, 0, ELSEWHERE if k % 3 else {1: 1, 2: 5}, -10.0 if k % 3 == 0 else 0.0, 0 if k % 3 == 0 else 1)
        marked[alone] = bool(learner.q_joint)
    assert marked == {0: False, 1: True}


# --- CQ's new joint states: waits valued afresh (cq_waits_fresh) -------------------------------------------


@pytest.mark.parametrize("fresh", [0, 1])
def test_cq_waits_fresh_values_a_new_joint_states_waits_at_least_a_step_lost_plus_the_free_road(fresh):
    """Cell 0 of the row has walls north, south and west: those three moves are waits."""
    learner = cq_with_conflict(cq_waits_fresh=fresh, gamma=0.9, reward_wall=-1.0)
    q_k = [-27.6, -7.2, 3.0, -100.0]  # waits left low by early exploration, the best of them above the floor
    learner.q_local[0] = list(q_k)
    learner.observe(2)
    learner.act({1: 1, 2: 3})  # marks (0, 1, 1) and (0, 2, 3)
    floor = -1.0 + 0.9 * 3.0
    expected = [floor, -7.2, 3.0, floor] if fresh else q_k
    assert set(learner.q_joint) == {(0, 1, 1), (0, 2, 3)}
    for row in learner.q_joint.values():
        assert row == pytest.approx(expected)
    assert learner.q_local[0] == q_k  # Q_k itself is left as it was


def test_cq_waits_fresh_a_new_joint_states_waits_are_never_below_the_floor():
    gm = make_map(3, ((0, 0), (1, 2)), ((1, 2), (0, 0)), height=2)
    rng = random.Random(5)
    for _ in range(200):
        learner = with_rules("waits_fresh")(0, gm, Settings(gamma=0.9, reward_wall=-2.0), seed=1)
        s = rng.randrange(gm.n_cells)
        q_k = [rng.uniform(-30.0, 10.0) for _ in range(N_MOVES)]
        learner.q_local[s] = list(q_k)
        (js,) = learner._mark(s, {1: rng.randrange(gm.n_cells)}, None)
        floor = -2.0 + 0.9 * max(q_k)
        for a, to in enumerate(gm.neighbours[s]):
            row = learner.q_joint[js]
            assert row[a] == (max(q_k[a], floor) if to == s else q_k[a])


# --- heard: the peer positions counted per episode, in the result files ------------------------------------


@pytest.mark.parametrize("algo", sorted(LEARNERS))
def test_heard_per_episode_in_episodes_and_greedy_csv_is_what_the_learners_counted(algo, tmp_path, monkeypatch):
    from cq_ros.lab.results import load_episodes, write_results

    gm = load_map("tunnel_to_goal")
    settings = Settings(window=10, step_cap=300, eval_episodes=3)
    counted = []  # what the learners counted over each episode, learning and greedy
    played = Team.episode

    def episode(team, *args, **kwargs):
        before = sum(learner.heard for learner in team.learners)
        result = played(team, *args, **kwargs)
        counted.append(sum(learner.heard for learner in team.learners) - before)
        return result

    monkeypatch.setattr(Team, "episode", episode)
    result = engine.run(algo, gm, settings, seed=3, run_index=0, episodes=20)
    write_results(tmp_path, gm, [result], {})
    files = [load_episodes(tmp_path / name)[(gm.name, algo)]["heard"][0] for name in ("episodes.csv", "greedy.csv")]
    assert [*files[0], *files[1]] == counted
    if algo == "indep":
        assert sum(counted) == 0  # it never looks


# --- the greedy evaluation: learning or frozen (eval_learning) --------------------------------------------

KEPT = ("q_local", "q_joint", "q_coord", "q_near", "confidence", "marked", "watch", "windows", "waiting")


def kept(learner) -> bytes:
    """Everything a learner keeps from step to step but its rng and counters."""
    return pickle.dumps({k: v for k, v in vars(learner).items() if k in KEPT})


@pytest.mark.parametrize("algo", sorted(LEARNERS))
@pytest.mark.parametrize("eval_learning", [0, 1])
def test_a_frozen_greedy_copy_only_acts_and_a_learning_one_learns(algo, eval_learning):
    gm = load_map("tunnel_to_goal")
    settings = Settings(window=10, step_cap=300, eval_learning=eval_learning)
    team = Team(GridWorld(gm, settings, seed=0), make_learners(algo, gm, settings, seed=4, run=0))
    for _ in range(150):
        team.episode()
    trained = [kept(learner) for learner in team.learners]
    greedy = engine.greedy_team(team)
    assert all(learner.epsilon == 0.0 for learner in greedy.learners)
    played = [greedy.episode() for _ in range(3)]
    assert [kept(learner) for learner in team.learners] == trained  # the run itself is never touched
    after = [kept(learner) for learner in greedy.learners]
    assert (after == trained) == (eval_learning == 0)
    if eval_learning == 0:
        assert len({e.states for e in played}) == 1  # a frozen LoC, near or CQ makes no joint state, drops none
        if algo == "cq":
            assert sum(e.joint_plays for e in played) > 0  # it acted on its joint states, without touching them

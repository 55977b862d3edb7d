"""The agent drivers without ROS: which peers they listen to and when, when they act, what they refuse,
checkpoints, the greedy episodes after the learning ones, and a whole lockstep run (world core + drivers,
messages in any cross-topic order) that equals cq_ros.engine.run, greedy episodes included."""

from __future__ import annotations

import math
import os
import random
from collections import defaultdict, deque

import numpy as np
import pytest

from agent_node.checkpoint import load_checkpoint, save_checkpoint
from agent_node.config import agent_config, make_driver
from agent_node.driver import AgentDriver, CentralDriver
from agent_node.effects import Finish, Renew, SaveCheckpoint, Send, Subscribe, Unsubscribe
from agent_node.peer_view import RENEW_AFTER_S
from agent_node.wire_reading import feedback_in, heartbeat_in, position_in
from cq_ros.engine import make_learner, run, world_seed
from cq_ros.gridmap import load_map, parse_map
from cq_ros.learners.base import Learner
from node_runtime.parameters import SETTING_NAMES
from cq_ros.settings import Settings, SettingsError
from cq_ros.world import GridWorld
from msgs_spec import EAST, NO_ACTION, Action, AgentStats, Feedback, Heartbeat, Position, WorldStats, decode, encode
from node_runtime.parameters import AGENT_PARAMETERS as PARAMETERS
from world_node.lockstep import Lockstep
from world_node.wire_reading import action_in

THREE = parse_map("""agent 1: start 0,0  goal 0,3
agent 2: start 1,0  goal 1,3
agent 3: start 2,0  goal 2,3

+-+-+-+-+
|. . . .|
+ + + + +
|. . . .|
+ + + + +
|. . . .|
+-+-+-+-+
""")


class Stub(Learner):
    """Names the peers (0-based) listed in `needs`, one tuple per decision; records every call."""

    name = "stub"

    def __init__(self, needs=(), agent=0, gridmap=THREE):
        super().__init__(agent, gridmap, Settings(), 0)
        self.needs = list(needs)
        self.calls = []

    def observe(self, cell):
        self.calls.append(("observe", cell))
        return self.needs.pop(0) if self.needs else ()

    def act(self, peer_cells):
        self.calls.append(("act", dict(peer_cells)))
        return 1

    def learn(self, reward, next_cell, done):
        self.calls.append(("learn", reward, next_cell, done))

    def end_episode(self):
        self.calls.append(("end",))

    def state_count(self):
        return self.n_cells


def fb(agent, episode, step, row, col, reward=0.0, done=False, truncated=False, applied=None):
    """Feedback as the world sends it to Stub, whose every action is EAST (`applied`: unless told otherwise)."""
    applied = (EAST if step else NO_ACTION) if applied is None else applied
    return encode(Feedback(agent, episode, step, row, col, reward, done, truncated, applied))


def pos(agent, episode, step, row, col):
    return encode(Position(agent, episode, step, row, col))


def sent(effects, kind=Action):
    return [e.payload for e in effects if isinstance(e, Send) and isinstance(e.payload, kind)]


def test_acts_at_once_when_the_learner_needs_nobody():
    d = AgentDriver(Stub(), 1, episodes=1, linger=0)
    assert feedback_in(d, 1, fb(1, 0, 0, 0, 0)) == [Send(Action(1, 0, 0, 1))]
    assert d.learner.calls == [("observe", 0), ("act", {})]


def test_subscribes_to_exactly_the_named_peers_and_acts_once_their_positions_of_this_step_are_in():
    learner = Stub(needs=[(), (2,)])  # peer index 2 = agent 3
    d = AgentDriver(learner, 1, episodes=1, linger=0)
    feedback_in(d, 1, fb(1, 0, 0, 0, 0))
    effects = feedback_in(d, 1, fb(1, 0, 1, 0, 1))
    assert effects == [Subscribe(3)]
    assert position_in(d, 3, pos(3, 0, 0, 2, 1)) == []  # an older step: not yet
    assert position_in(d, 3, pos(3, 0, 1, 2, 2)) == [Send(Action(1, 0, 1, 1))]
    assert learner.calls[-1] == ("act", {2: THREE.index(2, 2)})


def test_a_new_subscriptions_first_position_older_than_the_step_waited_for_is_dropped_uncounted():
    """The world sends a position topic nothing while nobody listens, and its newest position when a reader
    matches: a new reader may first get the last one sent before, from the latched cache. No fault; a second
    older one is."""
    d = AgentDriver(Stub(needs=[(), (2,)]), 1, episodes=1, linger=0)
    feedback_in(d, 1, fb(1, 0, 0, 0, 0))
    assert feedback_in(d, 1, fb(1, 0, 1, 0, 1)) == [Subscribe(3)]
    assert position_in(d, 3, pos(3, 0, 0, 2, 1)) == [] and d.drops.total == 0  # the cache's, from before
    assert position_in(d, 3, pos(3, 0, 0, 2, 1)) == [] and d.drops.counts == {"stale_step": 1}
    assert sent(position_in(d, 3, pos(3, 0, 1, 2, 2))) == [Action(1, 0, 1, 1)]
    assert d.peers.messages == 3


def test_waits_for_every_needed_peer():
    d = AgentDriver(Stub(needs=[(1, 2)]), 1, episodes=1, linger=0)
    assert feedback_in(d, 1, fb(1, 0, 0, 0, 0)) == [Subscribe(2), Subscribe(3)]
    assert position_in(d, 2, pos(2, 0, 0, 1, 0)) == []
    assert sent(position_in(d, 3, pos(3, 0, 0, 2, 0))) == [Action(1, 0, 0, 1)]


def test_positions_that_came_before_the_feedback_are_used():
    d = AgentDriver(Stub(needs=[(1,), (1,)]), 1, episodes=1, linger=5)
    feedback_in(d, 1, fb(1, 0, 0, 0, 0))
    position_in(d, 2, pos(2, 0, 0, 1, 0))
    position_in(d, 2, pos(2, 0, 1, 1, 1))  # the kept subscription delivers step 1 before our feedback
    assert sent(feedback_in(d, 1, fb(1, 0, 1, 0, 1))) == [Action(1, 0, 1, 1)]
    assert d.peers.created == 1


@pytest.mark.parametrize("linger", [0, 2])
def test_a_peer_no_longer_needed_is_dropped_after_linger_steps(linger):
    needs = [(1,)] + [()] * 5
    d = AgentDriver(Stub(needs=needs), 1, episodes=1, linger=linger)
    effects = feedback_in(d, 1, fb(1, 0, 0, 0, 0))
    position_in(d, 2, pos(2, 0, 0, 1, 0))
    dropped_at = None
    for step in range(1, 6):
        effects = feedback_in(d, 1, fb(1, 0, step, 0, 0))
        if Unsubscribe(2) in effects:
            dropped_at = step
    assert dropped_at == linger + 1
    assert d.peers.subscribed == [] and d.peers.created == 1


def test_the_end_of_an_episode_counts_as_a_step_without_need():
    d = AgentDriver(Stub(needs=[(1,)]), 1, episodes=2, linger=0)
    feedback_in(d, 1, fb(1, 0, 0, 0, 0))
    position_in(d, 2, pos(2, 0, 0, 1, 0))
    effects = feedback_in(d, 1, fb(1, 0, 1, 0, 1, 10.0, done=True))
    assert effects[0] == Unsubscribe(2)
    [stats] = sent(effects, AgentStats)
    assert (stats.subscriptions_created, stats.subscriptions_active, stats.peer_messages) == (1, 0, 1)


def test_learns_only_from_the_outcome_of_its_own_action():
    learner = Stub()
    d = AgentDriver(learner, 1, episodes=1, linger=0)
    feedback_in(d, 1, fb(1, 0, 0, 0, 0))
    feedback_in(d, 1, fb(1, 0, 1, 0, 1, -1.0))
    assert ("learn", -1.0, THREE.index(0, 1), False) in learner.calls


def test_an_action_the_world_did_not_apply_is_not_learnt_and_is_counted():
    """A stall seen in a real run: step 0's EAST was applied (it moved); step 1's came after step_timeout and the
    world stepped without it (it stayed, feedback of step 2 from the same cell): nothing is learnt from
    step 1, and the agent plays step 2 as usual."""
    learner = Stub()
    logs = []
    d = AgentDriver(learner, 1, episodes=1, linger=0, log=logs.append)
    feedback_in(d, 1, fb(1, 0, 0, 0, 0))
    feedback_in(d, 1, fb(1, 0, 1, 0, 1, -1.0, applied=EAST))
    effects = feedback_in(d, 1, fb(1, 0, 2, 0, 1, Settings().reward_step, applied=NO_ACTION))
    assert sent(effects) == [Action(1, 0, 2, EAST)]
    assert [c for c in learner.calls if c[0] == "learn"] == [("learn", -1.0, THREE.index(0, 1), False)]
    assert d.counters()["unapplied_actions"] == 1 and "skipped_steps" not in d.counters()
    assert "without our action of step 1" in logs[-1]


def test_a_central_driver_learns_a_joint_action_only_as_the_world_applied_it_whole():
    learner = make_learner("jsa", THREE, Settings(), 0, 0, 0)
    learnt = []
    learner.learn = lambda reward, cells, done: learnt.append((reward, cells))
    d = CentralDriver(learner, episodes=1)
    for k in (1, 2, 3):
        joint = sent(feedback_in(d, k, fb(k, 0, 0, k - 1, 0)))
    applied = {a.agent: a.action for a in joint}
    feedback_in(d, 1, fb(1, 0, 1, 0, 0, -1.0, applied=applied[1]))
    feedback_in(d, 2, fb(2, 0, 1, 1, 0, -1.0, applied=NO_ACTION))  # came late: the world stepped without it
    assert sent(feedback_in(d, 3, fb(3, 0, 1, 2, 0, -1.0, applied=applied[3])))  # it acts on
    assert learnt == [] and d.counters()["unapplied_actions"] == 1


def test_a_step_the_world_took_without_us_is_skipped_not_learnt():
    learner = Stub(needs=[(1,)])
    logs = []
    d = AgentDriver(learner, 1, episodes=1, linger=0, log=logs.append)
    feedback_in(d, 1, fb(1, 0, 0, 0, 0))  # waits for agent 2, whose position never comes
    effects = feedback_in(d, 1, fb(1, 0, 1, 0, 0))  # the world timed us out and stepped
    assert sent(effects) == [Action(1, 0, 1, 1)]
    assert not any(c[0] == "learn" for c in learner.calls)
    assert d.skipped_steps == 1 and d.counters()["skipped_steps"] == 1 and logs


def test_a_subscription_waited_on_that_delivers_nothing_is_made_anew_then_after_twice_as_long():
    """Once in CI a new position subscription got nothing for 28 steps (agent_node.peer_view): whichever side
    lost the match, a new subscription is a new match. Positions flowing, nothing is renewed."""
    clock, logs = Clock(), []
    d = AgentDriver(Stub(needs=[(1,)] * 6), 1, episodes=1, linger=0, log=logs.append, clock=clock)
    assert feedback_in(d, 1, fb(1, 0, 0, 0, 0)) == [Subscribe(2)]
    assert d.renew_quiet() == []  # first seen waited for at 0.0
    clock.now = RENEW_AFTER_S - 0.01
    assert d.renew_quiet() == []
    feedback_in(d, 1, fb(1, 0, 1, 0, 0))  # the world timed us out and stepped: still waiting for agent 2
    clock.now = RENEW_AFTER_S
    assert d.renew_quiet() == [Renew(2)] and "agv2" in logs[-1]
    clock.now = 2.9 * RENEW_AFTER_S
    assert d.renew_quiet() == []  # the next one after twice as long
    clock.now = 3 * RENEW_AFTER_S
    assert d.renew_quiet() == [Renew(2)]
    # the renewed reader's first position may be the latched one from before: no fault
    assert position_in(d, 2, pos(2, 0, 0, 1, 0)) == [] and d.drops.total == 0
    assert sent(position_in(d, 2, pos(2, 0, 1, 1, 0))) == [Action(1, 0, 1, 1)]
    assert d.counters()["renewed_subscriptions"] == 2 and d.peers.created == 3
    # positions flowing: each step's within RENEW_AFTER_S of the last, however long the run
    for step in range(2, 6):
        feedback_in(d, 1, fb(1, 0, step, 0, 0))
        assert d.renew_quiet() == []
        clock.now += 0.9 * RENEW_AFTER_S
        assert d.renew_quiet() == []
        assert sent(position_in(d, 2, pos(2, 0, step, 1, 0)))
    assert d.counters()["renewed_subscriptions"] == 2


def test_bad_feedback_is_counted_and_dropped():
    d = AgentDriver(Stub(), 1, episodes=3, linger=0)  # episode 1 is in the run (a later one would be far_ahead)
    feedback_in(d, 1, fb(1, 0, 0, 0, 0))
    nan = fb(1, 0, 1, 0, 1)
    nan.data[5] = math.nan
    for msg in (nan, fb(1, 0, 0, 0, 1), fb(1, 0, 2, 0, 1), fb(1, 1, 1, 0, 1), fb(2, 0, 1, 0, 1),
                fb(1, 0, 1, 9, 9)):
        assert feedback_in(d, 1, msg) == []
    # the later ones the world has not vouched for are held until the expected one comes, then dropped
    assert sent(feedback_in(d, 1, fb(1, 0, 1, 0, 1))) == [Action(1, 0, 1, 1)]
    assert d.drops.counts == {"not_finite": 1, "stale_step": 1, "future_step": 1, "future_episode": 1,
                              "wrong_agent": 1, "cell_out_of_range": 1}


def test_a_square_outside_the_world_is_refused_like_one_outside_the_grid():
    gm = parse_map("""agent 1: start 0,0  goal 0,1
agent 2: start 1,1  goal 1,1

+-+-+
|. .|
+-+ +
|# .|
+-+-+
""")
    d = AgentDriver(Stub(needs=[(1,)], gridmap=gm), 1, episodes=1, linger=0)
    assert feedback_in(d, 1, fb(1, 0, 0, 1, 0)) == []
    feedback_in(d, 1, fb(1, 0, 0, 0, 0))
    assert position_in(d, 2, pos(2, 0, 0, 1, 0)) == []
    assert d.drops["cell_out_of_range"] == 2


def test_resumes_at_whatever_step_the_world_is_at():
    learner = Stub()
    d = AgentDriver(learner, 1, episodes=10, linger=0, resync=True)
    assert sent(feedback_in(d, 1, fb(1, 7, 12, 0, 2, -1.0))) == [Action(1, 7, 12, 1)]
    assert learner.calls[0] == ("observe", THREE.index(0, 2))  # nothing learnt: we sent no action before
    assert d.expect == (7, 13)


def test_episode_end_publishes_stats_checkpoints_and_finishes():
    learner = make_learner("cq", THREE, Settings(), 0, 0, 0)
    d = AgentDriver(learner, 1, episodes=4, linger=0, checkpoint_every=2)
    kinds = []
    for e in range(4):
        feedback_in(d, 1, fb(1, e, 0, 0, 0))
        effects = feedback_in(d, 1, fb(1, e, 1, 0, 1, truncated=True))
        kinds.append([type(x).__name__ for x in effects])
    assert kinds == [["Send"], ["Send", "SaveCheckpoint"], ["Send"], ["Send", "SaveCheckpoint", "Finish"]]
    assert d.finished and effects[1] == SaveCheckpoint(3, learner) and effects[2] == Finish()
    [stats] = sent(effects, AgentStats)
    assert (stats.agent, stats.episode, stats.algorithm, stats.local_states, stats.joint_states) == (1, 3, "cq", 12, 0)


class Counting(Stub):
    """A Stub whose every action counts as a joint play."""

    def act(self, peer_cells):
        self.joint_plays += 1
        return super().act(peer_cells)


def play_agent_episode(d, episode):
    """Agent 1 acts at step 0; the episode is truncated at step 1."""
    return feedback_in(d, 1, fb(1, episode, 0, 0, 0)) + feedback_in(d, 1, fb(1, episode, 1, 0, 1, truncated=True))


def play_central_episode(d, episode):
    """Every agent of THREE acts at step 0; the episode is truncated at step 1."""
    out = []
    for step, truncated in ((0, False), (1, True)):
        for k in (1, 2, 3):
            out += feedback_in(d, k, fb(k, episode, step, k - 1, step, truncated=truncated))
    return out


@pytest.mark.parametrize("central", [False, True], ids=["agent", "central"])
def test_the_greedy_episodes_follow_the_last_learning_one_on_a_copy_at_epsilon_0(central, tmp_path):
    if central:
        learner = make_learner("jsa", THREE, Settings(), 0, 0, 0)
        d, play = CentralDriver(learner, 2, eval_episodes=2, checkpoint_every=1), play_central_episode
    else:
        learner = Counting()
        d, play = AgentDriver(learner, 1, 2, eval_episodes=2, linger=0, checkpoint_every=1), play_agent_episode
    effects = [play(d, e) for e in range(4)]
    saved = [[x for x in out if isinstance(x, SaveCheckpoint)] for out in effects]
    assert saved == [[SaveCheckpoint(0, learner)], [SaveCheckpoint(1, learner)], [], []]  # learning ones only
    assert [[x for x in out if isinstance(x, Finish)] for out in effects] == [[], [], [], [Finish()]]
    assert d.finished and d.greedy and d.learner is not learner
    assert d.learner.epsilon == 0.0 and learner.epsilon == Settings().epsilon
    assert saved[1][0].learner is learner  # the trained learner, not its greedy copy
    if central:  # a learner a checkpoint holds (the stub is none)
        save_checkpoint(tmp_path / "c.ckpt", saved[1][0].learner, 1)  # as the node does, once the effects are out
        loaded, _ = load_checkpoint(tmp_path / "c.ckpt", learner.name, THREE, 0, Settings())
        assert loaded.epsilon == Settings().epsilon
    stats = [s for out in effects for s in sent(out, AgentStats) if s.agent == 1]
    assert [s.episode for s in stats] == [0, 1, 2, 3]
    if not central:  # the copy acted in the greedy episodes, the original stopped; plays counted per episode
        assert [c[0] for c in learner.calls].count("act") == 2 and [c[0] for c in d.learner.calls].count("act") == 4
        assert [s.joint_plays for s in stats] == [1, 1, 1, 1]


def test_the_switch_to_greedy_comes_at_the_end_of_the_last_learning_episode():
    learner = Stub()
    d = AgentDriver(learner, 1, 1, eval_episodes=1, linger=0)
    feedback_in(d, 1, fb(1, 0, 0, 0, 0))
    assert d.learner is learner and not d.greedy  # still learning in episode 0
    effects = feedback_in(d, 1, fb(1, 0, 1, 0, 1, truncated=True))
    assert d.greedy and d.learner.epsilon == 0.0 and Finish() not in effects
    finished = AgentDriver(Stub(), 1, 1, linger=0)  # eval_episodes 0: finished right after learning
    assert play_agent_episode(finished, 0)[-1] == Finish() and not finished.greedy


def test_a_driver_resumed_in_the_greedy_phase_plays_greedy():
    learner = Stub()
    d = AgentDriver(learner, 1, 2, eval_episodes=3, linger=0, resync=True)
    assert sent(feedback_in(d, 1, fb(1, 3, 5, 0, 2))) == [Action(1, 3, 5, 1)]
    assert d.greedy and d.learner is not learner and d.learner.epsilon == 0.0
    assert learner.calls == [] and d.learner.calls == [("observe", THREE.index(0, 2)), ("act", {})]
    learning = AgentDriver(Stub(), 1, 2, eval_episodes=3, linger=0, resync=True)
    feedback_in(learning, 1, fb(1, 1, 5, 0, 2))
    assert not learning.greedy and learning.learner.epsilon == Settings().epsilon


def test_a_central_driver_resumed_in_the_greedy_phase_plays_greedy():
    learner = make_learner("jsa", THREE, Settings(), 0, 0, 0)
    d = CentralDriver(learner, 2, eval_episodes=3, resync=True)
    feedback_in(d, 1, fb(1, 2, 4, 0, 1))
    for k in (1, 2, 3):
        effects = position_in(d, k, pos(k, 2, 4, k - 1, 1))
    assert len(sent(effects)) == 3 and d.greedy and d.learner is not learner and d.learner.epsilon == 0.0


def test_checkpoint_round_trip_acts_identically(tmp_path):
    gm = load_map("tunnel_to_goal")
    learner = make_learner("cq", gm, Settings(window=5), 0, 0, 0)
    rng = random.Random(1)
    for _ in range(500):  # some learning, so the tables are not empty
        learner.observe(rng.randrange(gm.n_cells))
        learner.act({1: rng.randrange(gm.n_cells)})
        learner.learn(rng.choice([0.0, -1.0, -10.0]), rng.randrange(gm.n_cells), False)
    path = tmp_path / "agv1.ckpt"
    save_checkpoint(path, learner, 41)
    loaded, episode = load_checkpoint(path, "cq", gm, 0, Settings(window=5))
    assert episode == 41 and os.listdir(tmp_path) == ["agv1.ckpt"]
    for _ in range(300):
        cell, peer = rng.randrange(gm.n_cells), rng.randrange(gm.n_cells)
        assert loaded.observe(cell) == learner.observe(cell)
        assert loaded.act({1: peer}) == learner.act({1: peer})
        reward, nxt = rng.choice([0.0, -10.0]), rng.randrange(gm.n_cells)
        loaded.learn(reward, nxt, False)
        learner.learn(reward, nxt, False)
    assert loaded.q_local == learner.q_local and loaded.joint_states() == learner.joint_states()


def test_a_failed_checkpoint_write_leaves_the_previous_one(tmp_path, monkeypatch):
    gm = load_map("tunnel_to_goal")
    learner = make_learner("indep", gm, Settings(), 0, 0, 0)
    path = tmp_path / "agv1.ckpt"
    save_checkpoint(path, learner, 1)
    replaced = []
    real_replace = os.replace
    monkeypatch.setattr(os, "replace", lambda a, b: (replaced.append((a, b)), real_replace(a, b)))
    save_checkpoint(path, learner, 2)
    [(tmp, dest)] = replaced
    assert os.path.dirname(tmp) == str(tmp_path) and dest == str(path)  # a rename in the same directory

    def broken_fsync(*args, **kwargs):  # the temporary file written, its flush to the disk fails
        raise OSError("disk full")

    monkeypatch.setattr(os, "fsync", broken_fsync)
    with pytest.raises(OSError):
        save_checkpoint(path, learner, 3)
    assert load_checkpoint(path, "indep", gm, 0, Settings())[1] == 2 and os.listdir(tmp_path) == ["agv1.ckpt"]


def test_load_checkpoint_refuses_another_agent_or_a_broken_file(tmp_path):
    gm = load_map("tunnel_to_goal")
    path = tmp_path / "c.ckpt"
    save_checkpoint(path, make_learner("cq", gm, Settings(), 0, 0, 1), 5)
    with pytest.raises(SettingsError, match="parameter checkpoint: .*agent index 1.*agent index 0"):
        load_checkpoint(path, "cq", gm, 0, Settings())
    with pytest.raises(SettingsError, match="algo js"):
        load_checkpoint(path, "js", gm, 1, Settings())
    path.write_bytes(b"not a pickle")
    with pytest.raises(SettingsError, match="parameter checkpoint: .* is not a checkpoint"):
        load_checkpoint(path, "cq", gm, 1, Settings())


def test_make_driver_resumes_from_an_existing_checkpoint(tmp_path):
    values = {name: default for name, (default, _) in PARAMETERS.items()}
    cfg = agent_config({**values, "agent_id": 2, "checkpoint": str(tmp_path / "c.ckpt")})
    fresh = make_driver(cfg)
    assert fresh.expect == (0, 0) and fresh.checkpoint_every == 50
    assert (fresh.episodes, fresh.eval_episodes) == (500, Settings().eval_episodes)
    save_checkpoint(cfg.checkpoint, fresh.learner, 9)
    resumed = make_driver(cfg, log=lambda _: None)
    assert resumed.expect is None and resumed.learner.agent == 1
    assert make_driver(agent_config({**values, "agent_id": 2})).checkpoint_every == 0  # no path: none


def test_agent_config_checks_every_parameter():
    values = {name: default for name, (default, _) in PARAMETERS.items()}
    with pytest.raises(SettingsError, match="parameter agent_id must be 1..2"):
        agent_config(values)  # cq needs an agent id
    assert agent_config({**values, "agent_id": 2}).agent == 2
    with pytest.raises(SettingsError, match="parameter agent_id: algo jsa runs one central node"):
        agent_config({**values, "algo": "jsa", "agent_id": 1})
    assert agent_config({**values, "algo": "jsa"}).agent == 0
    unset = {k: v for k, v in values.items() if k not in SETTING_NAMES}  # settings not given: the map's
    assert agent_config({**unset, "agent_id": 1, "map": "warehouse_8"}).settings == Settings(
        reward_step=-1.0, gamma=0.98, epsilon_decay_episodes=1500)
    with pytest.raises(SettingsError, match="parameter algo: unknown algorithm 'sarsa'"):
        agent_config({**values, "algo": "sarsa", "agent_id": 1})
    with pytest.raises(SettingsError, match="parameter map: .*no such map"):
        agent_config({**values, "map": "atlantis", "agent_id": 1})
    with pytest.raises(SettingsError, match="setting epsilon"):
        agent_config({**values, "epsilon": -0.1, "agent_id": 1})
    with pytest.raises(SettingsError, match="parameter feedback_timeout must be > 0"):
        agent_config({**values, "feedback_timeout": 0.0, "agent_id": 1})
    with pytest.raises(SettingsError, match="parameter algo: jsa supports at most"):
        make_driver(agent_config({**values, "algo": "jsa", "map": "warehouse_8"}))


def test_central_driver_answers_for_every_acting_agent_once_all_feedback_is_in():
    learner = make_learner("jsa", THREE, Settings(), 0, 0, 0)
    d = CentralDriver(learner, episodes=1)
    assert feedback_in(d, 1, fb(1, 0, 0, 0, 0)) == []
    assert feedback_in(d, 2, fb(2, 0, 0, 1, 0)) == []
    actions = sent(feedback_in(d, 3, fb(3, 0, 0, 2, 0)))
    assert [(a.agent, a.episode, a.step) for a in actions] == [(1, 0, 0), (2, 0, 0), (3, 0, 0)]
    feedback_in(d, 1, fb(1, 0, 1, 0, 1))
    feedback_in(d, 2, fb(2, 0, 1, 1, 3, 10.0, done=True))
    actions = sent(feedback_in(d, 3, fb(3, 0, 1, 2, 1)))
    assert [a.agent for a in actions] == [1, 3]  # agent 2 is at its goal
    assert d.expect[2] == (1, 0) and d.expect[1] == (0, 2)


def test_central_driver_resumes_from_the_positions_of_the_step_it_joins():
    learner = make_learner("jsa", THREE, Settings(), 0, 0, 0)
    d = CentralDriver(learner, episodes=5, resync=True)
    assert feedback_in(d, 3, fb(3, 2, 6, 2, 2)) == [Subscribe(1), Subscribe(2), Subscribe(3)]
    assert feedback_in(d, 1, fb(1, 2, 6, 0, 1)) == []  # the positions decide
    assert position_in(d, 1, pos(1, 2, 6, 0, 1)) == []
    assert position_in(d, 2, pos(2, 2, 6, 1, 3)) == []  # at its goal: done
    effects = position_in(d, 3, pos(3, 2, 6, 2, 2))
    assert effects[:3] == [Unsubscribe(1), Unsubscribe(2), Unsubscribe(3)]
    assert [(a.agent, a.episode, a.step) for a in sent(effects)] == [(1, 2, 6), (3, 2, 6)]
    assert d.expect == {1: (2, 7), 2: (3, 0), 3: (2, 7)}


# -- a whole run, world core and drivers, without ROS ---------------------------------------------------


class Bus:
    """Delivers messages between a Lockstep and drivers the way DDS does with our QoS: in order per topic
    and receiver, in any order across topics (a seeded shuffle), latched positions handed to a new
    subscription at once."""

    def __init__(self, core, drivers, rng):
        self.core, self.drivers, self.rng = core, drivers, rng
        self.channels = defaultdict(deque)  # (receiver, topic) -> messages in order
        self.latched = {}
        self.subscribed = defaultdict(set)
        self.world_stats, self.agent_stats = [], defaultdict(list)
        self.owner = {k: d for d in drivers for k in d.agents}

    def world_out(self, payloads):
        for p in payloads:
            if isinstance(p, WorldStats):
                self.world_stats.append(p)
            elif isinstance(p, Position):
                self.latched[p.agent] = encode(p)
                for d in self.drivers:
                    if p.agent in self.subscribed[d]:
                        self.channels[(d, "position", p.agent)].append(encode(p))
            else:
                d = self.owner[p.agent]
                self.channels[(d, "feedback", p.agent)].append(encode(p))

    def driver_out(self, d, effects):
        for e in effects:
            match e:
                case Send(payload=Action() as a):
                    self.channels[(self.core, "action", a.agent)].append(encode(a))
                case Send(payload=stats):  # through the wire as every message, so its counts must fit it
                    self.agent_stats[stats.agent].append(decode(encode(stats)))
                case Subscribe(peer=j):
                    self.subscribed[d].add(j)
                    if j in self.latched:
                        self.channels[(d, "position", j)].append(self.latched[j])
                case Unsubscribe(peer=j):
                    self.subscribed[d].discard(j)
                    # a message already queued may still arrive (the driver must ignore it)

    def run(self):
        self.world_out(self.core.begin())
        while True:
            ready = [c for c, q in self.channels.items() if q]
            if not ready:
                return
            receiver, topic, agent = key = self.rng.choice(ready)
            msg = self.channels[key].popleft()
            if receiver is self.core:
                self.world_out(action_in(self.core, agent, msg))
            elif topic == "feedback":
                self.driver_out(receiver, feedback_in(receiver, agent, msg))
            else:
                self.driver_out(receiver, position_in(receiver, agent, msg))


ALGOS = ("cq", "js", "loc", "jsa", "indep")
# A few greedy episodes each: a barely trained greedy policy may run to step_cap.
CASES = [(algo, "tunnel_to_goal", 4, 15, {"window": 10, "step_cap": 300, "eval_episodes": 2}) for algo in ALGOS]
CASES += [(algo, "grid_game_2", 1, 60, {"window": 5, "eval_episodes": 3}) for algo in ALGOS]
CASES += [("cq", "tunnel_to_goal", 4, 40, {"window": 10, "step_cap": 500, "eval_episodes": 2})]
# JS's state space on warehouse_8 (132**8, about 9.2e16) is past int32 and float64's exact integers.
CASES += [("js", "warehouse_8", 0, 2, {"step_cap": 40, "eval_episodes": 1})]
# Slipping moves draw from the world's RNG, which the greedy episodes go on drawing from.
CASES += [("cq", "grid_game_2", 1, 60, {"window": 5, "eval_episodes": 3, "slip": 0.2})]
# A frozen greedy copy (eval_learning 0): CQ's confidence and LoC's new joint states stay as learnt, alike.
CASES += [("cq", "tunnel_to_goal", 4, 40, {"window": 10, "step_cap": 500, "eval_episodes": 2, "eval_learning": 0}),
          ("loc", "grid_game_2", 1, 60, {"window": 5, "eval_episodes": 3, "eval_learning": 0})]


@pytest.mark.parametrize("algo,map_name,seed,episodes,overrides", CASES)
@pytest.mark.slow
def test_a_whole_run_without_ros_equals_the_offline_engine(algo, map_name, seed, episodes, overrides):
    gridmap = load_map(map_name)
    settings = Settings().with_overrides(overrides)
    played = episodes + settings.eval_episodes  # the world plays the greedy episodes as any other
    core = Lockstep(GridWorld(gridmap, settings, seed=world_seed(seed, 0)), played, step_timeout=1.0)
    central = algo == "jsa"
    drivers = [make_driver(agent_config({**{n: v for n, (v, _) in PARAMETERS.items()}, **overrides,
                                         "algo": algo, "map": map_name, "seed": seed, "episodes": episodes,
                                         "agent_id": k, "peer_linger_steps": 1}))
               for k in ([0] if central else range(1, gridmap.n_agents + 1))]
    bus = Bus(core, drivers, random.Random(seed))
    bus.run()
    assert core.finished and all(d.finished for d in drivers)
    result = run(algo, gridmap, settings, seed, 0, episodes)
    offline = np.concatenate([result.episodes, result.greedy])  # the greedy episodes follow the learning ones
    assert len(result.greedy) == settings.eval_episodes > 0
    assert [(s.steps, s.collisions, s.truncated) for s in bus.world_stats] == \
        [(int(e["steps"]), int(e["collisions"]), bool(e["truncated"])) for e in offline]
    # the agents' statistics add up to the engine's per-episode joint plays and state counts
    per_agent = [bus.agent_stats[1]] if central else [bus.agent_stats[k] for k in range(1, gridmap.n_agents + 1)]
    plays = [sum(s[e].joint_plays for s in per_agent) for e in range(played)]
    states = [sum(s[e].local_states + s[e].joint_states for s in per_agent) for e in range(played)]
    assert plays == [int(e["joint_plays"]) for e in offline]
    assert states == [int(e["states"]) for e in offline]
    if algo == "indep":
        assert all(s[-1].subscriptions_created == 0 for s in per_agent)
    if algo == "js":
        assert all(s[-1].subscriptions_created == gridmap.n_agents - 1 for s in per_agent)  # every peer, all along


# -- faults: catching up, liveness, positions per stamp, keys, checkpoints --------------------------------

KEY = bytes(range(32))


class Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def kfb(agent, episode, step, row, col, reward=0.0, done=False, truncated=False):
    return encode(Feedback(agent, episode, step, row, col, reward, done, truncated, EAST if step else NO_ACTION),
                  key=KEY)


def beat(n, episode, step, key=None):
    return encode(Heartbeat(n, episode, step), key=key)


def test_a_later_keyed_feedback_is_adopted_at_once_and_the_gap_counted():
    learner = Stub()
    d = AgentDriver(learner, 1, episodes=5, linger=0, key=KEY)
    feedback_in(d, 1, kfb(1, 0, 0, 0, 0))
    feedback_in(d, 1, kfb(1, 0, 1, 0, 1))  # acted at step 1; its feedback of step 2 is lost
    assert sent(feedback_in(d, 1, kfb(1, 0, 3, 0, 2))) == [Action(1, 0, 3, 1)]
    assert d.expect == (0, 4) and d.counters() == {"caught_up": 1, "missed_feedback": 1}
    assert [c for c in learner.calls if c[0] == "learn"] == [("learn", 0.0, THREE.index(0, 1), False)]


def test_without_a_key_a_later_feedback_waits_for_the_worlds_heartbeat():
    d = AgentDriver(Stub(), 1, episodes=5, linger=0)
    feedback_in(d, 1, fb(1, 0, 0, 0, 0))
    assert feedback_in(d, 1, fb(1, 0, 5, 0, 2)) == []  # held: a forger could have sent it
    assert heartbeat_in(d, beat(1, 0, 4)) == []  # the world is not there yet
    assert sent(heartbeat_in(d, beat(2, 0, 5))) == [Action(1, 0, 5, 1)]
    assert d.counters() == {"caught_up": 1, "missed_feedback": 4}


def test_a_forged_far_future_feedback_never_captures_an_agent_without_a_key():
    d = AgentDriver(Stub(), 1, episodes=5, linger=0)
    feedback_in(d, 1, fb(1, 0, 0, 0, 0))
    for forged in (fb(1, 0, 10_000, 0, 2), fb(1, 3, 0, 0, 2)):
        assert feedback_in(d, 1, forged) == []
    heartbeat_in(d, beat(1, 0, 1))
    assert sent(feedback_in(d, 1, fb(1, 0, 1, 0, 1))) == [Action(1, 0, 1, 1)]  # the world's, as expected
    assert d.drops.counts == {"future_step": 1, "future_episode": 1} and "caught_up" not in d.counters()


def test_catching_up_across_episodes_sends_the_statistics_of_every_episode_left_behind():
    d = AgentDriver(Stub(), 1, episodes=10, linger=0, checkpoint_every=3, key=KEY)
    feedback_in(d, 1, kfb(1, 2, 0, 0, 0))  # a fresh driver joins at episode 2: nothing left behind
    assert d.counters() == {"caught_up": 1}
    feedback_in(d, 1, kfb(1, 2, 1, 0, 1))
    effects = feedback_in(d, 1, kfb(1, 5, 1, 0, 1))
    assert [s.episode for s in sent(effects, AgentStats)] == [2, 3, 4]
    assert [e.episode for e in effects if isinstance(e, SaveCheckpoint)] == [2]
    assert sent(effects) == [Action(1, 5, 1, 1)] and d.expect == (5, 2)


def test_a_restart_from_a_checkpoint_counts_its_catch_up():
    """a node resumed from its checkpoint joins the world where it is, counted as caught_up as a
    restart without one is (it was not)."""
    d = AgentDriver(Stub(), 1, episodes=5, linger=0, resync=True)
    assert sent(feedback_in(d, 1, fb(1, 2, 7, 0, 1))) == [Action(1, 2, 7, 1)]
    assert d.counters() == {"caught_up": 1}
    central = CentralDriver(make_learner("jsa", THREE, Settings(), 0, 0, 0), episodes=5, resync=True)
    feedback_in(central, 3, fb(3, 2, 6, 2, 2))
    assert central.counters() == {"caught_up": 1}


def test_a_restart_without_a_checkpoint_starts_a_fresh_learner_at_the_worlds_step(tmp_path):
    values = {name: default for name, (default, _) in PARAMETERS.items()}
    cfg = agent_config({**values, "agent_id": 1, "checkpoint": str(tmp_path / "none_yet.npz")})
    d = make_driver(cfg)
    assert d.expect == (0, 0)
    assert feedback_in(d, 1, fb(1, 7, 12, 0, 2)) == []  # held until the world's heartbeat vouches for it
    effects = heartbeat_in(d, beat(1, 7, 12))
    assert [(a.episode, a.step) for a in sent(effects)] == [(7, 12)] and not sent(effects, AgentStats)
    assert d.expect == (7, 13) and d.link.caught_up == 1 and d.link.missed_feedback == 0


def test_only_valid_new_messages_from_the_world_count_as_alive():
    clock = Clock()
    d = AgentDriver(Stub(), 1, episodes=5, linger=0, key=KEY, clock=clock)
    clock.now = 10.0
    feedback_in(d, 1, fb(1, 0, 0, 0, 0))  # no MAC
    feedback_in(d, 1, encode(Feedback(1, 0, 0, 9, 9, 0.0)))
    heartbeat_in(d, beat(1, 0, 0))  # no MAC
    assert d.link.silent_for() == 10.0 and d.drops["unauthenticated"] == 3
    heartbeat_in(d, beat(1, 0, 0, key=KEY))
    assert d.link.silent_for() == 0.0
    clock.now = 20.0
    heartbeat_in(d, beat(1, 0, 0, key=KEY))  # a replay
    assert d.link.silent_for() == 10.0 and d.drops["replayed"] == 1
    feedback_in(d, 1, kfb(1, 0, 0, 0, 0))
    assert d.link.silent_for() == 0.0


def test_positions_are_judged_by_their_stamp():
    d = AgentDriver(Stub(needs=[(1,), (1,)]), 1, episodes=1, linger=5)
    feedback_in(d, 1, fb(1, 0, 0, 0, 0))
    position_in(d, 2, pos(2, 0, 0, 1, 0))
    feedback_in(d, 1, fb(1, 0, 1, 0, 1))
    assert position_in(d, 2, pos(2, 0, 0, 1, 3)) == []  # stamped with the previous step: stale
    for step in range(2, 60):  # a burst of later positions from another writer
        position_in(d, 2, pos(2, 0, step, 1, 2))
    effects = position_in(d, 2, pos(2, 0, 1, 1, 2))  # the world's, after the burst: not pushed out
    assert sent(effects) == [Action(1, 0, 1, 1)] and d.learner.calls[-1] == ("act", {1: THREE.index(1, 2)})
    assert position_in(d, 2, pos(2, 0, 1, 1, 1)) == [] and d.drops["conflicting"] == 1  # the first writer wins
    assert d.drops["stale_step"] == 1 and d.drops["future_step"] == 51  # the burst beyond AHEAD stamps


def test_a_central_driver_catches_up_from_the_positions_of_the_worlds_step():
    learner = make_learner("jsa", THREE, Settings(), 0, 0, 0)
    d = CentralDriver(learner, episodes=5, key=KEY)
    for k in (1, 2, 3):
        feedback_in(d, k, kfb(k, 0, 0, k - 1, 0))
    effects = feedback_in(d, 2, kfb(2, 0, 2, 1, 1))  # its step-1 feedback was lost
    assert effects == [Subscribe(1), Subscribe(2), Subscribe(3)] and d.link.caught_up == 1
    for k in (1, 2, 3):
        effects = position_in(d, k, encode(Position(k, 0, 2, k - 1, 1), key=KEY))
    assert [(a.agent, a.episode, a.step) for a in sent(effects)] == [(1, 0, 2), (2, 0, 2), (3, 0, 2)]


def test_the_checkpoint_folder_must_exist_and_be_writable(tmp_path, monkeypatch):
    values = {**{name: default for name, (default, _) in PARAMETERS.items()}, "agent_id": 1}
    with pytest.raises(SettingsError, match="parameter checkpoint: .*does not exist"):
        agent_config({**values, "checkpoint": str(tmp_path / "no" / "such" / "x.npz")})
    with pytest.raises(SettingsError, match="parameter checkpoint: .*is a folder"):
        agent_config({**values, "checkpoint": str(tmp_path)})
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    # root may write anywhere (the tests may run as root): the check asks os.access, as the kernel would answer
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if str(p) == str(locked) else real_access(p, mode))
    with pytest.raises(SettingsError, match="parameter checkpoint: .*not writable"):
        agent_config({**values, "checkpoint": str(locked / "x.npz")})


def test_make_driver_removes_the_temporary_files_of_a_save_killed_mid_write(tmp_path):
    path = tmp_path / "agv1.npz"
    for name in ("agv1.npz.abc123.tmp", "agv1.npz.zz.tmp", "agv2.npz.abc.tmp", "other.tmp"):
        (tmp_path / name).write_bytes(b"half a pickle")
    logs = []
    values = {name: default for name, (default, _) in PARAMETERS.items()}
    make_driver(agent_config({**values, "agent_id": 1, "checkpoint": str(path)}), log=logs.append)
    assert sorted(os.listdir(tmp_path)) == ["agv2.npz.abc.tmp", "other.tmp"] and "removed 2" in logs[0]


@pytest.mark.parametrize("name", [n for n, (d, _) in PARAMETERS.items() if isinstance(d, float)])
@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_agent_config_refuses_nan_and_inf_for_every_number(name, bad):
    values = {**{n: d for n, (d, _) in PARAMETERS.items()}, "agent_id": 1}
    with pytest.raises(SettingsError, match=name):
        agent_config({**values, name: bad})


def test_a_key_file_must_be_the_users_alone(tmp_path):
    from msgs_spec import new_key_file

    values = {**{n: d for n, (d, _) in PARAMETERS.items()}, "agent_id": 1}
    path = new_key_file(tmp_path)
    assert agent_config({**values, "key_file": str(path)}).key.secret == bytes.fromhex(path.read_text())
    path.chmod(0o644)
    with pytest.raises(SettingsError, match="parameter key_file: .* accessible to others"):
        agent_config({**values, "key_file": str(path)})
    with pytest.raises(SettingsError, match="parameter key_file: cannot read"):
        agent_config({**values, "key_file": str(tmp_path / "nothing")})

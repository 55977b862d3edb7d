"""A learner's state as arrays (cq_ros.learners.state): a learner restored from them plays exactly the episodes
the original would have, for every learner, and every field is checked on the way back."""

import json
import random

import numpy as np
import pytest

from cq_ros.engine import Team, make_learners, world_seed
from cq_ros.episode import table
from cq_ros.gridmap import load_map
from cq_ros.learners import REGISTRY
from cq_ros.learners.state import StateError, from_arrays, to_arrays
from cq_ros.settings import Settings, run_settings
from cq_ros.world import GridWorld

ALL = [a.name for a in REGISTRY]
SMALL = Settings(window=10, step_cap=120)


def _round_trip(learners, gridmap, settings):
    # through an .npz's own types: what np.load hands back is arrays, never the objects written
    return [from_arrays({k: np.asarray(v) for k, v in to_arrays(learner).items()}, gridmap, settings)
            for learner in learners]


def _arrays_equal(a, b):
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f") for k in a)


# every learner on two agents; on eight (delays: CQ's W1 alone, its fresh waits, several joint states met at
# once) all but JSA, which supports at most five
@pytest.mark.parametrize("algo, mapname", [(a, "tunnel_to_goal") for a in ALL]
                         + [(a, "warehouse_8_delayed") for a in ALL if a != "jsa"])
def test_a_restored_team_plays_the_episodes_the_original_would_have(algo, mapname):
    gridmap = load_map(mapname)
    # on eight agents epsilon decays too; on two CQ marks joint states by episode 45 (seed 1), kept in the state
    decay = ["epsilon_decay_episodes=60"] if gridmap.n_agents > 2 else []
    settings = run_settings(gridmap, ["window=10", "step_cap=100", "reward_step=-1", *decay])
    k, m = 45, 15

    def team():
        return Team(GridWorld(gridmap, settings, seed=world_seed(1, 0)), make_learners(algo, gridmap, settings, 1, 0))

    straight = team()
    expected = table(straight.episode() for _ in range(k + m))
    resumed = team()
    first = [resumed.episode() for _ in range(k)]
    if algo == "cq" and gridmap.n_agents == 2:
        assert any(learner.joint_states() for learner in resumed.learners)
    resumed.learners = _round_trip(resumed.learners, gridmap, settings)
    got = table(first + [resumed.episode() for _ in range(m)])
    np.testing.assert_array_equal(got, expected)
    for a, b in zip(straight.learners, resumed.learners):  # and they end in the same state
        assert _arrays_equal(to_arrays(a), to_arrays(b))


@pytest.mark.parametrize("algo", ["cq", "js", "near", "loc", "indep"])
def test_a_step_whose_update_waits_survives_the_round_trip(algo):
    """Between two steps of an episode (after learn, before the next observe): CQ's and JS's waiting
    update is part of the state."""
    gridmap = load_map("tunnel_to_goal")
    [learner, _] = make_learners(algo, gridmap, SMALL, 1, 0)
    rng = random.Random(5)

    def step(lrn, cell, peer, reward, nxt):
        lrn.observe(cell)
        a = lrn.act({1: peer})
        lrn.learn(reward, nxt, False)
        return a

    def inputs():
        return (rng.randrange(gridmap.n_cells), rng.randrange(gridmap.n_cells), rng.choice([0.0, -1.0, -10.0]),
                rng.randrange(gridmap.n_cells))

    for _ in range(400):
        step(learner, *inputs())
    if algo in ("cq", "js", "near"):
        assert learner.waiting is not None
    [copy] = _round_trip([learner], gridmap, SMALL)
    for _ in range(300):
        x = inputs()
        assert step(copy, *x) == step(learner, *x)
    assert _arrays_equal(to_arrays(copy), to_arrays(learner))


def _cq_arrays():
    gridmap = load_map("tunnel_to_goal")
    team = Team(GridWorld(gridmap, SMALL), make_learners("cq", gridmap, SMALL, 0, 0))
    for _ in range(5):
        team.episode()
    return gridmap, {k: np.asarray(v) for k, v in to_arrays(team.learners[0]).items()}


@pytest.mark.parametrize("field, value, message", [
    ("algo", np.str_("str"), "field algo: unknown algorithm 'str'"),
    ("agent", np.int64(2), "field agent: holds 2, above its greatest value 1"),
    ("agent", np.float64(0.0), "field agent: holds float64 where it must hold integers"),
    ("epsilon", np.float64(np.nan), "field epsilon: holds a value that is not a finite number"),
    ("q_local", np.zeros((3, 4)), r"field q_local: has shape \(3, 4\) where .* make it \(25, 4\)"),
    ("q_local", np.zeros((55, 4), dtype=np.str_), "field q_local: holds <U1 where it must hold floats"),
    ("q_joint.keys", np.array([[0, 1]]), r"field q_joint.keys: has shape \(1, 2\) where .* make it \(any, 3\)"),
    ("rng", np.zeros(625, dtype=np.int64) + 700, "field rng: position 700"),
    ("settings", np.str_(json.dumps({**SMALL.as_dict(), "alpha": 0.5})), "field settings: alpha is 0.5; this run's"),
    ("windows.n1", np.full(100, 11), "field windows.n1: holds 11, above its greatest value 10"),
    ("format", np.int64(3), "field format: is 3"),
])
def test_every_field_is_checked(field, value, message):
    gridmap, arrays = _cq_arrays()
    with pytest.raises(StateError, match=message):
        from_arrays({**arrays, field: value}, gridmap, SMALL)
    without = dict(arrays)
    del without[field]
    with pytest.raises(StateError, match=f"field {field}: missing"):
        from_arrays(without, gridmap, SMALL)

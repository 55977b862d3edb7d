"""SuperSuit's wrapper chains take the PettingZoo env in its Box forms: `dtype_v0`, `flatten_v0`,
`pad_observations_v0`, `black_death_v3`, and the vector env (`pettingzoo_env_to_vec_env_v1` +
`concat_vec_envs_v1`) with agents staying at their goals, as the README's example chains them.

SuperSuit 3.11's `black_death_v3` ends an episode only when every agent is both terminated and truncated (its
`(terminations & truncations).all()`, fixed upstream after 3.11), which no agent here ever is: under it the env
ends and the wrapper steps on, which the env refuses with its "after the episode ended" line. So a vector env
takes `agents_stay=True` (nobody leaves, nothing to pad) rather than black_death; black_death keeps its use
for an env whose agents leave, padding them with zeros, within an episode.
"""

import numpy as np
import pytest
import supersuit as ss

from cq_ros.envs.pettingzoo_env import GridWorldEnv
from cq_ros.settings import Settings


def chain(env):
    return ss.flatten_v0(ss.dtype_v0(ss.pad_observations_v0(env), np.float32))


@pytest.mark.parametrize("observation, encoding, width", [("local", "onehot", 9), ("local", "coords", 2),
                                                           ("joint", "onehot", 18), ("joint", "coords", 4)])
def test_the_vector_env_plays_whole_episodes_and_resets(observation, encoding, width):
    env = GridWorldEnv("grid_game_2", Settings(step_cap=6), observation=observation, encoding=encoding,
                       agents_stay=True)
    vec = ss.concat_vec_envs_v1(ss.pettingzoo_env_to_vec_env_v1(chain(env)), 2, num_cpus=0,
                                base_class="gymnasium")
    obs, _ = vec.reset(seed=0)
    assert obs.shape == (4, width) and obs.dtype == np.float32  # 2 envs x 2 agents, one row each
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(20):
        obs, rewards, terms, truncs, infos = vec.step(rng.integers(4, size=vec.num_envs))
        assert obs.shape == (4, width) and rewards.shape == (4,)
        ends += int((terms | truncs).all())
    assert ends >= 3  # at most 6 steps an episode: each of the 20 steps' ends was followed by a reset
    vec.close()


def test_the_chains_observations_are_the_envs_flattened():
    env = GridWorldEnv("grid_game_2", observation="joint", encoding="onehot", agents_stay=True)
    wrapped = chain(env)
    obs, _ = wrapped.reset(seed=0)
    assert obs["agv1"].shape == (18,) and obs["agv1"].reshape(2, 9).argmax(axis=1).tolist() == env.world.cells


def test_black_death_pads_an_agent_at_its_goal_with_zeros():
    env = GridWorldEnv("grid_game_2", encoding="onehot")
    wrapped = ss.black_death_v3(env)
    wrapped.reset(seed=0)
    for a1 in (1, 0, 0, 1):  # agv1 home after three steps (tests/test_pettingzoo_env.py); one step more
        obs, rewards, *_ = wrapped.step({"agv1": a1, "agv2": 1})
    assert env.agents == ["agv2"] and sorted(obs) == ["agv1", "agv2"]
    assert not obs["agv1"].any() and rewards["agv1"] == 0.0 and obs["agv2"].sum() == 1.0


def test_black_death_steps_past_the_end_and_the_env_says_so():
    env = GridWorldEnv("grid_game_2", Settings(step_cap=2), encoding="onehot")
    wrapped = ss.black_death_v3(env)
    wrapped.reset(seed=0)
    for _ in range(2):
        wrapped.step({"agv1": 1, "agv2": 1})
    with pytest.raises(RuntimeError, match="after the episode ended"):
        wrapped.step({"agv1": 1, "agv2": 1})

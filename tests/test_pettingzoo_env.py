"""The world passes PettingZoo's own API and seed tests, in parallel and through its AEC wrapper, and its
dynamics are GridWorld's."""

import warnings

import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test
from pettingzoo.utils.conversions import parallel_to_aec

from cq_ros.gridmap import load_map
from cq_ros.envs.pettingzoo_env import GridWorldEnv
from cq_ros.settings import Settings
from cq_ros.world import GridWorld


@pytest.mark.parametrize("observation", ["local", "joint"])
@pytest.mark.parametrize("name", ["grid_game_2", "tunnel_to_goal", "isr", "warehouse_8"])
def test_parallel_api(name, observation):
    parallel_api_test(GridWorldEnv(name, Settings(step_cap=200), observation=observation), num_cycles=300)


# A paper map and a generated warehouse, each seen both ways.
PETTINGZOO_CASES = [(name, observation) for name in ("tunnel_to_goal", "warehouse_8")
                    for observation in ("local", "joint")]


@pytest.mark.parametrize("name, observation", PETTINGZOO_CASES)
def test_pettingzoo_tests_pass(name, observation):
    """PettingZoo only warns when an observation is not a value of its space, so those warnings fail here."""
    def make():
        return GridWorldEnv(name, Settings(step_cap=200), observation=observation, render_mode="ansi")

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        parallel_api_test(make(), num_cycles=300)
        parallel_seed_test(make)
        api_test(parallel_to_aec(make()), num_cycles=300)
    # Left alone, as advice that does not fit us: agent names (ours are agv1.. as on the ROS wire), Box or
    # Discrete spaces (the joint cells are MultiDiscrete) and a heuristic meant for images (cell 0 is a cell
    # like any other).
    allowed = ("agents to be named", "probably should be gymnasium.spaces", "array is all zeros")
    assert [str(w.message) for w in caught if not any(a in str(w.message) for a in allowed)] == []


@pytest.mark.parametrize("observation", ["local", "joint"])
def test_observations_and_state_are_numpy_values_of_their_spaces(observation):
    env = GridWorldEnv("warehouse_8", observation=observation)
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(20):
        for agent, value in obs.items():
            space = env.observation_space(agent)
            assert isinstance(value, (np.ndarray, np.integer)) and value.dtype == space.dtype
            assert space.contains(value)
        state = env.state()
        assert isinstance(state, np.ndarray) and env.state_space.contains(state)
        assert state.tolist() == env.world.cells
        obs = env.step({a: int(rng.integers(4)) for a in env.agents})[0]
    if observation == "joint":
        assert all(value.tolist() == env.world.cells for value in obs.values())


def test_actions_are_documented_and_move_as_named():
    from cq_ros.envs import pettingzoo_env
    assert "0 NORTH, 1 EAST, 2 SOUTH, 3 WEST" in pettingzoo_env.__doc__
    env = GridWorldEnv("grid_game_2")
    env.reset()
    start = env.world.map.cells[env.world.cells[0]]
    env.step({"agv1": 1, "agv2": 1})  # agv1 EAST from (2,0)
    assert env.world.map.cells[env.world.cells[0]] == (start[0], start[1] + 1)


def test_render_mode_is_honoured():
    env = GridWorldEnv("tunnel_to_goal")
    env.reset()
    assert env.render() is None
    with pytest.raises(ValueError, match="render_mode"):
        GridWorldEnv("tunnel_to_goal", render_mode="human")


def test_same_dynamics_as_gridworld():
    env = GridWorldEnv("tunnel_to_goal")
    world = GridWorld(load_map("tunnel_to_goal"))
    env.reset(seed=3)
    world.reset()
    rng = np.random.default_rng(0)
    while env.agents:
        actions = {a: int(rng.integers(4)) for a in env.agents}
        got = env.step(actions)
        want = world.step(actions)
        assert got[1] == want[1] and {a: int(o) for a, o in got[0].items()} == want[0]


def test_agents_leave_at_their_goal_and_bad_actions_are_refused():
    env = GridWorldEnv("grid_game_2")
    env.reset()
    with pytest.raises(ValueError, match="action 7 of agv1"):
        env.step({"agv1": 7, "agv2": 0})
    # agv1 starts at (2,0), goal (0,1): EAST, NORTH, NORTH while agv2 bumps the east wall.
    for a1 in (1, 0, 0):
        _, rewards, terms, _, _ = env.step({"agv1": a1, "agv2": 1} if "agv1" in env.agents else {"agv2": 1})
    assert terms["agv1"] and rewards["agv1"] == Settings().reward_goal
    assert env.agents == ["agv2"]


def test_render_draws_each_agent_at_its_cell():
    env = GridWorldEnv("tunnel_to_goal", render_mode="ansi")
    env.reset()
    lines = env.render().splitlines()
    for i, cell in enumerate(env.world.cells):
        row, col = env.world.map.cells[cell]
        assert lines[2 * row + 1][2 * col + 1] == str(i + 1)


def test_without_settings_the_env_takes_the_maps_defaults():
    assert GridWorldEnv("warehouse_8").world.rewards.step == -1.0  # warehouse_8's `set reward_step=-1`
    assert GridWorldEnv("warehouse_8", Settings()).world.rewards.step == 0.0

"""The world passes PettingZoo's own API test, and its dynamics are GridWorld's."""

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from cq_ros.gridmap import load_map
from cq_ros.envs.pettingzoo_env import GridWorldEnv
from cq_ros.settings import Settings
from cq_ros.world import GridWorld


@pytest.mark.parametrize("observation", ["local", "joint"])
@pytest.mark.parametrize("name", ["grid_game_2", "tunnel_to_goal", "isr", "warehouse_8"])
def test_parallel_api(name, observation):
    parallel_api_test(GridWorldEnv(name, Settings(step_cap=200), observation=observation), num_cycles=300)


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
        assert got[1] == want[1] and got[0] == want[0]


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
    env = GridWorldEnv("tunnel_to_goal")
    env.reset()
    lines = env.render().splitlines()
    for i, cell in enumerate(env.world.cells):
        row, col = env.world.map.cells[cell]
        assert lines[2 * row + 1][2 * col + 1] == str(i + 1)


def test_without_settings_the_env_takes_the_maps_defaults():
    assert GridWorldEnv("warehouse_8").world.rewards.step == -1.0  # warehouse_8's `set reward_step=-1`
    assert GridWorldEnv("warehouse_8", Settings()).world.rewards.step == 0.0

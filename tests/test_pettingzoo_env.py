"""The world passes PettingZoo's own API and seed tests, in parallel and through its AEC wrapper, in each
observation form and with agents leaving or staying at their goals; its dynamics are GridWorld's."""

import warnings

import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test
from pettingzoo.utils.conversions import parallel_to_aec

from gymnasium import spaces

from cq_ros.envs.pettingzoo_env import GridWorldEnv
from cq_ros.gridmap import agent_glyph, lattice, load_map
from cq_ros.lab.render import Frame, Picture
from cq_ros.mapgen.warehouse import warehouse_map
from cq_ros.settings import Settings
from cq_ros.world import GridWorld


@pytest.mark.parametrize("observation", ["local", "joint"])
@pytest.mark.parametrize("name", ["grid_game_2", "tunnel_to_goal", "isr", "warehouse_8"])
def test_parallel_api(name, observation):
    parallel_api_test(GridWorldEnv(name, Settings(step_cap=200), observation=observation), num_cycles=300)


# A paper map and a generated warehouse, each seen both ways; the Box forms and agents staying on one of them.
PETTINGZOO_CASES = [(name, observation, "index", False) for name in ("tunnel_to_goal", "warehouse_8")
                    for observation in ("local", "joint")] + [
    ("tunnel_to_goal", observation, encoding, stay) for observation in ("local", "joint")
    for encoding, stay in (("onehot", False), ("coords", True), ("index", True))]


@pytest.mark.parametrize("name, observation, encoding, agents_stay", PETTINGZOO_CASES)
def test_pettingzoo_tests_pass(name, observation, encoding, agents_stay):
    """PettingZoo only warns when an observation is not a value of its space, so those warnings fail here."""
    def make():
        return GridWorldEnv(name, Settings(step_cap=200), observation=observation, render_mode="ansi",
                            encoding=encoding, agents_stay=agents_stay)

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


@pytest.mark.parametrize("encoding", ["index", "onehot", "coords"])
@pytest.mark.parametrize("observation", ["local", "joint"])
def test_observations_and_state_are_numpy_values_of_their_spaces(observation, encoding):
    env = GridWorldEnv("warehouse_8", observation=observation, encoding=encoding)
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
    if observation == "joint" and encoding == "index":
        assert all(value.tolist() == env.world.cells for value in obs.values())


def test_the_box_forms_say_where_each_agent_is():
    m = load_map("warehouse_8")
    onehot = GridWorldEnv(m, encoding="onehot", observation="joint")
    coords = GridWorldEnv(m, encoding="coords")
    seen, mine = onehot.reset(seed=0)[0]["agv2"], coords.reset(seed=0)[0]["agv2"]
    assert isinstance(onehot.observation_space("agv1"), spaces.Box) and seen.shape == (m.n_agents, m.n_cells)
    assert seen.argmax(axis=1).tolist() == list(m.starts) and seen.sum() == m.n_agents
    row, col = m.cells[m.starts[1]]
    assert mine.tolist() == pytest.approx([row / (m.height - 1), col / (m.width - 1)])
    with pytest.raises(ValueError, match="encoding must be one of"):
        GridWorldEnv(m, encoding="image")


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


def test_agents_stay_at_their_goal_with_a_no_op_until_the_episode_ends():
    env = GridWorldEnv("grid_game_2", agents_stay=True)
    env.reset()
    for a1 in (1, 0, 0):  # agv1 home as above; agv2 bumps the east wall
        obs, rewards, terms, truncs, infos = env.step({"agv1": a1, "agv2": 1})
    assert infos["agv1"]["at_goal"] and not terms["agv1"] and env.agents == ["agv1", "agv2"]
    goal = env.world.cells[0]
    obs, rewards, terms, truncs, infos = env.step({"agv1": 2, "agv2": 1})  # agv1's SOUTH is ignored
    assert env.world.cells[0] == goal and rewards["agv1"] == 0.0 and sorted(obs) == ["agv1", "agv2"]
    assert not any(terms.values()) and not any(truncs.values())


def test_agents_that_stay_all_end_together_terminated_or_truncated():
    env = GridWorldEnv("grid_game_2", Settings(step_cap=5), agents_stay=True)
    env.reset()
    for a1 in (1, 0, 0, 1, 1):
        _, _, terms, truncs, _ = env.step({"agv1": a1, "agv2": 1})
    assert terms == {"agv1": True, "agv2": False} and truncs == {"agv1": False, "agv2": True}
    assert env.agents == []


@pytest.mark.parametrize("agents_stay", [False, True])
def test_a_step_after_the_end_says_the_episode_ended(agents_stay):
    env = GridWorldEnv("grid_game_2", Settings(step_cap=2), agents_stay=agents_stay)
    with pytest.raises(RuntimeError, match=r"reset\(\) was never called"):
        env.step({})
    env.reset()
    env.step({"agv1": 1, "agv2": 1})
    env.step({"agv1": 1, "agv2": 1})
    with pytest.raises(RuntimeError, match=r"after the episode ended \(truncated after step_cap=2 steps\): call reset"):
        env.step({})
    env.reset()
    assert env.step({"agv1": 1, "agv2": 1})[0]


def test_render_draws_each_agent_at_its_cell():
    env = GridWorldEnv("tunnel_to_goal", render_mode="ansi")
    env.reset()
    env.step({a: 1 for a in env.agents})
    lines = env.render().splitlines()
    for i, cell in enumerate(env.world.cells):
        row, col = env.world.map.cells[cell]
        assert lines[2 * row + 1][2 * col + 1] == str(i + 1)
    marked = [ch for line in lines[1::2] for ch in line[1::2] if ch.isdigit()]
    assert sorted(marked) == [str(i + 1) for i in range(env.world.n)]  # where they started shows no mark


@pytest.mark.parametrize("name", ["warehouse_16", "warehouse_32"])
def test_ansi_draws_every_fleet_with_a_legend(name):
    env = GridWorldEnv(name, render_mode="ansi")
    env.reset(seed=0)
    *drawing, legend = env.render().splitlines()
    n = env.world.n
    assert legend == f"agents: 1-9 agv1-agv9, a-{agent_glyph(n - 1)} agv10-agv{n}"
    for i, cell in enumerate(env.world.cells):
        row, col = env.world.map.cells[cell]
        assert drawing[2 * row + 1][2 * col + 1] == agent_glyph(i)


def test_ansi_names_each_agent_past_the_35th_by_its_cell():
    m = warehouse_map(37)
    env = GridWorldEnv(m, render_mode="ansi")
    env.reset()
    legend = env.render().splitlines()[-1]
    assert legend.startswith("agents: 1-9 agv1-agv9, a-z agv10-agv35; * agv36 at ")
    assert f"* agv37 at {m.cells[env.world.cells[36]]}" in legend


def test_rgb_array_is_the_animations_picture():
    env = GridWorldEnv("grid_game_2", render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    assert first.dtype == np.uint8 and first.ndim == 3 and first.shape[2] == 3
    env.step({"agv1": 1, "agv2": 1})
    moved = env.render()
    assert moved.shape == first.shape and (moved != first).any()
    m = env.world.map
    picture = Picture(lattice(m), tuple(m.cells[g] for g in m.goals), title=m.name)
    picture.show(Frame(0, 1, tuple(m.cells[c] for c in env.world.cells)))
    assert (picture.rgb() == moved).all()


def test_without_settings_the_env_takes_the_maps_defaults():
    assert GridWorldEnv("warehouse_8").world.rewards.step == -1.0  # warehouse_8's `set reward_step=-1`
    assert GridWorldEnv("warehouse_8", Settings()).world.rewards.step == 0.0


@pytest.mark.parametrize("make, error, says", [
    (lambda: GridWorldEnv(None), TypeError, "GridWorldEnv takes a map"),
    (lambda: GridWorldEnv("tunnel_to_goal", settings=["alpha=nan"]), ValueError, "alpha must be in"),
    (lambda: GridWorldEnv("tunnel_to_goal").step([0, 0]), TypeError, "step\\(\\) takes a dict of actions"),
    (lambda: GridWorldEnv("tunnel_to_goal").reset(seed=-1), ValueError, "a seed is a whole number of at least 0"),
    (lambda: GridWorldEnv("tunnel_to_goal").reset(seed="abc"), ValueError, "a seed is a whole number"),
    (lambda: GridWorldEnv("tunnel_to_goal").reset(seed=1.5), ValueError, "a seed is a whole number"),
])
def test_a_wrong_argument_is_refused_saying_what_is_wrong(make, error, says):
    with pytest.raises(error, match=says):
        make()


def test_settings_may_be_given_as_overrides_of_the_maps():
    env = GridWorldEnv("warehouse_8", settings={"reward_wall": -2})
    assert env.world.rewards.wall == -2 and env.world.rewards.step == -1  # the map's own reward_step kept

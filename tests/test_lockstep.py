"""The world's lockstep core without ROS: protocol order, timeouts, rejections, and per-episode statistics
equal to the offline engine's for the same joint actions."""

from __future__ import annotations

import math
import random

import pytest
from std_msgs.msg import Float64MultiArray, Int32MultiArray, MultiArrayDimension

from cq_ros.engine import Team
from cq_ros.gridmap import load_map, parse_map
from cq_ros.learners.base import Learner
from cq_ros.settings import Settings, SettingsError
from cq_ros.world import GridWorld
from msgs_spec import NO_ACTION, Action, Feedback, Heartbeat, Position, WorldStats, encode
from node_runtime.parameters import SETTING_NAMES
from node_runtime.parameters import WORLD_PARAMETERS as PARAMETERS
from world_node.lockstep import NO_PROGRESS_STEPS, Lockstep, world_config
from world_node.twin import Identity
from world_node.wire_reading import action_in


class Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def lockstep(gridmap, episodes=3, settings=Settings(), timeout=1.0, log=None, rejoin_time=0.0):
    clock = Clock()
    core = Lockstep(GridWorld(gridmap, settings), episodes, timeout, log=log, clock=clock, rejoin_time=rejoin_time)
    return core, clock


def ticks(core, clock, until):
    """Tick every tick_period from the clock's time to `until`, as the node does: what the ticks returned."""
    start, out = clock.now, []
    for i in range(1, math.ceil((until - start) / core.tick_period - 1e-9) + 1):
        clock.now = min(until, start + i * core.tick_period)
        out += core.on_tick()
    return out


def act(agent, episode, step, action):
    return encode(Action(agent, episode, step, action))


def int_array(label, data, size=4):
    msg = Int32MultiArray()
    msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=size)]
    msg.data = data
    return msg


# A 2x3 corridor: agent 1 walks east along the top row, agent 2 sits below its goal.
CORRIDOR = parse_map("""agent 1: start 0,0  goal 0,2
agent 2: start 1,1  goal 1,2

+-+-+-+
|. . .|
+ + + +
|. . .|
+-+-+-+
""")
EAST, WEST, NORTH = 1, 3, 0


def test_begin_publishes_every_position_before_any_feedback():
    core, _ = lockstep(CORRIDOR)
    out = core.begin()
    assert [type(p) for p in out] == [Position, Position, Feedback, Feedback]
    assert out[0] == Position(1, 0, 0, 0, 0) and out[1] == Position(2, 0, 0, 1, 1)
    assert out[2] == Feedback(1, 0, 0, 0, 0, 0.0) and out[3] == Feedback(2, 0, 0, 1, 1, 0.0)
    assert core.waiting == {1, 2} and (core.episode, core.step) == (0, 0)


def test_step_waits_for_every_acting_agent_then_positions_then_feedback():
    core, _ = lockstep(CORRIDOR)
    core.begin()
    assert action_in(core, 2, act(2, 0, 0, EAST)) == []  # agent 1 still missing
    out = action_in(core, 1, act(1, 0, 0, EAST))
    assert [type(p) for p in out] == [Position, Position, Feedback, Feedback]
    assert out[2] == Feedback(1, 0, 1, 0, 1, 0.0, applied=EAST)
    assert out[3] == Feedback(2, 0, 1, 1, 2, 10.0, done=True, applied=EAST)  # at its goal: no more actions this episode
    assert core.waiting == {1}


def test_only_watched_agents_positions_are_made_and_position_says_where_any_agent_is_now():
    core, _ = lockstep(CORRIDOR)
    assert core.position(1) is None  # no step yet
    core.watched = (2,)
    out = core.begin()
    assert out[0] == Position(2, 0, 0, 1, 1) and [type(p) for p in out] == [Position, Feedback, Feedback]
    core.watched = ()
    action_in(core, 2, act(2, 0, 0, EAST))
    out = action_in(core, 1, act(1, 0, 0, EAST))
    assert [type(p) for p in out] == [Feedback, Feedback]
    # a reader that comes is sent what a watched agent's Position of this step would have said
    assert core.position(1) == Position(1, 0, 1, 0, 1) and core.position(2) == Position(2, 0, 1, 1, 2)


def test_episode_end_sends_stats_then_the_next_episode():
    core, _ = lockstep(CORRIDOR, episodes=2)
    core.begin()
    action_in(core, 1, act(1, 0, 0, EAST))
    action_in(core, 2, act(2, 0, 0, EAST))
    out = action_in(core, 1, act(1, 0, 1, EAST))
    # positions of step 2, the last feedback (only agent 1 was acting), the stats, episode 1 from scratch
    assert [type(p) for p in out] == [Position, Position, Feedback, WorldStats, Position, Position, Feedback,
                                      Feedback]
    assert out[2] == Feedback(1, 0, 2, 0, 2, 10.0, done=True, applied=EAST)
    stats = out[3]
    assert (stats.episode, stats.steps, stats.truncated, stats.collisions, stats.missed_actions,
            stats.returns) == (0, 2, False, 0, 0, (10.0, 10.0))
    assert out[6] == Feedback(1, 1, 0, 0, 0, 0.0)
    action_in(core, 1, act(1, 1, 0, EAST))
    action_in(core, 2, act(2, 1, 0, EAST))
    out = action_in(core, 1, act(1, 1, 1, EAST))
    assert isinstance(out[-1], WorldStats) and core.finished and not core.waiting


def test_step_cap_truncates_every_acting_agent():
    core, _ = lockstep(CORRIDOR, episodes=1, settings=Settings(step_cap=1))
    core.begin()
    action_in(core, 1, act(1, 0, 0, WEST))  # a wall bump: agent 1 stays
    out = action_in(core, 2, act(2, 0, 0, WEST))
    fb = [p for p in out if isinstance(p, Feedback)]
    assert fb == [Feedback(1, 0, 1, 0, 0, -1.0, truncated=True, applied=WEST),
                  Feedback(2, 0, 1, 1, 0, 0.0, truncated=True, applied=WEST)]
    assert out[-1].truncated and core.finished


def test_timeout_lets_the_missing_agent_stay_and_counts_it():
    logs = []
    core, clock = lockstep(CORRIDOR, timeout=2.0, log=logs.append)
    core.begin()
    action_in(core, 1, act(1, 0, 0, EAST))
    assert ticks(core, clock, 1.9) == []  # not yet
    out = ticks(core, clock, 2.0 + core.tick_period)
    fb = {p.agent: p for p in out if isinstance(p, Feedback)}
    assert fb[2] == Feedback(2, 0, 1, 1, 1, Settings().reward_step, applied=NO_ACTION)  # stayed, bumped no wall
    assert fb[1] == Feedback(1, 0, 1, 0, 1, 0.0, applied=EAST)
    assert any("agv2" in line and "stay" in line for line in logs)
    assert action_in(core, 2, act(2, 0, 0, EAST)) == []  # the late answer is stale now
    assert core.drops["stale_step"] == 1
    action_in(core, 1, act(1, 0, 1, EAST))
    out = action_in(core, 2, act(2, 0, 1, EAST))  # both reach their goals
    [stats] = [p for p in out if isinstance(p, WorldStats)]
    assert (stats.steps, stats.missed_actions, stats.returns) == (2, 1, (10.0, 10.0 + Settings().reward_step))


def test_missing_agent_blocks_its_cell_like_a_parked_one():
    core, clock = lockstep(CORRIDOR, episodes=1, timeout=1.0, settings=Settings(step_cap=2, reward_step=-0.5))
    core.begin()
    action_in(core, 2, act(2, 0, 0, NORTH))  # agent 2 to (0, 1); agent 1 misses the step
    past_timeout = 1.0 + 2 * core.tick_period  # judged a tick after it ran out
    fb = {p.agent: p for p in ticks(core, clock, past_timeout) if isinstance(p, Feedback)}
    assert (fb[1].row, fb[1].col, fb[1].reward) == (0, 0, -0.5)
    assert (fb[2].row, fb[2].col, fb[2].reward) == (0, 1, -0.5)
    action_in(core, 1, act(1, 0, 1, EAST))  # agent 1 into agent 2's cell, while agent 2 misses this step
    out = ticks(core, clock, clock.now + past_timeout)
    fb = {p.agent: p for p in out if isinstance(p, Feedback)}
    assert (fb[1].row, fb[1].col, fb[1].reward) == (0, 0, Settings().reward_collision)
    # run into, it pays the collision as both agents of every collision do (a delayed agent too)
    assert (fb[2].row, fb[2].col, fb[2].reward) == (0, 1, Settings().reward_collision)
    stats = out[-1]
    assert (stats.steps, stats.truncated, stats.collisions, stats.missed_actions) == (2, True, 1, 2)


def test_rejected_actions_are_counted_by_kind_and_change_nothing():
    logs = []
    core, _ = lockstep(CORRIDOR, log=logs.append)
    core.begin()
    action_in(core, 1, act(1, 0, 0, EAST))
    action_in(core, 2, act(2, 0, 0, WEST))
    assert (core.episode, core.step) == (0, 1)
    bad = {
        "wrong_type": Float64MultiArray(),
        "wrong_layout": int_array("agent,episode,step,move", [1, 0, 1, 1]),
        "wrong_length": int_array("agent,episode,step,action", [1, 0, 1]),
        "out_of_range": int_array("agent,episode,step,action", [1, -1, 1, 1]),
        "unknown_agent": int_array("agent,episode,step,action", [7, 0, 1, 1]),
        "wrong_agent": act(2, 0, 1, EAST),
        "action_out_of_range": int_array("agent,episode,step,action", [1, 0, 1, 4]),
        "stale_step": act(1, 0, 0, EAST),
        "future_step": act(1, 0, 2, EAST),
        "future_episode": act(1, 1, 0, EAST),
    }
    for kind, msg in bad.items():
        assert action_in(core, 1, msg) == [], kind
        assert core.drops[kind] == 1, kind
    assert core.waiting == {1, 2}
    assert action_in(core, 1, act(1, 0, 1, EAST)) == []
    assert action_in(core, 1, act(1, 0, 1, WEST)) == []  # a second answer is ignored, not applied
    assert core.unexpected_actions == 1
    out = action_in(core, 2, act(2, 0, 1, EAST))
    assert Feedback(1, 0, 2, 0, 2, 10.0, done=True, applied=EAST) in out  # the first answer counted
    counters = core.counters()
    assert all(counters[f"dropped.{kind}"] == 1 for kind in bad)
    assert counters["ignored.unexpected_action"] == 1
    # logged once per kind
    assert sum("wrong_layout" in line for line in logs) == 1


def test_stale_episode_and_actions_before_begin():
    core, _ = lockstep(CORRIDOR, episodes=2)
    assert action_in(core, 1, act(1, 0, 0, EAST)) == []  # before begin: nothing is expected yet
    assert core.drops["future_episode"] == 1
    core.begin()
    action_in(core, 1, act(1, 0, 0, EAST))
    action_in(core, 2, act(2, 0, 0, EAST))
    action_in(core, 1, act(1, 0, 1, EAST))  # episode 0 over
    assert core.episode == 1
    action_in(core, 1, act(1, 0, 2, EAST))
    assert core.drops["stale_episode"] == 1


def test_an_agent_starting_at_its_goal_gets_done_at_step_zero():
    gm = parse_map("""agent 1: start 0,0  goal 0,2
agent 2: start 1,2  goal 1,2

+-+-+-+
|. . .|
+ + + +
|. . .|
+-+-+-+
""")
    core, _ = lockstep(gm, episodes=1)
    out = core.begin()
    assert Feedback(2, 0, 0, 1, 2, 0.0, done=True) in out and core.waiting == {1}


def test_an_episode_over_at_step_zero_is_reported_and_skipped():
    gm = parse_map("""agent 1: start 0,0  goal 0,0

+-+-+
|. .|
+-+-+
""")
    core, _ = lockstep(gm, episodes=3)
    out = core.begin()
    stats = [p for p in out if isinstance(p, WorldStats)]
    assert [s.steps for s in stats] == [0, 0, 0] and core.finished


class Scripted(Learner):
    """Random moves from its own seeded RNG: the same sequence however the world is driven."""

    name = "scripted"

    def observe(self, cell):
        return ()

    def act(self, peer_cells):
        return self.rng.randrange(4)

    def learn(self, reward, next_cell, done):
        pass

    def state_count(self):
        return 0


@pytest.mark.parametrize("map_name", ["tunnel_to_goal", "grid_game_2", "tunnel_to_goal_3"])
def test_statistics_equal_the_offline_team_for_the_same_moves(map_name):
    gridmap = load_map(map_name)
    settings = Settings(step_cap=150)

    def scripted():
        return [Scripted(i, gridmap, settings, 100 + i) for i in range(gridmap.n_agents)]

    offline = Team(GridWorld(gridmap, settings), scripted())
    expected = [offline.episode() for _ in range(8)]
    learners = scripted()
    core, _ = lockstep(gridmap, episodes=8, settings=settings)
    order = random.Random(3)
    stats = []
    out = core.begin()
    while not core.finished:
        stats += [p for p in out if isinstance(p, WorldStats)]
        agents = sorted(core.waiting)
        order.shuffle(agents)  # the order actions arrive in does not matter
        out = []
        for k in agents:
            out += action_in(core, k, act(k, core.episode, core.step, learners[k - 1].act({})))
    stats += [p for p in out if isinstance(p, WorldStats)]
    assert [(s.steps, s.collisions, s.truncated) for s in stats] == \
        [(e.steps, e.collisions, e.truncated) for e in expected]
    assert [math.fsum(s.returns) for s in stats] == [e.ret for e in expected]


def test_world_config_checks_every_parameter():
    values = {name: default for name, (default, _) in PARAMETERS.items()}
    cfg = world_config(values)
    assert cfg.gridmap.name == "tunnel_to_goal" and cfg.settings == Settings() and cfg.episodes == 500
    assert world_config({**values, "eval_episodes": 3}).total_episodes == 503  # the greedy ones come after
    with pytest.raises(SettingsError, match="parameter map: .*no such map"):
        world_config({**values, "map": "nowhere"})
    with pytest.raises(SettingsError, match="parameter step_timeout must be > 0"):
        world_config({**values, "step_timeout": 0.0})
    with pytest.raises(SettingsError, match="parameter episodes must be >= 1"):
        world_config({**values, "episodes": 0})
    with pytest.raises(SettingsError, match="setting alpha"):
        world_config({**values, "alpha": 2.0})
    assert world_config({**values, "reward_collision": -5.0}).settings.reward_collision == -5.0
    # A setting left out (not given to the node) is the map's default; one given goes over it.
    unset = {k: v for k, v in values.items() if k not in SETTING_NAMES}
    its_own = Settings(reward_step=-1.0, gamma=0.98, epsilon_decay_episodes=1500)  # warehouse_8's `set` lines
    assert world_config({**unset, "map": "warehouse_8"}).settings == its_own
    assert world_config({**unset, "map": "warehouse_8", "reward_step": 0.0}).settings == its_own.with_overrides(
        {"reward_step": 0.0})
    assert world_config({**values, "map": "warehouse_8"}).settings == Settings()  # all given: the map's go under


@pytest.mark.parametrize("name", [n for n, (d, _) in PARAMETERS.items() if isinstance(d, float)])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_world_config_refuses_nan_and_inf_for_every_number(name, bad):
    values = {n: d for n, (d, _) in PARAMETERS.items()}
    with pytest.raises(SettingsError, match=f"{name}"):
        world_config({**values, name: bad})


def test_the_wait_for_a_missing_agent_is_step_timeout_to_a_tick():
    logs = []
    core, clock = lockstep(CORRIDOR, timeout=2.0, log=logs.append)
    assert core.tick_period <= 2.0 / 20
    core.begin()
    assert ticks(core, clock, 2.0) == []  # run out at this tick: judged at the next, after what came meanwhile
    assert ticks(core, clock, 2.0 + core.tick_period) and core.missed_actions == 2
    assert "within step_timeout=2.0 s (waited 2.05 s)" in logs[-1]


def test_a_world_stopped_past_step_timeout_takes_the_actions_waiting_for_it():
    """stopped for 5 s (SIGSTOP) with both actions in its queue, the world's first tick after
    the stop comes before them; the stall is counted, nobody is judged late, and the step is played."""
    core, clock = lockstep(CORRIDOR, timeout=2.0)
    core.begin()
    ticks(core, clock, 0.5)
    clock.now += 5.0
    assert core.on_tick() == []
    action_in(core, 1, act(1, 0, 0, EAST))
    out = action_in(core, 2, act(2, 0, 0, EAST))
    assert [p.applied for p in out if isinstance(p, Feedback)] == [EAST, EAST]
    assert core.missed_actions == 0 and core.counters() == {"stalls": 1}
    assert ticks(core, clock, clock.now + 1.9) == []  # the next step waits its whole step_timeout


def test_the_wait_for_the_agents_before_the_first_step_is_no_stall():
    """A world that waited 12 s for its agents to connect (startup) before its first step counts no stall:
    its step timer starts with the first step."""
    core, clock = lockstep(CORRIDOR, timeout=2.0)
    clock.now += 12.0
    core.begin()
    assert ticks(core, clock, clock.now + 0.5) == []
    assert "stalls" not in core.counters()


def test_a_world_no_agent_acts_in_for_ten_steps_in_a_row_says_it_goes_nowhere():
    """Every acting agent missed NO_PROGRESS_STEPS steps in a row (agents gone, or bound to the world's earlier
    life): `no_progress` says why the run cannot go on. A step the agents acted in starts the count again (one
    agent silent for as long while the other plays: the rule of its own, tested below)."""
    core, clock = lockstep(load_map("grid_game_2"), episodes=1, timeout=1.0, settings=Settings(step_cap=100))
    core.begin()

    def time_out(steps):
        for _ in range(steps):
            ticks(core, clock, clock.now + 1.0 + 2 * core.tick_period)

    time_out(NO_PROGRESS_STEPS - 1)
    assert core.silent_steps == NO_PROGRESS_STEPS - 1 and core.no_progress is None
    for k in (1, 2):  # the agents act: the world is not going nowhere
        action_in(core, k, act(k, 0, core.step, 0))
    assert core.silent_steps == 0
    time_out(NO_PROGRESS_STEPS)
    assert core.no_progress is not None and f"no action from any agent in {NO_PROGRESS_STEPS} steps" in core.no_progress


def test_a_silent_world_waits_as_long_as_a_start_for_an_agent_to_rejoin():
    """An agent restarted mid-run needs as long to join as one starting (startup_timeout, here `rejoin_time`
    12 s): ten silent 1 s steps are not enough to give up on it, twelve are; its action on the way starts the
    count again, seconds included."""
    core, clock = lockstep(load_map("grid_game_2"), episodes=1, timeout=1.0, settings=Settings(step_cap=100),
                           rejoin_time=12.0)
    core.begin()

    def time_out(steps):
        for _ in range(steps):
            ticks(core, clock, clock.now + 1.0 + 2 * core.tick_period)

    time_out(NO_PROGRESS_STEPS + 1)
    assert core.silent_steps == NO_PROGRESS_STEPS + 1 and core.no_progress is None
    for k in (1, 2):
        action_in(core, k, act(k, 0, core.step, 0))
    assert (core.silent_steps, core.silent_for) == (0, 0.0)
    time_out(11)
    assert core.no_progress is None and 11.0 <= core.silent_for < 12.0
    time_out(1)
    assert core.no_progress is not None and "in 12 steps in a row" in core.no_progress, core.no_progress
    assert "startup_timeout=12 s at least" in core.no_progress


def test_heartbeats_count_up_and_say_where_the_world_is_and_who_it_is():
    core, _ = lockstep(CORRIDOR)
    core.identity = Identity(started=1_796_400_000, ticket=77)
    assert core.heartbeat() == Heartbeat(1, 0, 0, stepping=0, started=1_796_400_000, ticket=77)  # waiting
    core.begin()
    assert core.heartbeat() == Heartbeat(2, 0, 0, stepping=1, started=1_796_400_000, ticket=77)  # its first step
    action_in(core, 1, act(1, 0, 0, EAST))
    action_in(core, 2, act(2, 0, 0, EAST))
    assert core.heartbeat() == Heartbeat(3, 0, 1, stepping=1, started=1_796_400_000, ticket=77)


def test_with_a_key_only_actions_carrying_its_mac_count():
    key = bytes(range(32))
    clock = Clock()
    core = Lockstep(GridWorld(CORRIDOR, Settings()), 1, 1.0, clock=clock, key=key)
    core.begin()
    assert action_in(core, 1, act(1, 0, 0, EAST)) == []  # no MAC: a writer without the key
    assert action_in(core, 1, encode(Action(1, 0, 0, EAST), key=b"other key, same length, 32 bytes")) == []
    assert core.drops["unauthenticated"] == 2 and core.waiting == {1, 2}
    action_in(core, 1, encode(Action(1, 0, 0, EAST), key=key))
    assert core.waiting == {2}


def test_a_new_incarnation_binds_only_with_an_action_of_the_step_collected():
    """The node decodes and checks the seal (world_node.wire_reading); the core judges the step and only then
    binds a new incarnation of the agent, as a decoder binds only with a message every check accepted: a stale
    action of a restarted agent leaves the older incarnation's actions taken, an action of the step replaces it."""
    from msgs_spec.auth import RunKey

    secret = bytes(range(32))
    core = Lockstep(GridWorld(CORRIDOR, Settings()), 1, 1.0, clock=Clock(), key=RunKey(secret, run=7))
    old, new = (RunKey(secret, run=7, incarnation=life) for life in (1, 2))
    core.begin()
    action_in(core, 1, encode(Action(1, 0, 0, EAST), key=old))
    action_in(core, 2, encode(Action(2, 0, 0, WEST), key=old))  # step 1 now, both still acting
    assert core.step == 1 and core.key.held == {1: 1, 2: 1}
    assert action_in(core, 1, encode(Action(1, 0, 0, EAST), key=new)) == []  # stale: no binding
    assert core.drops["stale_step"] == 1 and core.key.held[1] == 1 and core.key.replaced == 0
    action_in(core, 1, encode(Action(1, 0, 1, EAST), key=new))  # of the step: the new incarnation replaces the old
    assert core.key.held[1] == 2 and core.key.replaced == 1 and core.waiting == {2}
    assert action_in(core, 1, encode(Action(1, 0, 1, EAST), key=old)) == [] and core.twin is not None


def test_the_core_takes_payloads():
    """Lockstep sees no bytes: an Action is what it takes, and it judges the stamp itself, counting a wrong one
    under the kind and topic a decoder would have named."""
    core, _ = lockstep(CORRIDOR)
    core.begin()
    assert core.on_action(Action(1, 0, 1, EAST)) == [] and core.drops["future_step"] == 1
    assert core.drops.by_source == {"agv1/action": 1}
    assert core.on_action(Action(1, 0, 0, EAST)) == [] and core.waiting == {2}

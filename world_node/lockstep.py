"""The world's side of the lockstep protocol (msgs_spec/README.md, "Protocol"), without ROS.

`Lockstep` owns a `cq_ros.world.GridWorld` and decides everything the world node does: which actions it
accepts, when a step is complete or timed out, and what goes out afterwards, in protocol order (the Position
of every agent in `watched`, then the Feedback of the agents that were acting, then WorldStats when the episode
is over, then the next episode's step 0). It takes payloads, never bytes: the node decodes each action
(world_node.wire_reading) and hands it an `Action`, or the refusal to count in its one `DropCounter`; the core
judges what needs its state, the step it collects (stale_*, future_*, counted there too) and who is asked. The
node only moves messages between ROS and this object, so the protocol is tested without a ROS graph
(tests/test_lockstep.py) and a run equals `cq_ros.engine.run` step for step.

A missing action past `step_timeout`: the agent stays where it is, for that step only, as a delayed agent
does (cq_ros.world, "Delays"): anyone moving into its cell collides with it (both get the collision
penalty, counted in the episode's collisions); otherwise it gets `reward_step`, the reward of a step lost.
The warning is logged and the miss counted (`WorldStats.missed_actions`); the agent's next Feedback says no
action of it was applied (`applied` NO_ACTION), so it does not learn from a step it did not play. The wait is
`step_timeout` from the moment the step's feedback went out, in the time the world was awake to hear the
answers (node_runtime.patience: a world stopped and resumed handles the actions waiting in its queue before
it judges anyone late, and counts the stall in `stalls`); the node ticks every `tick_period` (a twentieth
of step_timeout, at most 50 ms).

Every `heartbeat_period` the world sends a `Heartbeat` (`heartbeat()`), whether or not anyone acts, so an
agent waiting at its goal for the episode's end knows the world is alive. With a `key_file` every message
that steers the run is keyed and every action checked (msgs_spec.auth).

One agent, one node. With the key, an agent's actions carry its incarnation; a newer one replaces the one
before (an agent restarted from its checkpoint goes on), and the replaced one's actions are refused
(`other_incarnation`). One that still comes means the replaced node is alive: two nodes act as that agent (a
second node started with its name and the key). Each would steer the run, so the world names it in `twin`
and the node ends the run (exit code `TWIN_EXIT`): never a run that passes for the offline one with two
learners behind one AGV.

No progress. A world whose acting agents all miss NO_PROGRESS_STEPS steps in a row, and for at least
`rejoin_time` (the node's startup_timeout), is alive but goes nowhere (agents that gave up on it, or that
refuse it: a restarted world is another incarnation, which the agents of its earlier life never take for it):
it says so in `no_progress`, and the node ends the run (exit code 1). So does one agent that misses as many
steps for as long while the others play (its process gone and not restarted, its executor stuck, or deaf to its
feedback): `no_progress` names it. The time is there because an agent
restarted mid-run (`cq-ros launch --restart-agents`, a respawning supervisor) needs as long to join as one
starting: on a busy machine that is longer than ten short step timeouts while its peers wait at their goals.

`world_config` turns the node's parameters into a checked `WorldConfig`; a bad value raises `SettingsError`
with one line naming the parameter. The node plays `episodes + eval_episodes` episodes: the agents learn
in the first `episodes` and play their greedy policy in the rest, as `cq_ros.engine.run` then
`greedy_episodes`; for the world they are alike. `run` plays the greedy ones on its own world (it needs
the run no more), whose RNG (used only for delays) goes on from the same state, as the node's one world
does.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping

from cq_ros.engine import world_seed
from cq_ros.gridmap import GridMap
from node_runtime.parameters import MIN_HEARTBEAT_PERIOD, check_numbers, map_and_settings
from cq_ros.settings import Settings, SettingsError
from cq_ros.world import GridWorld
from msgs_spec import (
    FEEDBACK_LAYOUT, NO_ACTION, POSITION_LAYOUT, Action, Bounds, DropCounter, Feedback, Heartbeat, WireError,
    Position, WorldStats, action_topic, agent_namespace, check_sequence,
)
from msgs_spec.auth import RunKey
from node_runtime.parameters import run_key_parameters
from node_runtime.patience import Patience

from .twin import Identity

__all__ = ["TWIN_EXIT", "NO_PROGRESS_STEPS", "MIN_STEP_TIMEOUT", "WorldConfig", "world_config", "Lockstep",
           "world_core"]

TWIN_EXIT = 3  # the world's exit code when two live nodes act as one agent (`Lockstep.twin`)
# Steps in a row that every acting agent missed (each after a whole step_timeout) before the world gives up: no
# agent hears it (they gave up on it, or are bound to its earlier life) and the run would step on for ever.
NO_PROGRESS_STEPS = 10
# The least step_timeout. Below it an action is late whenever its agent's process waits for a core (tens of
# milliseconds on a busy machine), so the world steps without it and the run leaves the offline engine's; at
# 0.0001 s every step timed out.
MIN_STEP_TIMEOUT = 0.1


@dataclass(frozen=True)
class WorldConfig:
    gridmap: GridMap
    settings: Settings
    episodes: int
    seed: int
    run: int
    step_timeout: float
    startup_timeout: float
    min_stats_subscribers: int
    heartbeat_period: float
    key: RunKey | None  # the run's key, sealing with the run's nonce and this world's incarnation

    @property
    def total_episodes(self) -> int:
        """The episodes the world plays: the learning ones, then the greedy ones."""
        return self.episodes + self.settings.eval_episodes


def world_config(values: Mapping[str, Any]) -> WorldConfig:
    """Check the node's parameter values (name -> value, already of the declared ROS type)."""
    check_numbers(values, (("episodes", 1, False), ("seed", 0, False), ("run", 0, False), ("step_timeout", 0, True),
                           ("startup_timeout", 0, True), ("min_stats_subscribers", 0, False),
                           ("heartbeat_period", MIN_HEARTBEAT_PERIOD, False)))
    if values["step_timeout"] < MIN_STEP_TIMEOUT:
        raise SettingsError(f"parameter step_timeout must be at least {MIN_STEP_TIMEOUT} s, got "
                            f"{values['step_timeout']!r}: an action takes longer to come whenever its agent waits "
                            "for a core, and the world would step without it")
    gridmap, settings = map_and_settings(values)
    return WorldConfig(gridmap, settings, values["episodes"], values["seed"], values["run"],
                       values["step_timeout"], values["startup_timeout"], values["min_stats_subscribers"],
                       values["heartbeat_period"], run_key_parameters(values, world=True))



Outbox = list  # of Position | Feedback | WorldStats, to publish in this order


class Lockstep:
    """Steps `world` once every acting agent's action for the current step is in, or the step timed out.

    Agents are numbered 1..N on the wire (index i of the world is agent i + 1). Call `begin()` once every
    agent is connected, then for every message on agv<k>/action `on_action(action, seal)` with its decoded
    Action or `refused(k, error)` (world_node.wire_reading.action_in does either), and `on_tick()` now and then
    (for the timeout); each returns what to publish, in order. `finished` turns true with the last episode's
    WorldStats.
    """

    def __init__(self, world: GridWorld, episodes: int, step_timeout: float, *,
                 log: Callable[[str], Any] | None = None, clock: Callable[[], float] = time.monotonic,
                 key: RunKey | bytes | None = None, rejoin_time: float = 0.0, identity: Identity | None = None):
        self.world = world
        self.identity = identity or Identity(0, 0)  # who this world is to a twin (world_node.twin)
        self.key = key  # the run's key: actions must carry its MAC (None: no authentication)
        self.beats = 0  # heartbeats sent
        self.bounds = Bounds(world.n, world.map.height, world.map.width)
        self.episodes = episodes
        self.step_timeout = step_timeout
        self.drops = DropCounter(log)
        self._log = log or (lambda _msg: None)
        self._clock = clock
        self.episode = -1  # no episode yet: any action is future_episode until begin()
        self.finished = False
        self.waiting: set[int] = set()  # agents whose action for (episode, world.t) has not come
        self.unexpected_actions = 0  # valid, but from an agent not asked (done, or a second answer)
        self.collisions = self.missed_actions = 0  # in the current episode so far
        self.returns: list[float] = []  # of each agent in the current episode so far
        self.extra_counters: dict[str, int] = {}  # counted by the node (second writers in the graph)
        self.twin: str | None = None  # why the run cannot go on: two live nodes act as one agent
        self.no_progress: str | None = None  # why the run cannot go on: no agent has acted for steps
        self.silent_steps = 0  # steps in a row that every acting agent missed
        self.rejoin_time = rejoin_time  # seconds of such silence before `no_progress` too
        self.silent_for = 0.0  # seconds those steps waited, awake (Patience: a stall of the node is no silence)
        self.quiet: dict[int, tuple[int, float]] = {}  # agent -> (steps in a row it missed, their seconds awake)
        # Whose Position goes out each step: every agent's, unless the node says whom someone reads (most steps of a
        # run nobody does, and a Position not made costs nothing); a reader that comes asks `position` for the newest.
        self.watched: tuple[int, ...] = tuple(range(1, world.n + 1))
        self._actions: list[int | None] = []
        self._patience = Patience(step_timeout, self.tick_period, clock)  # the wait for the step's actions

    @property
    def step(self) -> int:
        return self.world.t

    def begin(self) -> Outbox:
        """Start episode 0: every agent's position and step-0 feedback."""
        self._patience.start()  # the wait for the agents to connect was no stall
        return self._next_episode()

    def on_action(self, action: Action, seal: tuple | None = None) -> Outbox:
        """An action decoded from agv<k>/action, k its agent; the step's outcome once it was the last action
        missing. `seal`: what it binds the run's key to (msgs_spec.arrays, ArrayLayout.read), once it is of the
        step collected: a new incarnation of its agent binds only with an action every check accepted."""
        agent, stamp = action.agent, (action.episode, action.step)
        if stamp != (self.episode, self.world.t):
            try:  # stale_* or future_*, as the decoder would name it given the step
                check_sequence(*stamp, self.episode, self.world.t)
            except WireError as e:
                return self.refused(agent, e)
        if seal is not None:
            self.key.accept(*seal)
        if agent not in self.waiting:
            self.unexpected_actions += 1
            if self.unexpected_actions == 1:  # a sender bug, not traffic: once is enough to find it
                self._log(f"ignored {action}: {agent_namespace(agent)} is not acting at this step or "
                          "has answered already (counted as ignored.unexpected_action)")
            return []
        self._actions[agent - 1] = action.action
        self.waiting.discard(agent)
        self.quiet.pop(agent, None)
        if self.waiting:
            return []
        self.silent_steps, self.silent_for = 0, 0.0
        return self._advance()

    def refused(self, agent: int, error: WireError) -> Outbox:
        """A message on agv<agent>/action refused, by its decode or for its stamp: counted by its kind. One of a
        replaced incarnation of the agent means a second live node acts as it (`twin`)."""
        self.drops.record(error, action_topic(agent))
        if self.twin is None and self.drops["other_incarnation"]:  # a replaced incarnation still acts
            self.twin = (f"two live nodes act as {agent_namespace(agent)}: actions of its replaced "
                         "incarnation still come after a newer one's (a second node started with its name "
                         "and the run's key?)")
            self.waiting.clear()  # no step more: the node ends the run at its next tick
        return []

    @property
    def tick_period(self) -> float:
        """How often to call on_tick: a step times out at most this late."""
        return min(self.step_timeout / 20, 0.05)

    def on_tick(self) -> Outbox:
        """Call every `tick_period`: past `step_timeout` the agents still missing stay, and the world steps."""
        if not self.waiting or not self._patience.expired():
            return []
        waited = self._patience.waited
        missing = sorted(self.waiting)
        self.missed_actions += len(missing)
        acting = sum(1 for done in self.world.done if not done)
        silent = len(missing) == acting
        self.silent_steps = self.silent_steps + 1 if silent else 0
        self.silent_for = self.silent_for + waited if silent else 0.0
        names = ", ".join(agent_namespace(k) for k in missing)
        limits = f"step_timeout={self.step_timeout} s each, startup_timeout={self.rejoin_time:g} s at least"
        if self.silent_steps >= NO_PROGRESS_STEPS and self.silent_for >= self.rejoin_time and self.no_progress is None:
            self.no_progress = (f"no action from any agent in {self.silent_steps} steps in a row, "
                                f"{self.silent_for:.1f} s ({limits}; acting: {names}): they are gone, stuck or take "
                                "no feedback, or they gave up on this world or refuse it (a world restarted mid-run "
                                "is another incarnation to them)")
        for k in missing:
            steps, seconds = self.quiet.get(k, (0, 0.0))
            self.quiet[k] = steps, seconds = steps + 1, seconds + waited
            if steps >= NO_PROGRESS_STEPS and seconds >= self.rejoin_time and self.no_progress is None:
                self.no_progress = (f"no action from {agent_namespace(k)} in {steps} steps in a row, {seconds:.1f} s "
                                    f"({limits}) while the others play: it is gone, stuck, or takes no feedback")
        self._log(f"episode {self.episode} step {self.step}: no action from "
                  f"{names} within step_timeout={self.step_timeout} s "
                  f"(waited {waited:.2f} s); they stay for this step")
        self.waiting.clear()
        return self._advance()

    def position(self, agent: int) -> Position | None:
        """Where `agent` is now, as its newest Position said or would have said; None before the first step."""
        if self.episode < 0:
            return None
        w = self.world
        return POSITION_LAYOUT.new(agent, self.episode, w.t, *w.map.cells[w.cells[agent - 1]])

    def heartbeat(self) -> Heartbeat:
        """The next heartbeat: where the world is (episode 0, step 0 before the first step), and who it is."""
        self.beats += 1
        me, stepping = self.identity, self.episode >= 0
        return Heartbeat(self.beats, max(self.episode, 0), self.step if stepping else 0, int(stepping), me.started,
                         me.ticket)

    def counters(self) -> dict[str, int]:
        """Monotonic counters for WorldStats: messages dropped by kind, actions ignored, and `extra` (the
        node's: second writers seen in the graph)."""
        out = self.drops.as_counters()
        if self.unexpected_actions:
            out["ignored.unexpected_action"] = self.unexpected_actions
        if self._patience.stalls:
            out["stalls"] = self._patience.stalls
        replaced = getattr(self.key, "replaced", 0)
        if replaced:  # an agent's actions came from a new incarnation: it restarted (or has a twin)
            out["replaced_incarnations"] = replaced
        out.update(self.extra_counters)
        return out

    # -- the steps of the protocol ---------------------------------------------------------------------

    def _advance(self) -> Outbox:
        w = self.world
        acting = [i + 1 for i in range(w.n) if not w.done[i]]
        rewards = w.step_joint(self._actions)  # a missing action (None): the agent stays
        self.collisions += w.last_collisions
        self.returns = [r + x for r, x in zip(self.returns, rewards)]
        out = self._positions()
        cap = w.capped
        out += [self._feedback(k - 1, rewards[k - 1], cap, self._actions[k - 1]) for k in acting]
        if w.over:
            out.append(self._episode_stats())
            out += self._next_episode()
        else:
            self._collect()
        return out

    def _next_episode(self) -> Outbox:
        """Reset for the next episode (skipping any that is over at step 0: every agent starts at its goal)."""
        w = self.world
        out: Outbox = []
        while self.episode + 1 < self.episodes:
            self.episode += 1
            w.reset_joint()
            self.collisions, self.missed_actions = 0, 0
            self.returns = [0.0] * w.n
            self._episode_started = self._clock()
            out += self._positions()
            out += [self._feedback(i, 0.0, False) for i in range(w.n)]
            if not w.finished:
                self._collect()
                return out
            out.append(self._episode_stats())
        self.finished = True
        return out

    def _collect(self) -> None:
        w = self.world
        self.waiting = {i + 1 for i in range(w.n) if not w.done[i]}
        self._actions = [None] * w.n
        self._patience.restart()

    def _positions(self) -> Outbox:
        return [self.position(k) for k in self.watched]

    def _feedback(self, i: int, reward: float, cap: bool, applied: int | None = None) -> Feedback:
        """Agent i's feedback; `applied`: its action the world applied into this step (None: none came)."""
        w = self.world
        row, col = w.map.cells[w.cells[i]]
        done = w.done[i]
        return FEEDBACK_LAYOUT.new(i + 1, self.episode, w.t, row, col, reward, done, cap and not done,
                                   NO_ACTION if applied is None else applied)

    def _episode_stats(self) -> WorldStats:
        w = self.world
        return WorldStats(episode=self.episode, steps=w.t, truncated=w.truncated, collisions=self.collisions,
                          missed_actions=self.missed_actions, returns=tuple(self.returns),
                          duration_s=self._clock() - self._episode_started, counters=self.counters())


def world_core(values: Mapping[str, Any], log: Callable[[str], Any],
               identity: Identity) -> tuple[WorldConfig, Lockstep]:
    """The world node's configuration and core from its parameter values: its world seeded from the run's seed."""
    cfg = world_config(values)
    world = GridWorld(cfg.gridmap, cfg.settings, seed=world_seed(cfg.seed, cfg.run))
    return cfg, Lockstep(world, cfg.total_episodes, cfg.step_timeout, log=log, key=cfg.key,
                         rejoin_time=cfg.startup_timeout, identity=identity)

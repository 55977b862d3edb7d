"""Every tunable number of an experiment in one flat, typed record: the paper's settings where it gives
them, our choices where it does not (docs/choices.md), each written into every result manifest.

`Settings.with_overrides(["alpha=0.2", ...])` is how the CLI's `--set key=value` and the nodes'
parameters reach it, so a bad key or value is reported the same way everywhere. `run_settings` is the one
place the settings of a run are made: Settings() <- the map's own defaults (its `set` lines) <- a preset the
user names (PRESETS: `paper`, Algorithm 2 as the paper reads) <- the user's, and where the world is then delayed,
CQ's settings for delays (UNDER_DELAYS, the preset `under_delays`) that none of them set.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .gridmap import GridMap


class SettingsError(ValueError):
    """A setting that does not exist or a value of the wrong type or range."""


def setting(default, doc: str):
    """A field of Settings with its description: one source for `cq-ros settings`, the nodes' parameter
    descriptors (node_runtime.parameters) and the docs. A new setting is one more line of this."""
    return field(default=default, metadata={"doc": doc})


@dataclass(frozen=True)
class Settings:
    alpha: float = setting(0.1, "learning rate (the paper's)")
    epsilon: float = setting(0.1, "epsilon-greedy exploration (the paper's: fixed 0.1)")
    epsilon_decay_episodes: int = setting(
        0, "0 keeps epsilon fixed (the paper's); N > 0 lowers it linearly from `epsilon` after each episode, to 0 "
           "from episode N on, so that exploration stops (not in the paper)")
    window: int = setting(60, "CQ's window size: samples in W1 and in W2 (the paper's)")
    gamma: float = setting(0.9, "discount (not in the paper)")
    significance: float = setting(0.05, "significance level of both of CQ's t-tests (not in the paper)")
    reward_step: float = setting(0.0, "each agent's own reward per step (not in the paper; warehouses: -1)")
    reward_wall: float = setting(-1.0, "reward for bumping into a wall (the agent stays; not in the paper)")
    reward_collision: float = setting(-10.0, "reward for a collision (the agents stay; not in the paper)")
    reward_goal: float = setting(10.0, "reward for reaching the goal (not in the paper)")
    conf_init: float = setting(1.0, "CQ's confidence in a newly marked joint state (not in the paper)")
    conf_up: float = setting(0.5, "CQ's confidence rise when a marked joint state is met (at most conf_max)")
    conf_down: float = setting(0.02, "CQ's confidence fall when its local state is met without the joint state")
    conf_max: float = setting(10.0, "CQ's highest confidence in a joint state")
    conf_drop: float = setting(0.0, "a marked joint state whose confidence falls below this is dropped")
    cq_bootstrap_acted: int = setting(
        1, "CQ's bootstrap (ours; 0 is the paper's): 0, every update bootstraps from Q_k of the next cell, since "
           "the agent cannot know yet whether it will act on a joint state there; 1, the update waits one step "
           "and bootstraps from the row the agent then acts on (Q^j where a joint state is met), so waiting in a "
           "joint state is valued as waiting, not as the free road Q_k of the same cell promises")
    cq_mark_range: int = setting(
        2, "CQ marks joint states only with the peers at most this many cells away (Manhattan) when a conflict "
           "is detected; 0 marks every peer, as the paper does (which, with two agents, is the one peer there is)")
    cq_mark_colliders: int = setting(
        0, "CQ marks joint states only with the peers that could have collided with the agent at the step of the "
           "conflict (ours; 0 is the paper's): 1, none if the agent moved (a collision leaves it in its cell), else "
           "the peers then at most 1 cell from the cell it moved toward or from its own (with cq_mark_range=2, a "
           "peer two cells off that moved into the same cell too); 0, every peer that cq_mark_range allows; 1 where "
           "the world is delayed (slip or start_hold above 0) unless the map or the user sets it")
    cq_all_met: int = setting(
        1, "several marked joint states of one cell met at once (three or more agents; the paper is silent): 1, "
           "the agent acts on the elementwise minimum of their Q^j rows and updates each; 0, it acts on and "
           "updates the most confident alone, which is blind to the peers the others name")
    cq_w1_alone: int = setting(
        0, "CQ's W1 (ours, 0 is the paper's): 0, the first N rewards of each (cell, action); 1, the rewards of "
           "acting alone there (the world's reward for the move with nobody else, a share slip of them delayed), "
           "so that a conflict present from the start, as under delays, shows as a drop; 1 where the world is "
           "delayed (slip or start_hold above 0) unless the map or the user sets it")
    cq_waits_fresh: int = setting(
        0, "CQ's new joint states (ours, 0 is the paper's): 0, a new Q^j is a copy of Q_k; 1, in the copy each wait "
           "(a move into a wall, which leaves the agent in its cell) is worth at least one step lost plus the free "
           "road, reward_wall + gamma * max Q_k of the cell, since Q_k's waits hold what early exploration left "
           "and, never tried again once exploration stops, would keep the agent from waiting where it must; 1 where "
           "the world is delayed (slip or start_hold above 0) unless the map or the user sets it")
    cq_look_if_decisive: int = setting(
        0, "CQ's looks when greedy (ours, 0 is the paper's): 0, at a cell with marked joint states the agent looks "
           "at every peer they name, every step; 1, at epsilon 0 it does not look where Q_k and every Q^j of the "
           "cell have the same unique best action (and no waiting update lands in them), since what it saw could "
           "not change what it does: it acts on Q_k there, meeting no joint state; 1 where the world is delayed "
           "(slip or start_hold above 0) unless the map or the user sets it")
    cq_collision_conflict: int = setting(
        0, "CQ's conflicts (ours, 0 is the paper's): 0, only the t-tests find one; 1, a reward at or below "
           "reward_collision is one at once, since the world pays that reward for a collision only (where it is "
           "below every other reward, as on every map shipped), and a collision rarer than about 1 in 20 visits of "
           "a (cell, action) never lowers W2's mean enough for the t-test to see it")
    loc_range: int = setting(2, "LoC: active perception is TRUE when a peer is at most this many cells away "
                                "(Manhattan), i.e. close enough to collide this step")
    loc_cost: float = setting(0.1, "LoC: what choosing COORDINATE costs of the learner's reward")
    near_range: int = setting(2, "near (the baseline that watches every peer in range at every step): the range, "
                                 "Manhattan cells")
    step_cap: int = setting(5000, "an episode ends when all agents are at their goals or after this many steps "
                                  "(recorded as truncated)")
    eval_episodes: int = setting(
        20, "after the last episode, this many episodes of the greedy policy (epsilon 0) on a copy of the "
            "learners: what was learnt, without the collisions that exploration causes")
    eval_learning: int = setting(
        1, "what the greedy copy does with what it sees: 1, it goes on learning (t-tests, marking, confidence, "
           "updates); 0, it is frozen and only acts, so the greedy episodes show exactly the policy the learning "
           "episodes left")
    slip: float = setting(
        0.0, "delays (cq_ros.world; 0: deterministic, as in the paper): the probability that an AGV's move fails "
             "at a step (it stays: a person in the aisle, a wheel slipping)")
    start_hold: int = setting(
        0, "delays: the longest hold at the start of an episode (each AGV's first 0..start_hold moves fail, "
           "uniformly drawn: a slow load at the dock)")

    def __post_init__(self):
        _check(0.0 < self.alpha <= 1.0, "alpha", self.alpha, "in (0, 1]")
        _check(0.0 <= self.epsilon <= 1.0, "epsilon", self.epsilon, "in [0, 1]")
        _check(self.epsilon_decay_episodes >= 0, "epsilon_decay_episodes", self.epsilon_decay_episodes, "at least 0")
        _check(self.window >= 2, "window", self.window, "at least 2")
        _check(0.0 <= self.gamma < 1.0, "gamma", self.gamma, "in [0, 1)")
        _check(0.0 < self.significance < 0.5, "significance", self.significance, "in (0, 0.5)")
        _check(self.conf_up >= 0 and self.conf_down >= 0, "conf_up/conf_down", (self.conf_up, self.conf_down),
               "not negative")
        _check(self.conf_drop < self.conf_init <= self.conf_max, "conf_drop < conf_init <= conf_max",
               (self.conf_drop, self.conf_init, self.conf_max), "ordered")
        _check(self.cq_bootstrap_acted in (0, 1), "cq_bootstrap_acted", self.cq_bootstrap_acted, "0 or 1")
        _check(self.cq_all_met in (0, 1), "cq_all_met", self.cq_all_met, "0 or 1")
        _check(self.cq_w1_alone in (0, 1), "cq_w1_alone", self.cq_w1_alone, "0 or 1")
        _check(self.cq_waits_fresh in (0, 1), "cq_waits_fresh", self.cq_waits_fresh, "0 or 1")
        _check(self.cq_mark_colliders in (0, 1), "cq_mark_colliders", self.cq_mark_colliders, "0 or 1")
        _check(self.cq_look_if_decisive in (0, 1), "cq_look_if_decisive", self.cq_look_if_decisive, "0 or 1")
        _check(self.cq_collision_conflict in (0, 1), "cq_collision_conflict", self.cq_collision_conflict, "0 or 1")
        _check(self.cq_mark_range >= 0, "cq_mark_range", self.cq_mark_range, "at least 0")
        _check(self.loc_range >= 1, "loc_range", self.loc_range, "at least 1")
        _check(self.near_range >= 1, "near_range", self.near_range, "at least 1")
        _check(self.step_cap >= 1, "step_cap", self.step_cap, "at least 1")
        _check(0.0 <= self.slip < 1.0, "slip", self.slip, "in [0, 1) (at 1 every move fails: no AGV ever moves)")
        _check(self.start_hold >= 0, "start_hold", self.start_hold, "at least 0")
        _check(self.start_hold < self.step_cap, "start_hold", self.start_hold,
               f"below step_cap={self.step_cap} (a hold that long can keep an AGV at its dock for the whole "
               "episode)")
        _check(self.eval_episodes >= 0, "eval_episodes", self.eval_episodes, "at least 0")
        _check(self.eval_learning in (0, 1), "eval_learning", self.eval_learning, "0 or 1")
        for f in fields(self):
            value = getattr(self, f.name)
            _check(math.isfinite(value), f.name, value, "a finite number")

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)

    @staticmethod
    def describe(name: str) -> str:
        """The description of setting `name` (KeyError for a name that is no setting)."""
        return _FIELDS[name].metadata["doc"]

    def with_overrides(self, pairs: list[str] | dict) -> "Settings":
        """A copy with `key=value` strings (or a dict) applied; SettingsError names a bad key or value."""
        items = pairs.items() if isinstance(pairs, dict) else (split_pair(p) for p in pairs)
        types = {f.name: f.type for f in fields(self)}
        changes = {}
        for key, value in items:
            if key not in types:
                raise SettingsError(f"unknown setting {key!r}; settings are: {', '.join(sorted(types))}")
            changes[key] = coerce(key, value, int if types[key] in ("int", int) else float)
        return dataclasses.replace(self, **changes)


_FIELDS = {f.name: f for f in fields(Settings)}


# CQ's behaviour wherever the world is delayed (slip or start_hold above 0), unless the map or the user sets
# them: under delays a conflict is there from the first episode on, so W1 of the first rewards is no measure of
# being alone, and a new Q^j's waits must be worth waiting; a conflict marks only the peers that could have
# collided with the agent (two AGVs two cells apart that moved into one cell among them), and a greedy agent
# looks only where what it sees can change its action, since on delayed warehouses every joint state is a peer
# asked about at each visit of its cell (docs/choices.md). Without delays, the paper's.
UNDER_DELAYS = {"cq_w1_alone": 1, "cq_waits_fresh": 1, "cq_mark_colliders": 1, "cq_look_if_decisive": 1}

# Algorithm 2 as the paper reads: every choice of CQ's at the paper's value (docs/choices.md); where the paper
# is silent (several joint states met at once), the reading closest to its one Q^j per step. It sets every key
# of UNDER_DELAYS, so a delayed world keeps the paper's CQ too.
PAPER_CQ = {"cq_bootstrap_acted": 0, "cq_all_met": 0, "cq_mark_range": 0, "cq_mark_colliders": 0,
            "cq_w1_alone": 0, "cq_waits_fresh": 0, "cq_look_if_decisive": 0, "cq_collision_conflict": 0}

# The presets a user names (`--preset NAME`), and the one a delayed world applies by itself.
PRESETS = {"paper": PAPER_CQ}
DELAYED = "under_delays"


def run_settings(gridmap: "GridMap | None", overrides: list[str] | Mapping[str, Any] = (),
                 preset: str | None = None) -> Settings:
    """The settings of a run on `gridmap` (run_settings_and_presets says how they are made)."""
    return run_settings_and_presets(gridmap, overrides, preset)[0]


def run_settings_and_presets(gridmap: "GridMap | None", overrides: list[str] | Mapping[str, Any] = (),
                             preset: str | None = None) -> tuple[Settings, dict[str, dict[str, Any]]]:
    """The settings of a run on `gridmap` (None: maps without defaults of their own, as the paper's grid): the
    defaults, then the map's (its `set` lines), then the preset named `preset` (PRESETS), then `overrides`
    (`key=value` strings, or a dict such as a node's parameters that were given); where the result has a delay,
    UNDER_DELAYS for those of them none of these sets. Beside them, {preset name: the settings it set}, for each
    preset that set any (the user's, and `under_delays`): what a run's manifest and `cq-ros experiment` report."""
    given = dict(overrides) if isinstance(overrides, Mapping) else dict(split_pair(p) for p in overrides)
    if preset is not None and preset not in PRESETS:
        raise SettingsError(f"unknown preset {preset!r}; presets are: {', '.join(PRESETS)}")
    named = {k: v for k, v in PRESETS.get(preset, {}).items() if k not in given}
    chosen = {**(gridmap.defaults if gridmap is not None else {}), **named, **given}
    settings = Settings().with_overrides(chosen)
    applied = {preset: named} if named else {}
    if settings.slip > 0 or settings.start_hold > 0:
        delayed = {k: v for k, v in UNDER_DELAYS.items() if k not in chosen}
        settings = settings.with_overrides(delayed)
        applied.update({DELAYED: delayed} if delayed else {})
    return settings, applied


def split_pair(pair: str) -> tuple[str, str]:
    """'key=value' -> (key, value), stripped; SettingsError otherwise."""
    key, sep, value = pair.partition("=")
    if not sep or not key.strip():
        raise SettingsError(f"expected key=value, got {pair!r}")
    return key.strip(), value.strip()


def coerce(key: str, value, kind: type):
    """`value` (a string from the command line, or a number) as an int or a float; SettingsError otherwise."""
    if isinstance(value, bool):
        raise SettingsError(f"setting {key} takes a number, got {value!r}")
    try:
        if kind is int:
            if isinstance(value, float) and not value.is_integer():
                raise ValueError
            return int(value) if not isinstance(value, str) else int(value, 10)
        return float(value)
    except (TypeError, ValueError):
        wanted = "an integer" if kind is int else "a number"
        raise SettingsError(f"setting {key} takes {wanted}, got {value!r}") from None


def _check(ok: bool, name: str, value, what: str) -> None:
    if not ok:
        raise SettingsError(f"setting {name} must be {what}, got {value}")

"""Every tunable number of an experiment in one flat, typed record: the paper's settings where it gives
them, our choices where it does not (docs/choices.md), each written into every result manifest.

`Settings.with_overrides(["alpha=0.2", ...])` is how the CLI's `--set key=value` and the nodes'
parameters reach it, so a bad key or value is reported the same way everywhere. `run_settings` is the one
place the settings of a run are made: Settings() <- the map's own defaults (its `set` lines) <- the user's.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .gridmap import GridMap


class SettingsError(ValueError):
    """A setting that does not exist or a value of the wrong type or range."""


@dataclass(frozen=True)
class Settings:
    # The paper's: learning rate, fixed epsilon-greedy exploration, CQ's window size.
    alpha: float = 0.1
    epsilon: float = 0.1
    # Not in the paper: 0 keeps epsilon fixed (the paper's); N > 0 lowers it linearly from `epsilon` after
    # each episode, to 0 from episode N on, so that exploration stops.
    epsilon_decay_episodes: int = 0
    window: int = 60
    # Not in the paper: discount, significance of both t-tests.
    gamma: float = 0.9
    significance: float = 0.05
    # Rewards (not in the paper): each agent's own reward per step.
    reward_step: float = 0.0
    reward_wall: float = -1.0
    reward_collision: float = -10.0
    reward_goal: float = 10.0
    # CQ's confidence in a marked joint state (not in the paper): starts at conf_init, rises by conf_up
    # (at most conf_max) when the joint state is met, falls by conf_down when its local state is met
    # without it, and the joint state is dropped when it falls below conf_drop.
    conf_init: float = 1.0
    conf_up: float = 0.5
    conf_down: float = 0.02
    conf_max: float = 10.0
    conf_drop: float = 0.0
    # CQ's bootstrap (ours; 0 is the paper's): 0, every update bootstraps from Q_k of the next cell, since
    # the agent cannot know yet whether it will act on a joint state there; 1, the update waits one step
    # and bootstraps from the row the agent then acts on (Q^j where a joint state is met), so waiting in
    # a joint state is valued as waiting, not as the free road Q_k of the same cell promises.
    cq_bootstrap_acted: int = 1
    # CQ marks joint states only with the peers at most this many cells away (Manhattan) when a conflict
    # is detected; 0 marks every peer, as the paper does (which, with two agents, is the one peer there is).
    cq_mark_range: int = 2
    # Several marked joint states of one cell met at once (three or more agents; the paper is silent): 1, the
    # agent acts on the elementwise minimum of their Q^j rows and updates each; 0, it acts on and updates
    # the most confident alone, which is blind to the peers the others name.
    cq_all_met: int = 1
    # CQ's W1 (ours, 0 is the paper's): 0, the first N rewards of each (cell, action); 1, the rewards of acting
    # alone there (the world's reward for the move with nobody else, a share slip of them delayed), so that a
    # conflict present from the start, as under delays, shows as a drop.
    cq_w1_alone: int = 0
    # LoC: active perception is TRUE when a peer is at most this many cells away (Manhattan), i.e.
    # close enough to collide this step; choosing COORDINATE costs this much of the learner's reward.
    loc_range: int = 2
    loc_cost: float = 0.1
    # near (the baseline that watches every peer in range at every step): the range, Manhattan cells.
    near_range: int = 2
    # Episodes end when all agents are at their goals or after this many steps (recorded as truncated).
    step_cap: int = 5000
    # After the last episode, this many episodes of the greedy policy (epsilon 0) on a copy of the
    # learners: what was learnt, without the collisions that exploration causes.
    eval_episodes: int = 20
    # Delays (cq_ros.world; 0: deterministic, as in the paper): the probability that an AGV's move fails at a
    # step (it stays: a person in the aisle, a wheel slipping), and the longest hold at the start of an
    # episode (each AGV's first 0..start_hold moves fail, uniformly drawn: a slow load at the dock).
    slip: float = 0.0
    start_hold: int = 0

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
        _check(self.cq_mark_range >= 0, "cq_mark_range", self.cq_mark_range, "at least 0")
        _check(self.loc_range >= 1, "loc_range", self.loc_range, "at least 1")
        _check(self.near_range >= 1, "near_range", self.near_range, "at least 1")
        _check(self.step_cap >= 1, "step_cap", self.step_cap, "at least 1")
        _check(0.0 <= self.slip <= 1.0, "slip", self.slip, "in [0, 1]")
        _check(self.start_hold >= 0, "start_hold", self.start_hold, "at least 0")
        _check(self.eval_episodes >= 0, "eval_episodes", self.eval_episodes, "at least 0")
        for f in fields(self):
            value = getattr(self, f.name)
            _check(math.isfinite(value), f.name, value, "a finite number")

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)

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


def run_settings(gridmap: "GridMap", overrides: list[str] | Mapping[str, Any] = ()) -> Settings:
    """The settings of a run on `gridmap`: the defaults, then the map's (its `set` lines), then `overrides`
    (`key=value` strings, or a dict such as a node's parameters that were given)."""
    given = dict(overrides) if isinstance(overrides, Mapping) else dict(split_pair(p) for p in overrides)
    return Settings().with_overrides({**gridmap.defaults, **given})


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
        raise SettingsError(f"setting {key} takes {'an integer' if kind is int else 'a number'}, got {value!r}") from None


def _check(ok: bool, name: str, value, what: str) -> None:
    if not ok:
        raise SettingsError(f"setting {name} must be {what}, got {value}")

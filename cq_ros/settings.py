"""Every tunable number of an experiment in one flat, typed record: the paper's settings where it gives
them, our choices where it does not (docs/choices.md), each written into every result manifest.

`Settings.with_overrides(["alpha=0.2", ...])` is how the CLI's `--set key=value` and the nodes'
parameters reach it, so a bad key or value is reported the same way everywhere. `run_settings` is the one
place the settings of a run are made: Settings() <- the map's own defaults (its `set` lines) <- the user's.
No setting changes which algorithm a name plays: the two CQs are two learners (cq_ros.learners).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .gridmap import GridMap


# CQ's confidence in a joint state starts at CONF_INIT when it is marked and the joint state is dropped once it
# falls below CONF_DROP (the paper gives neither); conf_up, conf_down and conf_max move it in between.
CONF_INIT, CONF_DROP = 1.0, 0.0


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
    conf_up: float = setting(0.5, "CQ's confidence rise when a marked joint state is met (at most conf_max)")
    conf_down: float = setting(0.02, "CQ's confidence fall when its local state is met without the joint state")
    conf_max: float = setting(10.0, "CQ's highest confidence in a joint state")
    loc_cost: float = setting(0.1, "LoC: what choosing COORDINATE costs of the learner's reward")
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
        _check(self.conf_max >= CONF_INIT, "conf_max", self.conf_max, f"at least CONF_INIT={CONF_INIT}")
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


def run_settings(gridmap: "GridMap | None", overrides: list[str] | Mapping[str, Any] = ()) -> Settings:
    """The settings of a run on `gridmap` (None: maps without defaults of their own, as the paper's grid): the
    defaults, then the map's (its `set` lines), then `overrides` (`key=value` strings, or a dict such as a
    node's parameters that were given)."""
    given = dict(overrides) if isinstance(overrides, Mapping) else dict(split_pair(p) for p in overrides)
    return Settings().with_overrides({**(gridmap.defaults if gridmap is not None else {}), **given})


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

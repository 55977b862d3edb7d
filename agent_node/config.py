"""An agent node's configuration: its parameters checked into an `AgentConfig`, and the driver that
configuration makes (a fresh learner, or the one in its checkpoint)."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping

from cq_ros.engine import make_learner
from cq_ros.gridmap import GridMap
from cq_ros.learners import LEARNERS
from node_runtime.parameters import check_numbers, map_and_settings
from cq_ros.lab.output import OutputError, probe_folder
from cq_ros.settings import Settings, SettingsError
from msgs_spec.auth import RunKey
from node_runtime.parameters import run_key_parameters

from .checkpoint import load_checkpoint, remove_stale_temporaries
from .driver import AgentDriver, CentralDriver

__all__ = ["AgentConfig", "agent_config", "make_driver"]


@dataclass(frozen=True)
class AgentConfig:
    gridmap: GridMap
    settings: Settings
    algo: str
    agent: int  # 1..N; 0 for the JSA central node
    episodes: int
    seed: int
    run: int
    checkpoint: str
    checkpoint_every: int
    feedback_timeout: float
    peer_linger_steps: int
    min_stats_subscribers: int
    key: RunKey | None  # the run's key; its run nonce given, or learnt from the world's first keyed message
    max_catch_up: int


def agent_config(values: Mapping[str, Any]) -> AgentConfig:
    """Check the node's parameter values (name -> value, already of the declared ROS type)."""
    check_numbers(values, (("episodes", 1, False), ("seed", 0, False), ("run", 0, False),
                           ("checkpoint_every", 1, False), ("feedback_timeout", 0, True),
                           ("peer_linger_steps", 0, False), ("agent_id", 0, False),
                           ("min_stats_subscribers", 0, False), ("max_catch_up", 1, False)))
    algo = values["algo"]
    if algo not in LEARNERS:
        raise SettingsError(f"parameter algo: unknown algorithm {algo!r}; algorithms are: "
                            f"{', '.join(LEARNERS)}")
    gridmap, settings = map_and_settings(values)
    agent = values["agent_id"]
    if LEARNERS[algo].central:
        if agent != 0:  # a second central node would answer for every AGV a second time
            raise SettingsError(f"parameter agent_id: algo {algo} runs one central node for all AGVs; "
                                f"leave agent_id 0, got {agent}")
    elif not 1 <= agent <= gridmap.n_agents:
        raise SettingsError(f"parameter agent_id must be 1..{gridmap.n_agents} (the agents of map "
                            f"{gridmap.name}) for algo {algo}, got {agent}")
    _check_checkpoint_folder(values["checkpoint"])
    return AgentConfig(gridmap, settings, algo, agent, values["episodes"], values["seed"], values["run"],
                       values["checkpoint"], values["checkpoint_every"], values["feedback_timeout"],
                       values["peer_linger_steps"], values["min_stats_subscribers"],
                       run_key_parameters(values, world=False), values["max_catch_up"])


def _check_checkpoint_folder(path: str) -> None:
    """A checkpoint must be writable from the start, not found unwritable at the first save."""
    if not path:
        return
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise SettingsError(f"parameter checkpoint: {path!r}: folder {folder!r} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise SettingsError(f"parameter checkpoint: {path!r}: folder {folder!r} is not writable")
    if os.path.isdir(path):
        raise SettingsError(f"parameter checkpoint: {path!r} is a folder, not a file")
    try:  # a read-only or full file system, which the permission bits do not show (and root passes them)
        probe_folder(folder, "folder")
    except OutputError as e:
        raise SettingsError(f"parameter checkpoint: {path!r}: {e}") from None


def make_driver(cfg: AgentConfig, log: Callable[[str], Any] | None = None,
                clock: Callable[[], float] = time.monotonic) -> AgentDriver | CentralDriver:
    """The driver of a node with this configuration: a fresh learner, or the one in cfg.checkpoint."""
    if cfg.checkpoint:
        removed = remove_stale_temporaries(cfg.checkpoint)
        if removed and log:
            log(f"removed {len(removed)} temporary checkpoint file(s) a save killed mid-write left: "
                f"{', '.join(removed)}")
    resume = bool(cfg.checkpoint) and os.path.exists(cfg.checkpoint)
    if resume:
        learner, episode = load_checkpoint(cfg.checkpoint, cfg.algo, cfg.gridmap, max(cfg.agent - 1, 0),
                                          cfg.settings)
        if log:
            log(f"resuming from {cfg.checkpoint} (episodes up to {episode} learnt)")
    else:
        try:
            learner = make_learner(cfg.algo, cfg.gridmap, cfg.settings, cfg.seed, cfg.run, max(cfg.agent - 1, 0))
        except ValueError as e:  # e.g. jsa on a map with too many agents
            raise SettingsError(f"parameter algo: {e}") from None
    every = cfg.checkpoint_every if cfg.checkpoint else 0
    greedy = cfg.settings.eval_episodes
    if learner.central:
        return CentralDriver(learner, cfg.episodes, eval_episodes=greedy, checkpoint_every=every, resync=resume,
                             log=log, key=cfg.key, clock=clock, max_catch_up=cfg.max_catch_up)
    return AgentDriver(learner, cfg.agent, cfg.episodes, eval_episodes=greedy, linger=cfg.peer_linger_steps,
                       checkpoint_every=every, resync=resume, log=log, key=cfg.key, clock=clock,
                       max_catch_up=cfg.max_catch_up)

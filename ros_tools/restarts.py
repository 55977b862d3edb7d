"""What `cq-ros launch --restart-agents N` does with an agent node that died while the world runs: it is started
again with the same command and resumes from its checkpoint (agent_node.checkpoint), and what that costs is said
and counted. Its checkpoint is loaded here first: the node would say why it cannot resume only in its log, and a
checkpoint it cannot load ends the launch with that one line instead.

The learning a restart loses is the episodes its learner had learnt past the checkpoint it goes back to. A
checkpoint names an episode of the run that wrote it; the one the launch copied in from `start_from` (an earlier
run's, still in place until the node writes its first) is no episode of this run, so a node restarted from it goes
back to before this run's first episode. Which one is in place is told by the file itself (os.replace gives every
checkpoint written a new inode), not by the episode it names; any other checkpoint of an episode past this run's
learning episodes is refused.
"""

from __future__ import annotations

import os
import sys
from typing import Any

from tqdm import tqdm

from agent_node.checkpoint import load_checkpoint
from cq_ros.gridmap import GridMap
from cq_ros.settings import Settings, SettingsError

__all__ = ["Restarts", "file_identity"]


def file_identity(path: str | os.PathLike) -> tuple[int, int, int] | None:
    """What tells one file written at `path` from the next: (device, inode, mtime), or None if there is none."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino, st.st_mtime_ns


class Restarts:
    """The restarts of one launch's agent nodes. `nodes`: node name -> (module, parameters), as
    ros_tools.launch_nodes.node_specs; `started_from`: node name -> file_identity of the checkpoint copied in from
    `start_from`; `learners`: the launch's learner ids. `error` is the exception a checkpoint that cannot be
    resumed from raises (LaunchError: the caller's)."""

    def __init__(self, nodes: dict[str, tuple[str, dict[str, Any]]], algo: str, gridmap: GridMap,
                 settings: Settings, episodes: int, learners: list[int], listener: Any,
                 started_from: dict[str, tuple[int, int, int] | None], error: type[Exception]):
        self.nodes, self.algo, self.gridmap, self.settings = nodes, algo, gridmap, settings
        self.episodes, self.learners, self.listener = episodes, learners, listener
        self.started_from, self.error = started_from, error

    def _resumed_from(self, child: Any) -> int:
        """The episode of this run `child`'s node resumes after: -1 before the first (no checkpoint yet, or the
        one start_from gave); `error` for a checkpoint it cannot load or that is no checkpoint of this run."""
        params = self.nodes[child.name][1]
        path = params["checkpoint"]
        here = file_identity(path)
        if here is None or here == self.started_from.get(child.name):
            return -1
        listener = self.listener
        try:
            return load_checkpoint(path, self.algo, self.gridmap, max(params.get("agent_id", 0) - 1, 0),
                                   self.settings, episodes=self.episodes)[1]
        except SettingsError as e:
            raise self.error(f"{child.describe_exit()} after {len(listener.world)}/{listener.episodes} episodes "
                             f"and cannot restart: {e}") from None

    def loss(self, child: Any) -> str:
        """Record the learning `child`'s restart loses, and say it."""
        resumed, listener = self._resumed_from(child), self.listener
        params = self.nodes[child.name][1]
        ids = self.learners if child.name == "jsa" else [params["agent_id"]]
        # its learner had learnt at least to the checkpoint it wrote, whose statistics may not have come in yet
        heard = max((listener.newest[k].episode for k in ids if k in listener.newest), default=-1)
        learnt = max(min(heard, self.episodes - 1), resumed)
        lost = learnt - resumed
        listener.learning_lost.setdefault(child.name, []).append(
            {"learnt_to": learnt, "resumed_from": resumed, "episodes": lost})
        if resumed >= 0:
            start = f"its checkpoint of episode {resumed}"
        elif child.name in self.started_from:
            start = "the checkpoint it started from (none of this run yet)"
        else:
            start = "a fresh learner (no checkpoint yet)"
        return f"it resumes from {start}: {lost} learning episode{'s'[:lost != 1]} lost"

    def restart(self, child: Any, env: dict) -> None:
        """Start a dead agent node again, saying so and what learning that loses (`loss`); its learners are
        marked restarted in the listener (the episodes they miss meanwhile are written without them)."""
        said = child.describe_exit()
        loss = self.loss(child)
        child.restarts += 1
        ids = self.learners if child.name == "jsa" else [int(child.name.removeprefix("agv"))]
        self.listener.restarted.update(ids)
        child.start(env)
        tqdm.write(f"cq-ros launch: {said} after {len(self.listener.world)}/{self.listener.episodes} episodes: "
                   f"restarted it (restart {child.restarts}, pid {child.process.pid}); {loss}",
                   file=sys.stderr)

"""Agent checkpoints: a pickle of the learner and the last finished episode, written to a temporary file in
the same directory and moved into place with os.replace, so a reader sees the old checkpoint or the new
one, never half of one.

Only learning episodes are checkpointed, so the last checkpoint holds the trained learner, not its greedy
copy. A node restarted from one decodes its first feedback without an expected (episode, step) and resumes
at whatever step the world is at (switching to the greedy copy first if the world is past the learning
episodes). Temporary files a save killed mid-write left behind are removed at start (`make_driver`); a
checkpoint folder that is missing or not writable is a bad parameter (`agent_node.config`).
"""

from __future__ import annotations

import glob
import os
import pickle
import tempfile

from cq_ros.gridmap import GridMap
from cq_ros.learners import Learner
from cq_ros.settings import SettingsError

__all__ = ["save_checkpoint", "checkpoint_bytes", "write_checkpoint", "save_checkpoints", "load_checkpoint",
           "remove_stale_temporaries"]

# 2: CQ learners keep `looking` (cq_look_if_decisive); 3: a learner's settings hold cq_mark_colliders. A learner
# pickled before lacks them.
_CHECKPOINT_FORMAT = 3


def _temporary_prefix(path: str) -> tuple[str, str]:
    """(folder, name prefix) of the temporary files save_checkpoint writes for `path`."""
    return os.path.dirname(os.path.abspath(path)), os.path.basename(path) + "."


def save_checkpoint(path: str | os.PathLike, learner: Learner, episode: int) -> None:
    """Write learner and episode to path atomically: a temporary file beside it, fsync, os.replace."""
    write_checkpoint(path, checkpoint_bytes(learner, episode))


def checkpoint_bytes(learner: Learner, episode: int) -> bytes:
    """The checkpoint of learner after `episode`, pickled: what `write_checkpoint` writes. Taken at once, as
    the learner goes on learning; the writing may follow later (the agent node writes on a thread of its own)."""
    state = {"format": _CHECKPOINT_FORMAT, "algo": learner.name, "map": learner.map.name,
             "agent": learner.agent, "episode": episode, "learner": learner}
    return pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL)


def write_checkpoint(path: str | os.PathLike, data: bytes) -> None:
    """Write checkpoint_bytes' `data` to path atomically: a temporary file beside it, fsync, os.replace."""
    path = os.fspath(path)
    folder, prefix = _temporary_prefix(path)
    fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def save_checkpoints(folder: str | os.PathLike, names: list[str], learners: list[Learner], episode: int) -> None:
    """A checkpoint per learner, `<name>.pkl` in `folder`: learners trained elsewhere (an offline run) for nodes
    of these names to start from (`ros_tools.launch.launch(start_from=folder)`)."""
    for name, learner in zip(names, learners, strict=True):
        save_checkpoint(os.path.join(folder, f"{name}.pkl"), learner, episode)


def remove_stale_temporaries(path: str | os.PathLike) -> list[str]:
    """Remove the temporary files of `path` a save killed mid-write left (a node starting with this checkpoint
    path is its only writer); their names."""
    folder, prefix = _temporary_prefix(os.fspath(path))
    removed = []
    for tmp in sorted(glob.glob(os.path.join(glob.escape(folder), glob.escape(prefix) + "*.tmp"))):
        try:
            os.unlink(tmp)
            removed.append(os.path.basename(tmp))
        except FileNotFoundError:
            pass
    return removed


def load_checkpoint(path: str | os.PathLike, algo: str, gridmap: GridMap, agent: int) -> tuple[Learner, int]:
    """(learner, last episode learnt) from a checkpoint written for this algorithm, map and agent (0-based);
    SettingsError naming the checkpoint parameter otherwise."""
    where = f"parameter checkpoint: {os.fspath(path)!r}"
    try:
        with open(path, "rb") as f:
            state = pickle.load(f)
        learner, episode = state["learner"], state["episode"]
        written_for = (state["format"], state["algo"], state["map"], state["agent"])
    except Exception as e:  # an unreadable file of any kind is a bad parameter value, not a crash
        raise SettingsError(f"{where}: cannot load it: {type(e).__name__}: {e}") from None
    wanted = (_CHECKPOINT_FORMAT, algo, gridmap.name, agent)
    if written_for != wanted:
        what = "format {}, algo {}, map {}, agent index {}"
        raise SettingsError(f"{where} holds {what.format(*written_for)}; this node runs {what.format(*wanted)}")
    return learner, episode

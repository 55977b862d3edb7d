"""Agent checkpoints: the learner's state as named arrays (cq_ros.learners.state) and the last finished
episode, in a numpy .npz read with allow_pickle=False, so a checkpoint is data and loading one runs no code
(docs/design.md#checkpoints). It is written to a temporary file in the same directory and moved into place
with os.replace, so a reader sees the old checkpoint or the new one, never half of one; on loading, every
field is checked against the node's algorithm, map, agent and settings, and a bad one is a bad parameter
naming the file and the field.

Only learning episodes are checkpointed, so the last checkpoint holds the trained learner, not its greedy
copy. A node restarted from one decodes its first feedback without an expected (episode, step) and resumes
at whatever step the world is at (switching to the greedy copy first if the world is past the learning
episodes). Temporary files a save killed mid-write left behind are removed at start (`make_driver`); a
checkpoint folder that is missing or not writable is a bad parameter (`agent_node.config`).

Checkpoints up to format 3 were pickles, which can run any code when loaded: they are refused, naming
`cq-ros checkpoint convert`, which unpickles one (only ever one you trust) into this format.
"""

from __future__ import annotations

import errno
import glob
import io
import os
import pickle
import stat
import tempfile
import zipfile
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any, Callable, Iterator

import numpy as np

from cq_ros.gridmap import GridMap
from cq_ros.lab.output import os_reason
from cq_ros.learners import Learner
from cq_ros.learners.state import StateError, from_arrays, scalar, to_arrays
from cq_ros.settings import Settings, SettingsError
from msgs_spec import INT32_MAX

__all__ = ["save_checkpoint", "checkpoint_bytes", "write_checkpoint", "CheckpointWriter", "save_checkpoints",
           "load_checkpoint", "read_checkpoint", "remove_stale_temporaries", "convert_pickle", "SUFFIX"]

# 1-3: pickles of the learner (2: CQ learners keep `looking`; 3: settings held cq_mark_colliders); 4: an .npz of
# the learner's state as arrays.
_CHECKPOINT_FORMAT = 4
_PICKLE_FORMAT = 3  # the last pickled format, the one `convert_pickle` reads
SUFFIX = ".npz"
# A learner's state is megabytes (warehouse_32's CQ: 1.3 MB): a file whose members unpack to more than this is no
# checkpoint of ours, and is refused before any of it is read into memory (a zip bomb).
_MAX_BYTES = 4 << 30
_MAX_MEMBERS = 256  # arrays in a file: a learner's state is a few dozen (cq_ros.learners.state)
# The greatest episode a checkpoint may name: episodes go on the wire as int32 (msgs_spec), so no run plays more
MAX_EPISODE = INT32_MAX
CONVERT = "cq-ros checkpoint convert"


def _temporary_prefix(path: str) -> tuple[str, str]:
    """(folder, name prefix) of the temporary files save_checkpoint writes for `path`."""
    return os.path.dirname(os.path.abspath(path)), os.path.basename(path) + "."


def save_checkpoint(path: str | os.PathLike, learner: Learner, episode: int) -> None:
    """Write learner and episode to path atomically: a temporary file beside it, fsync, os.replace."""
    write_checkpoint(path, checkpoint_bytes(learner, episode))


def checkpoint_bytes(learner: Learner, episode: int) -> bytes:
    """The checkpoint of learner after `episode`, as .npz bytes: what `write_checkpoint` writes. Taken at once, as
    the learner goes on learning; the writing may follow later (the agent node writes on a thread of its own)."""
    buffer = io.BytesIO()
    np.savez(buffer, checkpoint_format=np.int64(_CHECKPOINT_FORMAT), map=np.str_(learner.map.name),
             episode=np.int64(episode), **to_arrays(learner))
    return buffer.getvalue()


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


class CheckpointWriter:
    """Writes an agent node's checkpoints in order on a thread of its own: the file's fsync took longer than
    taking the learner's state, on the path every other node of a composed process waits on.

    A write that fails is logged and counted in `counters` (`checkpoint_failed.<errno>`) once it is known
    (`count`, run on the executor's thread, which alone touches the counters): a full or read-only disk costs
    the checkpoint, never the learning, which goes on in memory (the next save tries again)."""

    def __init__(self, path: str, thread_name: str, counters: dict[str, int], log: Callable[[str], Any]):
        self.path, self.thread_name, self.counters, self.log = path, thread_name, counters, log
        self._pool: ThreadPoolExecutor | None = None  # made at the first save
        self.writes: list = []  # (episode, concurrent Future) of the writes not counted yet

    def save(self, episode: int, learner: Learner) -> None:
        """Take the learner's state now (it goes on learning) and queue its write."""
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=self.thread_name)
        data = checkpoint_bytes(learner, episode)
        self.writes.append((episode, self._pool.submit(write_checkpoint, self.path, data)))

    def count(self, wait: bool = False) -> bool:
        """Count and log the failures of the writes done (with `wait`: of every write, waiting for them); True if
        any. A failure that is not the disk's is a bug, raised here as it was when the writes were made in place."""
        failed = False
        while self.writes and (wait or self.writes[0][1].done()):
            episode, write = self.writes.pop(0)
            error = write.exception()
            if error is None:
                continue
            if not isinstance(error, OSError):
                raise error
            failed = True
            name = f"checkpoint_failed.{errno.errorcode.get(error.errno, 'other').lower()}"
            self.counters[name] = self.counters.get(name, 0) + 1
            self.log(f"checkpoint {self.path} of episode {episode} not written: {os_reason(error)}; learning goes "
                     f"on (counted as {name})")
        return failed

    def written(self) -> bool:
        return all(write.done() for _, write in self.writes)

    def close(self) -> None:
        """Wait for the writes in flight: a destroyed node's checkpoints are on disk, as when written in place."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)


def save_checkpoints(folder: str | os.PathLike, names: list[str], learners: list[Learner], episode: int) -> None:
    """A checkpoint per learner, `<name>.npz` in `folder`: learners trained elsewhere (an offline run) for nodes
    of these names to start from (`ros_tools.launch.launch(start_from=folder)`)."""
    for name, learner in zip(names, learners, strict=True):
        save_checkpoint(os.path.join(folder, name + SUFFIX), learner, episode)


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


def read_checkpoint(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The arrays of the checkpoint at `path`, read as data only; SettingsError naming the file otherwise (an old
    pickle: with the command that converts it)."""
    where = f"parameter checkpoint: {os.fspath(path)!r}"
    try:
        with _regular_file(path, where) as f:
            head = f.read(2)
            f.seek(0)
            if head[:1] == b"\x80":  # a pickle's protocol opcode: never loaded here
                raise SettingsError(f"{where} is a pickle (checkpoint format {_PICKLE_FORMAT} or older), which could "
                                    f"run code if loaded: if you trust it, convert it with `{CONVERT} "
                                    f"{os.fspath(path)} NEW{SUFFIX}`")
            if head != b"PK":
                raise SettingsError(f"{where} is not a checkpoint (an .npz file)")
            with np.load(f, allow_pickle=False) as npz:
                members = npz.zip.infolist()
                if len(members) > _MAX_MEMBERS:
                    raise SettingsError(f"{where} holds {len(members):,} arrays, more than a checkpoint's "
                                        f"{_MAX_MEMBERS:,}")
                size = sum(member.file_size for member in members)
                if size > _MAX_BYTES:
                    raise SettingsError(f"{where} unpacks to {size:,} bytes, more than a checkpoint's {_MAX_BYTES:,}")
                return {name: npz[name] for name in npz.files}
    except SettingsError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:  # truncated, corrupt, object arrays
        raise SettingsError(f"{where}: cannot read it: {type(e).__name__}: {e}") from None


@contextmanager
def _regular_file(path: str | os.PathLike, where: str) -> Iterator[io.BufferedReader]:
    """`path` opened for reading, refused (SettingsError) unless it is a regular file. Opened without blocking
    and looked at through its descriptor: open() of a FIFO waits for a writer, for ever, and a device (a
    terminal, /dev/zero) never ends; what is looked at is what is read, even if the name is replaced meanwhile."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            kind = {stat.S_IFIFO: "a FIFO", stat.S_IFCHR: "a character device", stat.S_IFBLK: "a block device",
                    stat.S_IFSOCK: "a socket", stat.S_IFDIR: "a folder"}.get(stat.S_IFMT(mode), "not a file")
            raise SettingsError(f"{where} is {kind}, not a regular file: a checkpoint is a file cq-ros wrote")
        os.set_blocking(fd, True)
        f = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    with f:
        yield f


def load_checkpoint(path: str | os.PathLike, algo: str, gridmap: GridMap, agent: int,
                    settings: Settings, episodes: int | None = None) -> tuple[Learner, int]:
    """(learner, last episode learnt) from a checkpoint written for this algorithm, map, agent (0-based) and
    settings; SettingsError naming the checkpoint parameter and the field otherwise. `episodes`: the learning
    episodes of the run that wrote it, when that is known (a node restarted mid-run): a checkpoint of a later
    episode is no checkpoint of that run."""
    where = f"parameter checkpoint: {os.fspath(path)!r}"
    arrays = read_checkpoint(path)
    try:
        fmt = scalar(arrays, "checkpoint_format", "i")
        if fmt != _CHECKPOINT_FORMAT:
            raise StateError("checkpoint_format", f"is {fmt}; this version reads format {_CHECKPOINT_FORMAT}")
        episode = scalar(arrays, "episode", "i", 0, MAX_EPISODE)
        if episodes is not None and episode >= episodes:
            raise StateError("episode", f"is {episode}, beyond this run's {episodes} learning episodes "
                                        f"(0..{episodes - 1}): not a checkpoint of this run")
        saved_map = scalar(arrays, "map", "U")
        if saved_map != gridmap.name:  # before the shapes, which would only say that less plainly
            raise StateError("map", f"is {saved_map}; this node runs map {gridmap.name}")
        learner = from_arrays(arrays, gridmap, settings)
        if (learner.name, learner.agent) != (algo, agent):
            raise SettingsError(f"{where} holds algo {learner.name}, agent index {learner.agent}; this node runs "
                                f"algo {algo}, agent index {agent}")
    except StateError as e:
        raise SettingsError(f"{where}: {e}") from None
    return learner, episode


def convert_pickle(old: str | os.PathLike, new: str | os.PathLike) -> tuple[str, int]:
    """Write the pickled checkpoint `old` (format 3) as a checkpoint of this format at `new`: (algorithm,
    episode). Unpickling runs whatever code the file holds: only for a file you trust."""
    with open(old, "rb") as f:
        state = pickle.load(f)  # noqa: S301 (the one place a pickle is read, on the user's word)
    if not isinstance(state, dict) or state.get("format") != _PICKLE_FORMAT:
        found = state.get("format") if isinstance(state, dict) else type(state).__name__
        raise ValueError(f"{os.fspath(old)}: a pickled checkpoint of format {found}; only format {_PICKLE_FORMAT} "
                         f"converts (an older one lacks settings this version needs)")
    learner, episode = state["learner"], state["episode"]
    if not isinstance(learner, Learner) or not isinstance(episode, int) or episode < 0:
        raise ValueError(f"{os.fspath(old)}: holds no learner and episode")
    save_checkpoint(new, learner, episode)
    return learner.name, episode

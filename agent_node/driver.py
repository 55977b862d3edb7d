"""An agent's side of the lockstep protocol (msgs_spec/README.md, "Protocol"), without ROS.

The drivers decide everything the agent node does and return it as effects for the node to carry out
(`Subscribe`/`Unsubscribe` a peer's position topic, `Send` an Action or AgentStats, `SaveCheckpoint`,
`Finish`), so the protocol is tested without a ROS graph (tests/test_driver.py):

- `AgentDriver` runs one decentralised learner (indep, js, loc, cq) exactly as `cq_ros.engine.Team` does:
  on Feedback(e, s) it learns from the outcome of its action of step s-1, asks the learner which peers it
  must see (`observe`), and acts once the positions stamped (e, s) of exactly those peers are in.
- `CentralDriver` runs the JSA learner for every AGV: it waits for the feedback of every acting agent,
  learns from the sum of their rewards and answers with every acting agent's action.

Peer subscriptions (`PeerView`): a peer the learner names is subscribed at once; one it no longer names is
dropped after `linger` decision steps without need (the end of the agent's episode counts as one, except
for JS, which needs every peer at every step). The
default, 0, is the design's rule: an agent listens to a peer only while it stands in a state that names it.
A new subscription waits for the match and the reliable handshake before the latched sample arrives, while
a kept one costs a message a step: lingering saves subscriptions, not messages, and LoC, which re-decides
COORDINATE every step, gains most from it. The measured costs are in the README ("Who listens to whom").

Greedy evaluation: after its `episodes` learning episodes a driver plays `eval_episodes` more, as
`cq_ros.engine.greedy_episodes` does after `run`: on a deep copy of the learner with epsilon 0 (learning goes
on inside the copy), so its random stream continues exactly as the engine's copy does. The world plays
them as ordinary episodes (episode indices episodes..episodes+eval_episodes-1) and the AgentStats go on.

Catching up (`WorldLink`). Feedback is decoded without a sequence expectation and then judged: the expected
(episode, step) is played; an older one is dropped and counted (`stale_*`); a later one means the world
stepped on without us (a feedback lost, a restart, a world that ran ahead): the driver adopts it, as a
restarted agent does, counts it (`caught_up`, and `missed_feedback`: the steps it never heard) and sends the
AgentStats of every episode it left behind. Only a later stamp the world vouches for is adopted: with the
run's key every message is the world's; without one, the world's heartbeat must have reached that stamp
(else a forged far-future feedback would capture the agent), so a later stamp is held until it has, and
dropped (`future_*`) if the expected one comes first. A node started without a checkpoint file starts a
fresh learner wherever the world is.

Liveness. Only valid messages from the world count as signs of life: feedback the driver plays or adopts,
and heartbeats whose beat is new (`WorldLink.silent_for`); junk, replays and stale messages do not.

Positions (`PeerView`) are kept per stamp from the step the agent decides at onwards: an older one is dropped
and counted (`stale_*`), a second one for a stamp already heard with another cell too (`conflicting`: the
first writer wins), and at most `AHEAD` stamps are kept per peer (the farthest go first), so no burst of
other positions can push out the world's.

Checkpoints (`save_checkpoint`/`load_checkpoint`): a pickle of the learner and the last finished episode,
written to a temporary file in the same directory and moved into place with os.replace, so a reader sees
the old checkpoint or the new one, never half of one. Only learning episodes are checkpointed, so the last
checkpoint holds the trained learner, not its greedy copy. A node restarted from one decodes its first
feedback without an expected (episode, step) and resumes at whatever step the world is at (switching to
the greedy copy first if the world is past the learning episodes). Temporary files a save killed
mid-write left behind are removed at start (`make_driver`); a checkpoint folder that is missing or not
writable is a bad parameter.
"""

from __future__ import annotations

import copy
import glob
import os
import pickle
import tempfile
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping

from cq_ros.engine import make_learner
from cq_ros.gridmap import GridMap
from cq_ros.parameters import check_numbers, map_and_settings
from cq_ros.learners import LEARNERS, Learner, decode_joint_action
from cq_ros.settings import Settings, SettingsError
from msgs_spec import (
    HEARTBEAT_TOPIC, Action, AgentStats, Bounds, DropCounter, MarkedJointState, WireError, check_sequence,
    decode_feedback, decode_heartbeat, decode_position, feedback_topic, position_topic,
)
from node_runtime.parameters import read_key_parameter

__all__ = [
    "AgentConfig", "agent_config", "make_driver",
    "Subscribe", "Unsubscribe", "Send", "SaveCheckpoint", "Finish",
    "WorldLink", "PeerView", "AgentDriver", "CentralDriver", "save_checkpoint", "load_checkpoint",
    "remove_stale_temporaries", "state_counts",
]

_CHECKPOINT_FORMAT = 1


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
    key: bytes | None


def agent_config(values: Mapping[str, Any]) -> AgentConfig:
    """Check the node's parameter values (name -> value, already of the declared ROS type)."""
    check_numbers(values, (("episodes", 1, False), ("seed", 0, False), ("run", 0, False),
                           ("checkpoint_every", 1, False), ("feedback_timeout", 0, True),
                           ("peer_linger_steps", 0, False), ("agent_id", 0, False),
                           ("min_stats_subscribers", 0, False)))
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
                       read_key_parameter(values["key_file"]))


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


def make_driver(cfg: AgentConfig, log: Callable[[str], Any] | None = None,
                clock: Callable[[], float] = time.monotonic) -> "AgentDriver | CentralDriver":
    """The driver of a node with this configuration: a fresh learner, or the one in cfg.checkpoint."""
    if cfg.checkpoint:
        removed = remove_stale_temporaries(cfg.checkpoint)
        if removed and log:
            log(f"removed {len(removed)} temporary checkpoint file(s) a save killed mid-write left: "
                f"{', '.join(removed)}")
    resume = bool(cfg.checkpoint) and os.path.exists(cfg.checkpoint)
    if resume:
        learner, episode = load_checkpoint(cfg.checkpoint, cfg.algo, cfg.gridmap, max(cfg.agent - 1, 0))
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
                             log=log, key=cfg.key, clock=clock)
    return AgentDriver(learner, cfg.agent, cfg.episodes, eval_episodes=greedy, linger=cfg.peer_linger_steps,
                       checkpoint_every=every, resync=resume, log=log, key=cfg.key, clock=clock)


# -- effects: what a driver asks its node to do, in order ------------------------------------------------


@dataclass(frozen=True)
class Subscribe:
    peer: int  # agent id whose position topic to subscribe to (with msgs_spec POSITION.qos)


@dataclass(frozen=True)
class Unsubscribe:
    peer: int


@dataclass(frozen=True)
class Send:
    payload: Action | AgentStats  # on the topic of payload.agent


@dataclass(frozen=True)
class SaveCheckpoint:
    episode: int  # the last episode learnt
    # The learner as it was after that episode: named here because the driver may have moved on to its
    # greedy copy by the time the node carries the effect out.
    learner: Learner


@dataclass(frozen=True)
class Finish:
    """The last episode (the last greedy one, if any) is over: the node may exit."""


Effects = list  # of the effects above


# -- checkpoints -----------------------------------------------------------------------------------------


def _temporary_prefix(path: str) -> tuple[str, str]:
    """(folder, name prefix) of the temporary files save_checkpoint writes for `path`."""
    return os.path.dirname(os.path.abspath(path)), os.path.basename(path) + "."


def save_checkpoint(path: str | os.PathLike, learner: Learner, episode: int) -> None:
    """Write learner and episode to path atomically: a temporary file beside it, fsync, os.replace."""
    path = os.fspath(path)
    state = {"format": _CHECKPOINT_FORMAT, "algo": learner.name, "map": learner.map.name,
             "agent": learner.agent, "episode": episode, "learner": learner}
    folder, prefix = _temporary_prefix(path)
    fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            pickle.dump(state, f, protocol=pickle.HIGHEST_PROTOCOL)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


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


# -- shared pieces -------------------------------------------------------------------------------------


def state_counts(learner: Learner) -> tuple[int, int]:
    """(local, joint) states in use. Learners report the total (state_count: local plus joint); all but the
    joint-state learners (js, jsa) keep one local Q row per cell and add their joint states to it."""
    total = learner.state_count()
    local = 0 if learner.joint_state else learner.n_cells
    return local, total - local


def _bounds(gridmap: GridMap) -> Bounds:
    return Bounds(gridmap.n_agents, gridmap.height, gridmap.width)


def _cell(gridmap: GridMap, drops: DropCounter, row: int, col: int, source: str) -> int | None:
    """The cell index of (row, col); a '#' square inside the grid is refused like one outside it."""
    try:
        return gridmap.index(row, col)
    except KeyError:
        drops.record(WireError("cell_out_of_range", f"({row}, {col}) is not a cell of map {gridmap.name}"),
                     source)
        return None


AHEAD = 8  # stamps of positions kept per peer from the one the agent decides at


def _record_sequence(drops: DropCounter, stamp: tuple[int, int], expected: tuple[int, int], source: str) -> None:
    """Count a message stamped `stamp` where `expected` was due, as msgs_spec names the gap (stale_*, future_*)."""
    try:
        check_sequence(*stamp, *expected)
    except WireError as e:
        drops.record(e, source)


class WorldLink:
    """What a driver knows of the world beyond its own feedback: whether it is alive (when it last sent a valid
    message), where it is (its last heartbeat), and so whether a later feedback stamp is the world's."""

    def __init__(self, drops: DropCounter, key: bytes | None, clock: Callable[[], float]):
        self.drops, self.key, self._clock = drops, key, clock
        self.last_heard = clock()
        self.beat = 0  # the last heartbeat's number
        self.at = (0, 0)  # the world's (episode, step) by its last heartbeat
        self.caught_up = 0  # times a later stamp was adopted
        self.missed_feedback = 0  # feedback never heard, as far as the stamps tell
        self.extra_counters: dict[str, int] = {}  # counted by the node (second writers in the graph)
        # The earliest later feedback the world has not vouched for yet: (stamp, agent, feedback, cell, expected)
        self.held: tuple | None = None

    def heard(self) -> None:
        self.last_heard = self._clock()

    def silent_for(self) -> float:
        """Seconds since the last valid message from the world (or since the start)."""
        return self._clock() - self.last_heard

    def on_heartbeat(self, msg: Any) -> bool:
        """A message from world/heartbeat; True if it was valid and new."""
        hb = self.drops.guard(decode_heartbeat, msg, after=self.beat, key=self.key, source=HEARTBEAT_TOPIC)
        if hb is None:
            return False
        self.beat, self.at = hb.beat, (hb.episode, hb.step)
        self.heard()
        return True

    def judge(self, agent: int, fb: Any, cell: int, expected: tuple[int, int] | None) -> str:
        """'play' a feedback that is the expected one (or when none is), 'adopt' a later one the world vouches
        for; '' for one dropped (counted) or held until the world vouches for it (`vouched`)."""
        stamp = (fb.episode, fb.step)
        if expected is None or stamp == expected:
            self._drop_held()
            return "play"
        if stamp < expected:
            _record_sequence(self.drops, stamp, expected, feedback_topic(agent))
            return ""
        if self.vouches_for(stamp):
            self._drop_held()
            return "adopt"
        if self.held is None or stamp < self.held[0]:
            self._drop_held()
            self.held = (stamp, agent, fb, cell, expected)
        else:
            _record_sequence(self.drops, stamp, expected, feedback_topic(agent))
        return ""

    def vouches_for(self, stamp: tuple[int, int]) -> bool:
        """Is a feedback stamped `stamp` the world's? Any is, with the run's key; without it, one the world's
        heartbeat has reached."""
        return self.key is not None or stamp <= self.at

    def vouched(self) -> tuple | None:
        """The held (agent, feedback, cell) once the world's heartbeat has reached its stamp (no longer held)."""
        if self.held is None or not self.vouches_for(self.held[0]):
            return None
        _, agent, fb, cell, _ = self.held
        self.held = None
        return agent, fb, cell

    def adopted(self, expected: tuple[int, int] | None, fb: Any) -> str:
        """Count an adoption; a line for the log."""
        self.caught_up += 1
        if expected is None:
            return f"joining the world at episode {fb.episode} step {fb.step}"
        episode, step = expected
        # the rest of the old episode is unknown: at least its last feedback
        missed = fb.step - step if fb.episode == episode else fb.step + 1
        self.missed_feedback += missed
        return (f"the world is at episode {fb.episode} step {fb.step}, we expected episode {episode} step {step}: "
                f"catching up (about {missed} feedback message(s) missed)")

    def counters(self) -> dict[str, int]:
        out = {"caught_up": self.caught_up, "missed_feedback": self.missed_feedback}
        return {**{k: v for k, v in out.items() if v}, **self.extra_counters}

    def _drop_held(self) -> None:
        if self.held is not None:
            stamp, agent, _, _, expected = self.held
            _record_sequence(self.drops, stamp, expected, feedback_topic(agent))
            self.held = None


class PeerView:
    """The peers an agent listens to: which position topics are subscribed, the positions each has delivered
    from the step the agent decides at (`floor`) on, and when to let a subscription go (after `linger`
    decision steps without need)."""

    def __init__(self, gridmap: GridMap, drops: DropCounter, linger: int, key: bytes | None = None):
        self.map = gridmap
        self.bounds = _bounds(gridmap)
        self.drops = drops
        self.linger = linger
        self.key = key
        self.idle: dict[int, int] = {}  # subscribed peer -> decision steps since it was last needed
        self.created = 0  # subscriptions created since start (communication cost)
        self.messages = 0  # position messages received since start (communication cost)
        self.floor = (0, 0)  # the (episode, step) the agent decides at: older positions are stale
        self.between_episodes = False  # its episode is over: older positions are the others' traffic, not faults
        self._seen: dict[int, dict[tuple[int, int], int]] = {}  # peer -> {(episode, step): cell} from floor on

    @property
    def subscribed(self) -> list[int]:
        return sorted(self.idle)

    def advance(self, episode: int, step: int, between_episodes: bool = False) -> None:
        """The agent decides at (episode, step) now, or (`between_episodes`) waits for that one, the first
        of its next episode: forget every position stamped earlier."""
        self.floor, self.between_episodes = (episode, step), between_episodes
        for held in self._seen.values():
            for stamp in [s for s in held if s < self.floor]:
                del held[stamp]

    def need(self, peers: Iterable[int]) -> Effects:
        """A decision step needing `peers`: subscribe to the new ones, drop the ones idle too long."""
        peers = set(peers)
        out: Effects = []
        for j in self.subscribed:
            self.idle[j] = 0 if j in peers else self.idle[j] + 1
            if self.idle[j] > self.linger:
                del self.idle[j]
                self._seen.pop(j, None)
                out.append(Unsubscribe(j))
        for j in sorted(peers - self.idle.keys()):
            self.idle[j] = 0
            self.created += 1
            out.append(Subscribe(j))
        return out

    def on_position(self, peer: int, msg: Any) -> bool:
        """A message from agv<peer>/position; True if it was a new valid position of a subscribed peer."""
        self.messages += 1
        if peer not in self.idle:  # delivered after the subscription was dropped
            return False
        source = position_topic(peer)
        # No (episode, step) expectation: positions also arrive between two waits; the stamps are judged here.
        pos = self.drops.guard(decode_position, msg, bounds=self.bounds, agent=peer, key=self.key, source=source)
        cell = pos and _cell(self.map, self.drops, pos.row, pos.col, source)
        if cell is None:
            return False
        stamp = (pos.episode, pos.step)
        if stamp < self.floor:
            if not self.between_episodes:  # a peer still playing the episode we are done with is no fault
                _record_sequence(self.drops, stamp, self.floor, source)
            return False
        held = self._seen.setdefault(peer, {})
        if stamp in held:
            if held[stamp] != cell:  # the first writer wins: the world publishes before anyone could copy it
                self.drops.record(WireError("conflicting", f"episode {stamp[0]} step {stamp[1]}: cell {pos.row},"
                                            f"{pos.col} after {self.map.cells[held[stamp]]}"), source)
            return False
        held[stamp] = cell
        if len(held) > AHEAD:  # the farthest goes: the world's next positions are the nearest
            farthest = max(held)
            del held[farthest]
            _record_sequence(self.drops, farthest, self.floor, source)
            return farthest != stamp
        return True

    def missing(self, episode: int, step: int, peers: Iterable[int]) -> set[tuple[int, int, int]]:
        """(peer, episode, step) for every peer in `peers` whose position stamped (episode, step) has not come."""
        return {(j, episode, step) for j in peers if (episode, step) not in self._seen.get(j, {})}

    def cells_at(self, episode: int, step: int, peers: Iterable[int]) -> dict[int, int] | None:
        """{peer: cell} stamped (episode, step) for every peer in `peers`, or None while one is missing."""
        cells = {}
        for j in peers:
            cell = self._seen.get(j, {}).get((episode, step))
            if cell is None:
                return None
            cells[j] = cell
        return cells


# -- the decentralised agent ---------------------------------------------------------------------------


class AgentDriver:
    """One decentralised learner (agent id `agent`, 1..N) in the lockstep protocol."""

    def __init__(self, learner: Learner, agent: int, episodes: int, *, eval_episodes: int = 0, linger: int,
                 checkpoint_every: int = 0, resync: bool = False, log: Callable[[str], Any] | None = None,
                 key: bytes | None = None, clock: Callable[[], float] = time.monotonic):
        self.learner = learner
        self.agent = agent
        self.agents = (agent,)  # whose feedback it hears and whose actions it sends
        self.episodes = episodes  # learning episodes; then eval_episodes greedy ones
        self.eval_episodes = eval_episodes
        self.greedy = False  # playing the greedy episodes (self.learner is the copy at epsilon 0)
        self.checkpoint_every = checkpoint_every
        self.map = learner.map
        self.bounds = _bounds(self.map)
        self.drops = DropCounter(log)
        self.link = WorldLink(self.drops, key, clock)
        self.peers = PeerView(self.map, self.drops, linger, key)
        self._log = log or (lambda _msg: None)
        self.expect: tuple[int, int] | None = None if resync else (0, 0)  # next feedback; None: any
        self.finished = False
        self.skipped_steps = 0  # steps the world took without our action (it timed us out)
        self._played = False  # a feedback played: episodes left behind since get their statistics
        self._acted: tuple[int, int] | None = None  # (episode, step) of the action just sent
        self._pending: tuple[int, int, tuple[int, ...]] | None = None  # (episode, step, peers) awaiting positions
        self._plays_before = learner.joint_plays  # joint plays before the current episode

    def on_feedback(self, agent: int, msg: Any) -> Effects:
        """A message from agv<agent>/feedback (the node subscribes to its own agent's only)."""
        source = feedback_topic(agent)
        fb = self.drops.guard(decode_feedback, msg, bounds=self.bounds, agent=agent, key=self.link.key,
                              source=source)
        cell = fb and _cell(self.map, self.drops, fb.row, fb.col, source)
        if cell is None:
            return []
        verdict = self.link.judge(agent, fb, cell, self.expect)
        if verdict == "adopt":
            return self._catch_up(fb, cell)
        return self._play(fb, cell) if verdict == "play" else []

    def on_heartbeat(self, msg: Any) -> Effects:
        """A message from world/heartbeat: the world is alive, and may vouch for a later feedback held."""
        held = self.link.vouched() if self.link.on_heartbeat(msg) else None
        return self._catch_up(*held[1:]) if held else []

    def on_position(self, peer: int, msg: Any) -> Effects:
        """A message from agv<peer>/position."""
        return self._try_act() if self.peers.on_position(peer, msg) else []

    def waiting_for(self) -> set[tuple[int, int, int]]:
        """(peer, episode, step) of every position the agent waits for before it can act (none: it is not
        waiting for peers)."""
        if self._pending is None:
            return set()
        return self.peers.missing(*self._pending)

    def counters(self) -> dict[str, int]:
        out = self.drops.as_counters()
        if self.skipped_steps:
            out["skipped_steps"] = self.skipped_steps
        out.update(self.link.counters())
        return out

    def _catch_up(self, fb: Any, cell: int) -> Effects:
        """Adopt the world's later (episode, step), as a restarted agent does: the episodes left behind end
        here (with their statistics), and the feedback is played as a resumed agent's first."""
        self._log(self.link.adopted(self.expect if self._played else None, fb))
        out: Effects = []
        if self._played:
            for episode in range(self.expect[0], fb.episode):
                out += self._end_episode(episode)
                self._plays_before = self.learner.joint_plays
        self.expect = None
        return out if self.finished else out + self._play(fb, cell)

    def _play(self, fb: Any, cell: int) -> Effects:
        self.link.heard()
        self._played = True
        if self._pending is not None:
            self.skipped_steps += 1
            self._log(f"episode {fb.episode}: the world stepped to {fb.step} before our action of step "
                      f"{fb.step - 1} (step timeout); resuming there")
            self._pending = None
        if self.expect is None:  # resumed: the world may be past the learning episodes already
            _greedy_from(self, fb.episode)
        if fb.step == 0 or self.expect is None:
            self._plays_before = self.learner.joint_plays
        # Learn only from the outcome of an action we sent: after a skipped step or a restart there is none.
        if self._acted == (fb.episode, fb.step - 1):
            self.learner.learn(fb.reward, cell, fb.done)
        self._acted = None
        if fb.done or fb.truncated:
            return self._end_episode(fb.episode)
        self.expect = (fb.episode, fb.step + 1)
        self.peers.advance(fb.episode, fb.step)
        need = tuple(j + 1 for j in self.learner.observe(cell))
        self._pending = (fb.episode, fb.step, need)
        return self.peers.need(need) + self._try_act()

    def _try_act(self) -> Effects:
        if self._pending is None:
            return []
        episode, step, need = self._pending
        cells = self.peers.cells_at(episode, step, need)
        if cells is None:
            return []
        self._pending = None
        action = self.learner.act({j - 1: c for j, c in cells.items()})
        self._acted = (episode, step)
        return [Send(Action(self.agent, episode, step, action))]

    def _end_episode(self, episode: int) -> Effects:
        self.learner.end_episode()
        self.expect = (episode + 1, 0)
        self.peers.advance(episode + 1, 0, between_episodes=True)
        # Until its next episode the agent sees nobody, except a joint-state learner, which will need every
        # peer again at its first step (dropping would cost a new subscription every episode).
        out = self.peers.need([j + 1 for j in self.learner.peers] if self.learner.joint_state else ())
        out.append(Send(self._stats(episode)))
        out += _after_episode(self, episode)
        return out

    def _stats(self, episode: int) -> AgentStats:
        learner, cells = self.learner, self.map.cells
        local, joint = state_counts(learner)
        marked = tuple(MarkedJointState(*cells[s], j + 1, *cells[c], conf) for s, j, c, conf in learner.joint_states())
        return AgentStats(agent=self.agent, episode=episode, algorithm=learner.name,
                          joint_plays=learner.joint_plays - self._plays_before, local_states=local,
                          joint_states=joint, subscriptions_created=self.peers.created,
                          subscriptions_active=len(self.peers.idle), peer_messages=self.peers.messages,
                          marked=marked, counters=self.counters())


def _after_episode(driver: "AgentDriver | CentralDriver", episode: int) -> Effects:
    """After episode `episode`: a checkpoint (of learning episodes only: every checkpoint_every and the last),
    then Finish after the last episode of all, or else on to the next (greedy from `driver.episodes` on)."""
    out: Effects = []
    every = driver.checkpoint_every
    if every and episode < driver.episodes and (episode == driver.episodes - 1 or (episode + 1) % every == 0):
        out.append(SaveCheckpoint(episode, driver.learner))
    if episode >= driver.episodes + driver.eval_episodes - 1:
        driver.finished = True
        out.append(Finish())
    else:
        _greedy_from(driver, episode + 1)
    return out


def _greedy_from(driver: "AgentDriver | CentralDriver", episode: int) -> None:
    """Before playing `episode`: past the learning episodes, switch once to the greedy copy of the learner.

    Exactly what cq_ros.engine.greedy_episodes does (a deep copy, then epsilon 0), so the copy's random
    stream continues as the engine's does; the learner checkpointed before stays the trained one. The copy
    keeps joint_plays, so the per-episode counts (joint_plays - _plays_before) go on unchanged."""
    if episode >= driver.episodes and not driver.greedy:
        driver.learner = copy.deepcopy(driver.learner)
        driver.learner.epsilon = 0.0
        driver.greedy = True


# -- the central (JSA) node ----------------------------------------------------------------------------


class CentralDriver:
    """The JSA learner driving every AGV, as cq_ros.engine.Team drives a central learner.

    A resumed central node does not know where the agents that get no feedback are, so it reads every
    agent's latched position of the step it resumes at (subscribing only for that) and acts from there:
    an agent at its goal is done (goals are absorbing).
    """

    def __init__(self, learner: Learner, episodes: int, *, eval_episodes: int = 0, checkpoint_every: int = 0,
                 resync: bool = False, log: Callable[[str], Any] | None = None, key: bytes | None = None,
                 clock: Callable[[], float] = time.monotonic):
        self.learner = learner
        self.episodes = episodes  # learning episodes; then eval_episodes greedy ones
        self.eval_episodes = eval_episodes
        self.greedy = False  # playing the greedy episodes (self.learner is the copy at epsilon 0)
        self.checkpoint_every = checkpoint_every
        self.map = learner.map
        self.n = self.map.n_agents
        self.bounds = _bounds(self.map)
        self.drops = DropCounter(log)
        self.link = WorldLink(self.drops, key, clock)
        self.peers = PeerView(self.map, self.drops, linger=0, key=key)
        self._log = log or (lambda _msg: None)
        self.finished = False
        self._played = False  # a feedback played: episodes left behind since get their statistics
        self.agents = range(1, self.n + 1)  # whose feedback it hears and whose actions it sends
        self._cells = list(self.map.starts)
        self._done = [False] * self.n
        self._resync: tuple[int, int] | None = None  # resuming: the (episode, step) whose positions we await
        self._inbox: dict[int, deque] = {k: deque() for k in self.agents}  # (feedback, cell) not yet used
        self.expect: dict[int, tuple[int, int] | None] = {k: None if resync else (0, 0) for k in self.agents}
        self._collect(set(self.agents))
        self._acted: tuple[int, int] | None = None
        self._plays_before = learner.joint_plays

    def on_feedback(self, agent: int, msg: Any) -> Effects:
        """A message from agv<agent>/feedback."""
        source = feedback_topic(agent)
        fb = self.drops.guard(decode_feedback, msg, bounds=self.bounds, agent=agent, key=self.link.key,
                              source=source)
        cell = fb and _cell(self.map, self.drops, fb.row, fb.col, source)
        if cell is None:
            return []
        if self._resync is not None:  # the positions decide; a later feedback moves the step they must show
            if (fb.episode, fb.step) > self._resync and self.link.vouches_for((fb.episode, fb.step)):
                self.link.heard()
                return self._start_resync(fb)
            return []
        verdict = self.link.judge(agent, fb, cell, self.expect[agent])
        if verdict == "adopt":
            return self._catch_up(agent, fb)
        if verdict != "play":
            return []
        self.link.heard()
        self._played = True
        if self.expect[agent] is None:  # resuming: the first feedback says where the world is
            return self._start_resync(fb)
        # An agent's next feedback follows from this one alone (an agent still acting cannot see its episode
        # finish), and may come before the step it belongs to is complete: the agents' feedback comes on
        # separate topics, in no fixed order, so an agent at its goal may hear of the next episode before
        # the last feedback of this one has come from another agent. So hold it until its step is collected.
        self.expect[agent] = (fb.episode + 1, 0) if fb.done or fb.truncated else (fb.episode, fb.step + 1)
        self._inbox[agent].append((fb, cell))
        out: Effects = []
        while not self.finished and all(self._inbox[k] for k in self._waiting):
            out += self._joint_step()
        return out

    def on_position(self, peer: int, msg: Any) -> Effects:
        """A message from agv<peer>/position (subscribed only while resuming)."""
        if not self.peers.on_position(peer, msg) or self._resync is None:
            return []
        cells = self.peers.cells_at(*self._resync, self.agents)
        if cells is None:
            return []
        episode, step = self._resync
        self._resync = None
        out = self.peers.need(())
        self._cells = [cells[k] for k in self.agents]
        self._done = [c == g for c, g in zip(self._cells, self.map.goals)]
        self.expect = {k: (episode + 1, 0) if done else (episode, step + 1) for k, done in zip(self.agents, self._done)}
        if all(self._done):
            self._done = [False] * self.n
            self._collect(set(self.agents))
            return out
        self._plays_before = self.learner.joint_plays
        return out + self._act(episode, step)

    def on_heartbeat(self, msg: Any) -> Effects:
        """A message from world/heartbeat: the world is alive, and may vouch for a later feedback held."""
        held = self.link.vouched() if self.link.on_heartbeat(msg) else None
        return self._catch_up(held[0], held[1]) if held else []

    @property
    def acting(self) -> list[int]:
        """The agents still acting in the current episode (not at their goals)."""
        return [k for k in self.agents if not self._done[k - 1]]

    def waiting_for(self) -> set[tuple[int, int, int]]:
        """(agent, episode, step) of every position the node waits for (only while resuming)."""
        return set() if self._resync is None else self.peers.missing(*self._resync, self.agents)

    def counters(self) -> dict[str, int]:
        return {**self.drops.as_counters(), **self.link.counters()}

    def _catch_up(self, agent: int, fb: Any) -> Effects:
        """Adopt the world's later (episode, step), as a resumed node does (from the positions of that step);
        the episodes left behind end here, with their statistics."""
        expected = self.expect[agent]
        self._log(self.link.adopted(expected if self._played else None, fb))
        out: Effects = []
        if self._played:
            current = min(e for e, _ in filter(None, self.expect.values()))
            for episode in range(current, fb.episode):
                out += self._end_episode(episode)
                self._plays_before = self.learner.joint_plays
        self._played = True
        self.link.heard()
        for inbox in self._inbox.values():
            inbox.clear()
        self._acted = None
        self.expect = dict.fromkeys(self.agents)
        return out + self._start_resync(fb)
    def _joint_step(self) -> Effects:
        """Every acting agent's feedback of a step is in: learn, then end the episode or act."""
        for k in self._waiting:
            fb, self._cells[k - 1] = self._inbox[k].popleft()
            self._rewards[k - 1], self._done[k - 1] = fb.reward, fb.done
            self._truncated |= fb.truncated
        if fb.step == 0:
            self._plays_before = self.learner.joint_plays
        finished = all(self._done)
        if self._acted == (fb.episode, fb.step - 1):
            self.learner.learn(sum(self._rewards), tuple(self._cells), finished)
        self._acted = None
        if finished or self._truncated:
            return self._end_episode(fb.episode)
        return self._act(fb.episode, fb.step)

    def _start_resync(self, fb) -> Effects:
        if fb.truncated:  # the episode is over for everyone: start with the next
            self._resync = None
            self.expect = dict.fromkeys(self.agents, (fb.episode + 1, 0))
            return self.peers.need(())
        self._resync = (fb.episode, fb.step)
        self.peers.advance(*self._resync)
        return self.peers.need(self.agents)

    def _collect(self, agents: set[int]) -> None:
        self._waiting = agents
        self._rewards = [0.0] * self.n  # agents at their goals get nothing, as in GridWorld.step_joint
        self._truncated = False

    def _act(self, episode: int, step: int) -> Effects:
        # A no-op but after a resume, which may join the world past the learning episodes (from a
        # truncated step or from positions, neither passing through _end_episode).
        _greedy_from(self, episode)
        self.learner.observe(tuple(self._cells))
        joint = decode_joint_action(self.learner.act({}), self.n)
        acting = self.acting
        self._acted = (episode, step)
        self._collect(set(acting))
        return [Send(Action(k, episode, step, joint[k - 1])) for k in acting]

    def _end_episode(self, episode: int) -> Effects:
        self.learner.end_episode()
        self._done = [False] * self.n
        self._collect(set(self.agents))
        out: Effects = [Send(self._stats(k, episode)) for k in self.agents]
        out += _after_episode(self, episode)
        return out

    def _stats(self, agent: int, episode: int) -> AgentStats:
        local, joint = state_counts(self.learner)
        return AgentStats(agent=agent, episode=episode, algorithm=self.learner.name,
                          joint_plays=self.learner.joint_plays - self._plays_before, local_states=local,
                          joint_states=joint, subscriptions_created=self.peers.created,
                          subscriptions_active=len(self.peers.idle), peer_messages=self.peers.messages,
                          counters=self.counters())

"""An agent's side of the lockstep protocol (msgs_spec/README.md, "Protocol"), without ROS.

The drivers take payloads, never bytes: the node decodes each message (agent_node.wire_reading) and hands them
its `Feedback`, `Position` or `Heartbeat`; they keep the protocol's rules (sequence, catch-up, liveness). They
decide everything the agent node does and return it as effects for the node to carry out
(`Subscribe`/`Unsubscribe` a peer's position topic, `Send` an Action or AgentStats, `SaveCheckpoint`, `Finish`),
so the protocol is tested without a ROS graph (tests/test_driver.py):

- `AgentDriver` runs one decentralised learner (indep, js, loc, cq) through the engine's own step functions,
  as `cq_ros.engine.Team` does: on Feedback(e, s), `step_outcome` learns from the outcome of its action of
  step s-1 and names the peers it must see; once the positions stamped (e, s) of exactly those peers are
  in, `step_act` gives its action.
- `CentralDriver` runs the JSA learner for every AGV through the engine's central adapter
  (`central_outcome`, `central_act`): it waits for the feedback of every acting agent, learns from the sum
  of their rewards and answers with every acting agent's action.

Greedy evaluation: after its `episodes` learning episodes a driver plays `eval_episodes` more, as
`cq_ros.engine.greedy_episodes` does after `run`: on a deep copy of the learner with epsilon 0 (learning goes
on inside the copy unless the setting eval_learning is 0), so its random stream continues exactly as the engine's
copy does. The world plays them as ordinary episodes (episode indices episodes..episodes+eval_episodes-1) and the
AgentStats go on.

What the two drivers do alike lives once, in their base `_Driver`: the world link, heartbeat handling, the
per-episode counters (joint plays and peer positions heard since the episode began), the AgentStats they send,
checkpoints and the greedy switch. The pieces they share have their own modules: `effects` (what a driver
returns), `world_link` (liveness and catching up), `peer_view` (peer subscriptions and positions), `checkpoint`,
`wire_reading`; `config` makes a driver from a node's parameters.
"""

from __future__ import annotations

import copy
import time
from collections import deque
from typing import Any, Callable

from cq_ros.engine import central_act, central_outcome, step_act, step_outcome
from cq_ros.learners import Learner
from msgs_spec import (
    ACTION_LAYOUT, Action, AgentStats, DropCounter, Feedback, Heartbeat, MarkedJointState, Position, agent_namespace,
    feedback_topic,
)

from .effects import Effects, Finish, SaveCheckpoint, Send
from .peer_view import PeerView
from .wire_reading import bounds_of, cell_of
from .world_link import Verdict, WorldLink

__all__ = ["AgentDriver", "CentralDriver", "state_counts"]


def state_counts(learner: Learner) -> tuple[int, int]:
    """(local, joint) states in use. Learners report the total (state_count: local plus joint); all but the
    joint-state learners (js, jsa) keep one local Q row per cell and add their joint states to it."""
    total = learner.state_count()
    local = 0 if learner.joint_state else learner.n_cells
    return local, total - local


def counts(learner: Learner) -> tuple[int, int]:
    """(joint plays, peer positions heard) so far: the learner keeps them for its life, an episode's statistics
    carry what they grew by since the episode began."""
    return learner.joint_plays, learner.heard


# -- what both drivers share ----------------------------------------------------------------------------


class _Driver:
    """The state and rules AgentDriver and CentralDriver share; each says which agents it speaks for
    (`agents`), what feedback it expects next (`_expected`), and how it adopts a later step (`_catch_up`)."""

    _counted: tuple[str, ...] = ("unapplied_actions",)  # own counts reported beside the drops, when non-zero

    def __init__(self, learner: Learner, episodes: int, *, eval_episodes: int, linger: int, checkpoint_every: int,
                 log: Callable[[str], Any] | None, key: Any, clock: Callable[[], float], max_catch_up: int):
        self.learner = learner
        self.episodes = episodes  # learning episodes; then eval_episodes greedy ones
        self.eval_episodes = eval_episodes
        self.greedy = False  # playing the greedy episodes (self.learner is the copy at epsilon 0)
        self.checkpoint_every = checkpoint_every
        self.map = learner.map
        self.bounds = bounds_of(self.map)  # what the node decodes against (agent_node.wire_reading), as `key`
        self.key = key  # the run's key: messages must carry its MAC and seal (None: no authentication)
        self.drops = DropCounter(log)
        self.link = WorldLink(self.drops, key, clock, last_episode=episodes + eval_episodes - 1,
                              max_catch_up=max_catch_up)
        self.peers = PeerView(self.map, self.drops, linger)
        self._clock = clock
        self._log = log or (lambda _msg: None)
        self.finished = False
        self._played = False  # a feedback played: episodes left behind since get their statistics
        self.unapplied_actions = 0  # actions sent that the world did not apply (late or lost)
        self.extra_counters: dict[str, int] = {}  # counted by the node (second writers in the graph, lost samples)
        self._begin_episode()

    def on_heartbeat(self, hb: Heartbeat) -> Effects:
        """A heartbeat from world/heartbeat: the world is alive, and may vouch for a later feedback held."""
        held = self.link.vouched() if self.link.on_heartbeat(hb, self._expected()) else None
        return self._catch_up(*held) if held else []

    def renew_quiet(self) -> Effects:
        """Called every check period by the node: renew each peer subscription waited on that delivers nothing
        (PeerView.renew_quiet), saying so."""
        out, renewed = self.peers.renew_quiet({peer for peer, _, _ in self.waiting_for()}, self._clock())
        for peer, quiet in renewed:
            self._log(f"no position from {agent_namespace(peer)} in {quiet:.1f} s of waiting for it: subscribing to "
                      "it anew (renewed_subscriptions)")
        return out

    def waiting_for(self) -> set[tuple[int, int, int]]:
        """(peer, episode, step) of every position it waits for now."""
        raise NotImplementedError

    def counters(self) -> dict[str, int]:
        out = self.drops.as_counters()
        out.update((name, getattr(self, name)) for name in self._counted if getattr(self, name))
        if self.peers.renewed:
            out["renewed_subscriptions"] = self.peers.renewed
        out.update(self.link.counters())
        out.update(self.extra_counters)
        return out

    def _expected(self) -> tuple[int, int] | None:
        """The (episode, step) of the next feedback it expects; None: any (resuming)."""
        raise NotImplementedError

    def _catch_up(self, agent: int, fb: Any, cell: int) -> Effects:
        """Adopt the world's later (episode, step) of `fb`, agent `agent`'s feedback at `cell`."""
        raise NotImplementedError

    def _begin_episode(self) -> None:
        """An episode begins (or is resumed) here: its statistics count joint plays and peer positions heard
        from now."""
        self._before = counts(self.learner)

    def _stats(self, agent: int, episode: int, marked: tuple[MarkedJointState, ...] = ()) -> AgentStats:
        """Agent `agent`'s statistics of `episode`, which ends now."""
        learner = self.learner
        local, joint = state_counts(learner)
        plays, heard = counts(learner)
        return AgentStats(agent=agent, episode=episode, algorithm=learner.name,
                          joint_plays=plays - self._before[0], heard=heard - self._before[1], local_states=local,
                          joint_states=joint, subscriptions_created=self.peers.created,
                          subscriptions_active=len(self.peers.idle), peer_messages=self.peers.messages,
                          marked=marked, counters=self.counters())

    def _cell(self, fb: Feedback) -> int | None:
        """The index of a feedback's cell; None for a '#' square (within the bounds the node decoded against),
        logged and counted."""
        try:
            return self.map.index(fb.row, fb.col)
        except KeyError:  # cell_of records why (its topic's name made only then)
            return cell_of(self.map, self.drops, fb.row, fb.col, feedback_topic(fb.agent))

    def _after_episode(self, episode: int) -> Effects:
        """After episode `episode`: a checkpoint (of learning episodes only: every checkpoint_every and the
        last), then Finish after the last episode of all, or else on to the next (greedy from `episodes` on)."""
        out: Effects = []
        every = self.checkpoint_every
        if every and episode < self.episodes and (episode == self.episodes - 1 or (episode + 1) % every == 0):
            out.append(SaveCheckpoint(episode, self.learner))
        if episode >= self.episodes + self.eval_episodes - 1:
            self.finished = True
            out.append(Finish())
        else:
            self._greedy_from(episode + 1)
        return out

    def _greedy_from(self, episode: int) -> None:
        """Before playing `episode`: past the learning episodes, switch once to the greedy copy of the learner.

        Exactly what cq_ros.engine.greedy_episodes does (a deep copy, then Learner.make_greedy: epsilon 0, frozen
        unless eval_learning), so the copy's random
        stream continues as the engine's does; the learner checkpointed before stays the trained one. The copy
        keeps joint_plays and heard, so the per-episode counts (since `_before`, `counts`) go on unchanged."""
        if episode >= self.episodes and not self.greedy:
            self.learner = copy.deepcopy(self.learner)
            self.learner.make_greedy()
            self.greedy = True


# -- the decentralised agent ---------------------------------------------------------------------------


class AgentDriver(_Driver):
    """One decentralised learner (agent id `agent`, 1..N) in the lockstep protocol."""

    _counted = ("skipped_steps", "unapplied_actions")

    def __init__(self, learner: Learner, agent: int, episodes: int, *, eval_episodes: int = 0, linger: int,
                 checkpoint_every: int = 0, resync: bool = False, log: Callable[[str], Any] | None = None,
                 key: Any = None, clock: Callable[[], float] = time.monotonic, max_catch_up: int = 100):
        super().__init__(learner, episodes, eval_episodes=eval_episodes, linger=linger,
                         checkpoint_every=checkpoint_every, log=log, key=key, clock=clock, max_catch_up=max_catch_up)
        self.agent = agent
        self.agents = (agent,)  # whose feedback it hears and whose actions it sends
        self.expect: tuple[int, int] | None = None if resync else (0, 0)  # next feedback; None: any
        self.skipped_steps = 0  # steps the world took before we had acted (it timed us out)
        self._acted: tuple[int, int, int] | None = None  # (episode, step, action) of the action just sent
        self._pending: tuple[int, int, tuple[int, ...]] | None = None  # (episode, step, peers) awaiting positions

    def on_feedback(self, fb: Feedback) -> Effects:
        """A feedback from agv<k>/feedback, k its agent (the node subscribes to its own agent's only)."""
        agent, cell = fb.agent, self._cell(fb)
        if cell is None:
            return []
        verdict = self.link.judge(agent, fb, cell, self.expect)
        if verdict is Verdict.ADOPT:
            return self._catch_up(agent, fb, cell)
        return self._play(fb, cell) if verdict is Verdict.PLAY else []

    def on_position(self, pos: Position) -> Effects:
        """A position from agv<peer>/position, peer its agent."""
        return self._try_act() if self.peers.on_position(pos) else []

    def waiting_for(self) -> set[tuple[int, int, int]]:
        """(peer, episode, step) of every position the agent waits for before it can act (none: it is not
        waiting for peers)."""
        if self._pending is None:
            return set()
        return self.peers.missing(*self._pending)

    def _expected(self) -> tuple[int, int] | None:
        return self.expect

    def _catch_up(self, agent: int, fb: Any, cell: int) -> Effects:
        """Adopt the world's later (episode, step), as a restarted agent does: the episodes left behind end
        here (with their statistics), and the feedback is played as a resumed agent's first."""
        self._log(self.link.adopted(self.expect if self._played else None, fb))
        out: Effects = []
        if self._played:
            for episode in range(self.expect[0], fb.episode):
                step_outcome(self.learner, None, over=True)  # left behind: no last outcome to learn from
                out += self._end_episode(episode)
                self._begin_episode()
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
            self._greedy_from(fb.episode)
        if fb.step == 0 or self.expect is None:
            self._begin_episode()
        # Learn only from the outcome of an action we sent and the world applied: after a skipped step or a
        # restart there is none; one that came after step_timeout (or was lost) the world stepped without.
        reward = None
        acted = self._acted
        if acted is not None and acted[0] == fb.episode and acted[1] == fb.step - 1:
            if fb.applied == acted[2]:
                reward = fb.reward
            else:
                self._unapplied(fb)
        self._acted = None
        need = step_outcome(self.learner, cell, reward, fb.done, fb.done or fb.truncated)
        if need is None:
            return self._end_episode(fb.episode)
        self.expect = (fb.episode, fb.step + 1)
        self.peers.advance(fb.episode, fb.step)
        need = tuple([j + 1 for j in need]) if need else ()
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
        action = step_act(self.learner, {j - 1: c for j, c in cells.items()} if cells else {})
        self._acted = (episode, step, action)
        return [Send(ACTION_LAYOUT.new(self.agent, episode, step, action))]

    def _unapplied(self, fb: Any) -> None:
        self.unapplied_actions += 1
        self._log(f"episode {fb.episode}: the world stepped to {fb.step} without our action of step "
                  f"{fb.step - 1} (it came after step_timeout, or was lost): nothing learnt from that step")

    def _end_episode(self, episode: int) -> Effects:
        """The learner has ended `episode` (step_outcome): on to the next, with this one's statistics."""
        self.expect = (episode + 1, 0)
        self.peers.advance(episode + 1, 0, between_episodes=True)
        # Until its next episode the agent sees nobody, except a joint-state learner, which will need every
        # peer again at its first step (dropping would cost a new subscription every episode).
        out = self.peers.need([j + 1 for j in self.learner.peers] if self.learner.joint_state else ())
        cells = self.map.cells
        marked = tuple(MarkedJointState(*cells[s], j + 1, *cells[c], conf)
                       for s, j, c, conf in self.learner.joint_states())
        out.append(Send(self._stats(self.agent, episode, marked)))
        out += self._after_episode(episode)
        return out


# -- the central (JSA) node ----------------------------------------------------------------------------


class CentralDriver(_Driver):
    """The JSA learner driving every AGV, as cq_ros.engine.Team drives a central learner.

    A resumed central node does not know where the agents that get no feedback are, so it reads every
    agent's latched position of the step it resumes at (subscribing only for that) and acts from there:
    an agent at its goal is done (goals are absorbing).
    """

    def __init__(self, learner: Learner, episodes: int, *, eval_episodes: int = 0, checkpoint_every: int = 0,
                 resync: bool = False, log: Callable[[str], Any] | None = None, key: Any = None,
                 clock: Callable[[], float] = time.monotonic, max_catch_up: int = 100):
        super().__init__(learner, episodes, eval_episodes=eval_episodes, linger=0,
                         checkpoint_every=checkpoint_every, log=log, key=key, clock=clock, max_catch_up=max_catch_up)
        self.n = self.map.n_agents
        self.agents = range(1, self.n + 1)  # whose feedback it hears and whose actions it sends
        self._cells = list(self.map.starts)
        self._done = [False] * self.n
        self._resync: tuple[int, int] | None = None  # resuming: the (episode, step) whose positions we await
        self._inbox: dict[int, deque] = {k: deque() for k in self.agents}  # (feedback, cell) not yet used
        self.expect: dict[int, tuple[int, int] | None] = {k: None if resync else (0, 0) for k in self.agents}
        self._collect(set(self.agents))
        self._acted: tuple[int, int] | None = None
        self._sent: dict[int, int] = {}  # agent -> its action of the step acted at (self._acted)

    def on_feedback(self, fb: Feedback) -> Effects:
        """A feedback from agv<k>/feedback, k its agent."""
        agent, cell = fb.agent, self._cell(fb)
        if cell is None:
            return []
        if self._resync is not None:  # the positions decide; a later feedback moves the step they must show
            if ((fb.episode, fb.step) > self._resync and self.link.vouches_for((fb.episode, fb.step))
                    and not self.link.far_ahead(agent, fb, self._resync)):
                self.link.heard()
                return self._start_resync(fb)
            return []
        verdict = self.link.judge(agent, fb, cell, self.expect[agent])
        if verdict is Verdict.ADOPT:
            return self._catch_up(agent, fb, cell)
        if verdict is not Verdict.PLAY:
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

    def on_position(self, pos: Position) -> Effects:
        """A position from agv<peer>/position, peer its agent (subscribed only while resuming)."""
        if not self.peers.on_position(pos) or self._resync is None:
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
        self._begin_episode()
        # The greedy switch first: a resume may join the world past the learning episodes.
        self._greedy_from(episode)
        central_outcome(self.learner, self._cells, None, False, False)  # nothing to learn: observe only
        return out + self._act(episode, step)

    @property
    def acting(self) -> list[int]:
        """The agents still acting in the current episode (not at their goals)."""
        return [k for k in self.agents if not self._done[k - 1]]

    def waiting_for(self) -> set[tuple[int, int, int]]:
        """(agent, episode, step) of every position the node waits for (only while resuming)."""
        return set() if self._resync is None else self.peers.missing(*self._resync, self.agents)

    def _expected(self) -> tuple[int, int] | None:
        """The earliest step expected of any agent; None while resuming."""
        return None if self._resync is not None or None in self.expect.values() else min(self.expect.values())

    def _catch_up(self, agent: int, fb: Any, cell: int) -> Effects:
        """Adopt the world's later (episode, step), as a resumed node does (from the positions of that step);
        the episodes left behind end here, with their statistics."""
        expected = self.expect[agent]
        self._log(self.link.adopted(expected if self._played else None, fb))
        out: Effects = []
        if self._played:
            current = min(e for e, _ in filter(None, self.expect.values()))
            for episode in range(current, fb.episode):
                central_outcome(self.learner, self._cells, None, False, True)  # left behind: nothing to learn
                out += self._end_episode(episode)
                self._begin_episode()
        self._played = True
        self.link.heard()
        for inbox in self._inbox.values():
            inbox.clear()
        self._acted = None
        self.expect = dict.fromkeys(self.agents)
        return out + self._start_resync(fb)

    def _joint_step(self) -> Effects:
        """Every acting agent's feedback of a step is in: learn, then end the episode or act."""
        unapplied = 0  # acting agents whose action the world did not apply (it came late, or was lost)
        for k in self._waiting:
            fb, self._cells[k - 1] = self._inbox[k].popleft()
            self._rewards[k - 1], self._done[k - 1] = fb.reward, fb.done
            self._truncated |= fb.truncated
            unapplied += fb.applied != self._sent.get(k)
        if fb.step == 0:
            self._begin_episode()
        # A no-op but after a resume from a truncated step, which may join the world past the learning
        # episodes without passing through _end_episode.
        self._greedy_from(fb.episode)
        finished = all(self._done)
        rewards = None
        if self._acted == (fb.episode, fb.step - 1):
            # The joint action is learnt only as the world applied it whole.
            if unapplied:
                self.unapplied_actions += unapplied
                self._log(f"episode {fb.episode}: the world stepped to {fb.step} without {unapplied} of our "
                          f"actions of step {fb.step - 1}: nothing learnt from that step")
            else:
                rewards = self._rewards
        self._acted = None
        if central_outcome(self.learner, self._cells, rewards, finished, finished or self._truncated) is None:
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
        """The learner has observed this step (central_outcome): every acting agent's action."""
        joint = central_act(self.learner, self.n)
        acting = self.acting
        self._acted = (episode, step)
        self._sent = {k: joint[k - 1] for k in acting}
        self._collect(set(acting))
        return [Send(Action(k, episode, step, joint[k - 1])) for k in acting]

    def _end_episode(self, episode: int) -> Effects:
        """The learner has ended `episode` (central_outcome): on to the next, with this one's statistics."""
        self._done = [False] * self.n
        self._collect(set(self.agents))
        out: Effects = [Send(self._stats(k, episode)) for k in self.agents]
        out += self._after_episode(episode)
        return out

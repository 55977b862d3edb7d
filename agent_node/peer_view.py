"""The peers an agent listens to.

Peer subscriptions (`PeerView`): a peer the learner names is subscribed at once; one it no longer names is
dropped after `linger` decision steps without need (the end of the agent's episode counts as one, except
for JS, which needs every peer at every step). The
default, 0, is the design's rule: an agent listens to a peer only while it stands in a state that names it.
A new subscription waits for the match and the reliable handshake before the latched sample arrives, while
a kept one costs a message a step: lingering saves subscriptions, not messages, and LoC, which re-decides
COORDINATE every step, gains most from it. The measured costs are in docs/ros.md ("Who listens to whom").

Positions (`PeerView`) are kept per stamp from the step the agent decides at onwards: an older one is dropped
and counted (`stale_*`), a second one for a stamp already heard with another cell too (`conflicting`: the
first writer wins), and at most `AHEAD` stamps are kept per peer (the farthest go first), so no burst of
other positions can push out the world's.

A subscription waited on that delivers no new position for `RENEW_AFTER_S` is made anew (`renew_quiet`), then
after twice as long, and so on. Once in a CI run (tests/test_faults.py, a launch of grid_game_2 at its 1,766th
episode) a new subscription got nothing for 28 steps while the world stepped on without the agent, and the run
ended; whichever side lost the match, a new subscription is a new match, which the world answers with the
position it holds, and the writer's latched history holds the newest one it sent.
"""

from __future__ import annotations

from typing import Iterable

from cq_ros.gridmap import GridMap
from msgs_spec import DropCounter, Position, WireError, position_topic

from .effects import Effects, Renew, Subscribe, Unsubscribe
from .wire_reading import cell_of, record_sequence

__all__ = ["AHEAD", "RENEW_AFTER_S", "PeerView"]

AHEAD = 8  # stamps of positions kept per peer from the one the agent decides at
# Waited on this long without a new position, a subscription is made anew: a new subscription's match takes
# milliseconds on a running graph, and a step waits step_timeout (2 s by default) for an action.
RENEW_AFTER_S = 1.0


class PeerView:
    """The peers an agent listens to: which position topics are subscribed, the positions each has delivered
    from the step the agent decides at (`floor`) on, and when to let a subscription go (after `linger`
    decision steps without need)."""

    def __init__(self, gridmap: GridMap, drops: DropCounter, linger: int):
        self.map = gridmap
        self.drops = drops
        self.linger = linger
        self.idle: dict[int, int] = {}  # subscribed peer -> decision steps since it was last needed
        self.created = 0  # subscriptions created since start (communication cost)
        self.messages = 0  # position messages received since start (communication cost)
        self.floor = (0, 0)  # the (episode, step) the agent decides at: older positions are stale
        self.between_episodes = False  # its episode is over: older positions are the others' traffic, not faults
        self._seen: dict[int, dict[tuple[int, int], int]] = {}  # peer -> {(episode, step): cell} from floor on
        self._fresh: set[int] = set()  # peers subscribed whose first position has not come yet
        self._quiet: dict[int, tuple[float, int]] = {}  # peer waited for -> (quiet since, renewals since)
        self.renewed = 0  # subscriptions made anew (renew_quiet)

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
        if not peers and not self.idle:  # most steps of a run: nobody needed, nobody subscribed
            return []
        peers = set(peers)
        out: Effects = []
        for j in self.subscribed:
            self.idle[j] = 0 if j in peers else self.idle[j] + 1
            if self.idle[j] > self.linger:
                del self.idle[j]
                self._seen.pop(j, None)
                self._quiet.pop(j, None)
                self._fresh.discard(j)
                out.append(Unsubscribe(j))
        for j in sorted(peers - self.idle.keys()):
            self.idle[j] = 0
            self.created += 1
            self._fresh.add(j)
            out.append(Subscribe(j))
        return out

    def delivered(self, peer: int) -> bool:
        """A message came on agv<peer>/position (counted, valid or not: the communication cost); whether its peer
        is subscribed, so that it is read (one delivered after the subscription was dropped is not)."""
        self.messages += 1
        return peer in self.idle

    def on_position(self, pos: Position) -> bool:
        """A position of a subscribed peer (`delivered`), decoded by the node without an (episode, step)
        expectation: positions also arrive between two waits; the stamps are judged here. True if it was a new
        valid one."""
        peer = pos.agent
        try:  # cell_of's work, the topic's name made only for a position refused
            cell = self.map.index(pos.row, pos.col)
        except KeyError:
            cell_of(self.map, self.drops, pos.row, pos.col, position_topic(peer))
            return False
        stamp = (pos.episode, pos.step)
        # The first position a new subscription delivers may be the writer's latched history from before
        # anyone listened (the world sends a position only while someone listens): older than what the agent
        # waits for, and no fault; the world sends the position waited for once the reader has matched.
        first = peer in self._fresh
        if first:
            self._fresh.discard(peer)
        if stamp < self.floor:
            # a peer still playing the episode we are done with is no fault either
            if not self.between_episodes and not first:
                record_sequence(self.drops, stamp, self.floor, position_topic(peer))
            return False
        held = self._seen.setdefault(peer, {})
        if stamp in held:
            if held[stamp] != cell:  # the first writer wins: the world publishes before anyone could copy it
                self.drops.record(WireError("conflicting", f"episode {stamp[0]} step {stamp[1]}: cell {pos.row},"
                                            f"{pos.col} after {self.map.cells[held[stamp]]}"), position_topic(peer))
            return False
        held[stamp] = cell
        self._quiet.pop(peer, None)  # it delivers
        if len(held) > AHEAD:  # the farthest goes: the world's next positions are the nearest
            farthest = max(held)
            del held[farthest]
            record_sequence(self.drops, farthest, self.floor, position_topic(peer))
            return farthest != stamp
        return True

    def renew_quiet(self, waiting: Iterable[int], now: float) -> tuple[Effects, list[tuple[int, float]]]:
        """Renew the subscriptions of the peers in `waiting` (waited for now) that delivered no new position
        since they were first seen waited for, or since their last renewal, for RENEW_AFTER_S times 2 per
        renewal so far. Returns the effects and (peer, seconds quiet) of each renewed."""
        waiting = set(waiting)
        for j in [j for j in self._quiet if j not in waiting]:
            del self._quiet[j]
        out: Effects = []
        renewed = []
        for j in sorted(waiting & self.idle.keys()):
            since, renewals = self._quiet.setdefault(j, (now, 0))
            if now - since >= RENEW_AFTER_S * 2 ** renewals:
                self._quiet[j] = (now, renewals + 1)
                self._fresh.add(j)  # its first position may again be the latched one from before
                self.created += 1
                self.renewed += 1
                out.append(Renew(j))
                renewed.append((j, now - since))
        return out, renewed

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

"""The one rule for a second world in our namespace: a second system started on the same ROS_DOMAIN_ID and
namespace (a second launch, a script that retries, another person). Which of the two goes on is decided here,
without ROS; the world node hands it what it hears and sees (world_node.node).

Every world says who it is in each heartbeat (msgs_spec.Heartbeat): whether it has begun `stepping`, the second
it `started` and a `ticket` drawn at its start. Worlds rank by (started, ticket): the one started earlier goes
first, and the ticket orders two started in the same second. Both sides rank with the same numbers, so they
agree:

- a world still waiting for its agents refuses beside a twin that steps or that ranks before it (the newcomer
  refuses, and of two waiting worlds exactly one does);
- a world that has begun stepping goes on, whatever starts beside it. It yields to one twin only: one that
  ranks before it and steps too, which happens only to two worlds started together that each began before
  hearing the other; the later one yields, seconds into its run (two systems stepping in one namespace would
  each take the other's agents' messages).
- a waiting world does not begin stepping while the graph shows a twin it has not heard from (its heartbeat
  comes every heartbeat_period): the twin may be a running system, whose agents it would otherwise step. A
  killed world's ghost stays in the graph until its DDS lease runs out (about 20 s), so a world restarted
  after a crash waits that long, within its startup_timeout.

What counts as a twin: a world whose heartbeat we hear, with a ticket not ours, while the graph shows a second
node with our name and namespace (in its node list, or as a writer of world/heartbeat). A writer of
heartbeats in a node of another name (`ros2 topic pub`, junk, a recording) is no world: it can neither stop a
run nor hold one back. The graph learns a writer before the name of its node (node_runtime.graph.UNKNOWN_NODE):
a waiting world begins only once it can name every writer's node. A second system's agents can still be
discovered before its world, and make a newcomer begin: it then yields at the first heartbeat it hears of the
running world (its few messages meanwhile fail the running agents' key checks, under `cq-ros launch`).
A heartbeat's fields are read without its MAC: a second launch has a key of its own. An outsider that both
names a node after our world and writes heartbeats can stop a waiting world, as it could flood any topic:
docs/faults.md says what an outsider can do.
"""

from __future__ import annotations

import random
import time
from dataclasses import dataclass
from typing import Iterable

from msgs_spec import INT32_MAX, Heartbeat
from node_runtime.graph import UNKNOWN_NODE

__all__ = ["Identity", "Twins"]

HEARD_FOR_BEATS = 3  # a twin's word holds this many of its heartbeat periods (a refused twin falls silent)
KEPT = 16  # twins remembered at most (an outsider's stream of tickets cannot grow the table)


@dataclass(frozen=True)
class Identity:
    """Who a world is to its twins: the second it started and its ticket."""

    started: int
    ticket: int

    @classmethod
    def draw(cls) -> "Identity":
        """This world's, drawn at its start: not from the run's seed (two runs of one seed must still differ)."""
        return cls(int(time.time()), random.SystemRandom().randrange(INT32_MAX + 1))

    def before(self, started: int, ticket: int) -> bool:
        """Does this world rank before one that started at `started` with `ticket`?"""
        return (self.started, self.ticket) < (started, ticket)


class Twins:
    """What a world has heard of other worlds in its namespace, and whether it must refuse or wait. What the graph
    shows, below: `writers`, the writers of world/heartbeat, (node name, namespace, gid) each
    (node_runtime.graph.writers); `namesakes`, the nodes of the node list with our name and namespace, ourselves
    included (the graph may learn one before the other)."""

    def __init__(self, me: Identity, name: str, namespace: str, beat_period: float, clock=time.monotonic):
        self.me, self.node, self._clock = me, (name, namespace), clock
        self.fq = f"{namespace.rstrip('/')}/{name}"
        self._fresh_for = HEARD_FOR_BEATS * beat_period
        self._heard: dict[int, tuple[Heartbeat, float]] = {}  # ticket -> (its last heartbeat, when heard)

    def heard(self, hb: Heartbeat) -> None:
        """A heartbeat on our namespace's world/heartbeat (our own ones included: they are told apart here), decoded
        by the node without the key (world_node.wire_reading: a twin of another launch has a key of its own)."""
        if hb.ticket == self.me.ticket and hb.started == self.me.started:
            return
        self._heard.pop(hb.ticket, None)
        self._heard[hb.ticket] = (hb, self._clock())
        if len(self._heard) > KEPT:
            del self._heard[next(iter(self._heard))]  # the one heard longest ago

    def fresh(self) -> list[Heartbeat]:
        now = self._clock()
        return [hb for hb, at in self._heard.values() if now - at <= self._fresh_for]

    def _in_graph(self, writers: Iterable[tuple], namesakes: int) -> bool:
        return namesakes > 1 or sum(1 for w in writers if (w[0], w[1]) == self.node) > 1

    def refusal(self, stepping: bool, writers: Iterable[tuple], namesakes: int = 1) -> str | None:
        """The line to refuse with, or None to go on. `stepping`: this world has begun."""
        if not self._in_graph(writers, namesakes):
            return None
        for hb in self.fresh():
            ranks_before = not self.me.before(hb.started, hb.ticket)
            if stepping and not (hb.stepping and ranks_before):
                continue
            if not stepping and not (hb.stepping or ranks_before):
                continue
            when = time.strftime("%H:%M:%S", time.localtime(hb.started))
            if stepping:
                return (f"another node named {self.fq} on this ROS_DOMAIN_ID started before this one ({when}) and "
                        "steps too: a second system started together with this one; yielding to it")
            how = "steps" if hb.stepping else "waits for its agents"
            return (f"another node named {self.fq} is on this ROS_DOMAIN_ID and {how} (started {when}): a second "
                    f"system in namespace {self.node[1]}; refusing to start; give this one another namespace or "
                    "domain id")
        return None

    def waits_for(self, writers: Iterable[tuple], namesakes: int = 1) -> str | None:
        """What a waiting world must learn before it may begin stepping (once refusal() said go on), or None:
        the node of every writer of world/heartbeat, and a heartbeat of a twin in the graph."""
        writers = list(writers)
        if any(w[0] == UNKNOWN_NODE for w in writers):
            return "the node of a second writer of world/heartbeat (the graph has not named it yet)"
        if self._in_graph(writers, namesakes) and not self.fresh():
            return (f"a heartbeat of the second {self.fq} in the graph (a second system, or a killed world's ghost "
                    "until its DDS lease runs out, about 20 s)")
        return None

"""The world as an agent driver knows it beyond its own feedback.

Catching up (`WorldLink`). Feedback is decoded by the node without a sequence expectation
(agent_node.wire_reading) and then judged here: the expected (episode, step) is played; an older one is dropped
and counted (`stale_*`); a later one means the world stepped on without us (a feedback lost, a restart, a world
that ran ahead): the driver adopts it, as a restarted agent does, counts it (`caught_up`, and `missed_feedback`:
the steps it never heard) and sends the AgentStats of every episode it left behind. Only a later stamp the world
vouches for is adopted: with the run's key every message is the world's; without one, the world's heartbeat must
have reached that stamp (else a forged far-future feedback would capture the agent), so a later stamp is held
until it has, and dropped (`future_*`) if the expected one comes first. A node started without a checkpoint file
starts a fresh learner wherever the world is.

The catch-up is bounded: a feedback past the run's last episode, or (once the agent has played) more than
`max_catch_up` episodes past the one expected, is refused and counted (`far_ahead`), whoever vouches for it.
Adopting ends every episode left behind one by one (its statistics, maybe a checkpoint), so one forged or
corrupt stamp far ahead (episode 2**31-1, keyed by a key holder's bug, or vouched for by a forged heartbeat
where there is no key) would otherwise loop for ever. A node that has played nothing yet (a fresh learner, a
restart without a checkpoint, a twin) has no episode to end on the way: it joins the world wherever it is.

Progress, not arrival. Only valid messages from the world that leave the agent with something to do count
as signs of progress: feedback the driver plays or adopts, and heartbeats whose beat is new and that show the
world not past the feedback the agent expects (`WorldLink.silent_for`); junk, replays and stale messages do
not, nor does a heartbeat of a world that stepped past us: an agent that takes no feedback (a reader or a
callback that stopped) while the world's heartbeats still come is `behind`, and gives up after its
feedback_timeout saying so, as one that hears nothing does. The node judges the silence with a
`node_runtime.patience.Patience` it hands the link (`patience`, restarted by every sign of progress), so the
time the agent itself was stopped does not count against the world, and the heartbeats waiting in its queue
when it resumes are heard before it gives up.

A heartbeat, decoded by the node, is judged here as well: a beat not above the last one heard is `replayed` (a
replay, or a second world). Heartbeat beats are bounded as feedback's catch-up is: after the first, a beat may
be at most `beat_bound(seconds)` past the last one heard (the world beats at most 1/MIN_HEARTBEAT_PERIOD times a
second), so a forged or corrupt far-ahead beat (2**31-1, by a key holder) is refused and counted (`far_ahead`)
instead of making every later real one a replay.
"""

from __future__ import annotations

from enum import Enum
from typing import Any, Callable

from msgs_spec import HEARTBEAT_TOPIC, DropCounter, Heartbeat, WireError, check_beat, feedback_topic
from node_runtime.parameters import MIN_HEARTBEAT_PERIOD
from node_runtime.patience import Patience

from .wire_reading import record_sequence

__all__ = ["BEAT_SLACK", "beat_bound", "Verdict", "WorldLink"]

BEAT_SLACK = 100  # beats a heartbeat may be ahead of the last one beside those its elapsed time allows


def beat_bound(seconds: float) -> int:
    """How far past the last beat heard `seconds` ago a real world's beat can be: its timer's beats in that time
    at the fastest period a world takes, and BEAT_SLACK for delivery jitter (a world sends one more beat when it
    begins stepping)."""
    return BEAT_SLACK + int(seconds / MIN_HEARTBEAT_PERIOD)


class Verdict(Enum):
    """What a driver does with a feedback (WorldLink.judge)."""

    PLAY = "play"  # the expected one: learn from it and act
    ADOPT = "adopt"  # a later one the world vouches for: catch up to it
    NONE = "none"  # dropped (counted), or held until the world vouches for it


class WorldLink:
    """What a driver knows of the world beyond its own feedback: whether it is alive (when it last sent a valid
    message), where it is (its last heartbeat), and so whether a later feedback stamp is the world's."""

    def __init__(self, drops: DropCounter, key: Any, clock: Callable[[], float], *, last_episode: int = 2**31 - 1,
                 max_catch_up: int = 100):
        self.drops, self.key, self._clock = drops, key, clock
        self.last_episode = last_episode  # the run's last episode: nothing later is the world's
        self.max_catch_up = max_catch_up  # episodes a later feedback may be ahead of the expected one
        self.last_heard = clock()
        self.patience: Patience | None = None  # the node's judge of the silence: restarted by every sign of life
        self.beat = 0  # the last heartbeat's number
        self.beat_at = clock()  # when it was heard
        self.at = (0, 0)  # the world's (episode, step) by its last heartbeat
        # (the world's stamp, the one expected) while the last heartbeat showed the world past the feedback this
        # agent expects: no progress, however alive the world
        self.behind: tuple[tuple[int, int], tuple[int, int]] | None = None
        self.caught_up = 0  # times a later stamp was adopted
        self.missed_feedback = 0  # feedback never heard, as far as the stamps tell
        # The earliest later feedback the world has not vouched for yet: (stamp, agent, feedback, cell, expected)
        self.held: tuple | None = None
        self.joined = False  # a feedback played or adopted: later ones are caught up to episode by episode

    def heard(self) -> None:
        self.behind = None
        self.last_heard = self._clock()
        if self.patience is not None:
            self.patience.restart()

    def silent_for(self) -> float:
        """Seconds since the last valid message from the world (or since the start)."""
        return self._clock() - self.last_heard

    def on_heartbeat(self, hb: Heartbeat, expected: tuple[int, int] | None = None) -> bool:
        """A heartbeat from world/heartbeat; True if it was new (and its beat not too far ahead). `expected`: the
        feedback the agent waits for (None: any); a heartbeat of a world past it is no sign of progress."""
        try:
            check_beat(hb.beat, self.beat)
        except WireError as e:
            self.drops.record(e, HEARTBEAT_TOPIC)
            return False
        now = self._clock()
        if self.beat and hb.beat - self.beat > beat_bound(now - self.beat_at):
            self.drops.record(WireError("far_ahead", f"heartbeat beat {hb.beat}, {hb.beat - self.beat} past beat "
                                                     f"{self.beat} heard {now - self.beat_at:.1f} s ago (at most "
                                                     f"{beat_bound(now - self.beat_at)})"), HEARTBEAT_TOPIC)
            return False
        self.beat, self.beat_at, self.at = hb.beat, now, (hb.episode, hb.step)
        if expected is not None and self.at > expected:
            self.behind = (self.at, expected)
        else:
            self.behind = None
            self.heard()
        return True

    def judge(self, agent: int, fb: Any, cell: int, expected: tuple[int, int] | None) -> Verdict:
        """PLAY a feedback that is the expected one, ADOPT a later one the world vouches for (or any, when none
        is expected: a node resuming from its checkpoint); NONE for one dropped (counted) or held until the world
        vouches for it (`vouched`)."""
        stamp = (fb.episode, fb.step)
        if self.far_ahead(agent, fb, expected):
            return Verdict.NONE
        if expected is None:  # resuming (from a checkpoint): joining the world where it is, a catch-up too
            self._drop_held()
            self.joined = True
            return Verdict.ADOPT
        if stamp == expected:
            self._drop_held()
            self.joined = True
            return Verdict.PLAY
        if stamp < expected:
            record_sequence(self.drops, stamp, expected, feedback_topic(agent))
            return Verdict.NONE
        if self.vouches_for(stamp):
            self._drop_held()
            self.joined = True
            return Verdict.ADOPT
        if self.held is None or stamp < self.held[0]:
            self._drop_held()
            self.held = (stamp, agent, fb, cell, expected)
        else:
            record_sequence(self.drops, stamp, expected, feedback_topic(agent))
        return Verdict.NONE

    def far_ahead(self, agent: int, fb: Any, expected: tuple[int, int] | None) -> bool:
        """Is `fb` past the run's last episode, or more than max_catch_up episodes past `expected`? Then it is
        counted (`far_ahead`) and never caught up to."""
        if fb.episode > self.last_episode:
            bound = "the run's last episode"
        elif self.joined and expected is not None and fb.episode > expected[0] + self.max_catch_up:
            bound = f"max_catch_up={self.max_catch_up}"
        else:
            return False
        self.drops.record(WireError("far_ahead", f"episode {fb.episode} step {fb.step}, expected "
                                                 f"{expected or 'any'}: past {bound}"), feedback_topic(agent))
        return True

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
        self.joined = True
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
        out = {"caught_up": self.caught_up, "missed_feedback": self.missed_feedback,
               "stalls": self.patience.stalls if self.patience is not None else 0}
        return {k: v for k, v in out.items() if v}

    def giving_up(self, feedback_timeout: float) -> str:
        """The line an agent gives up on a silent world with (its patience expired): whether the world steps
        without it (its heartbeats still come), or is gone, or restarted as another incarnation or run."""
        # A world restarted mid-run is another incarnation, of another run unless it was given this one's nonce:
        # its messages are refused, never taken for the world this agent played with, so the run ends here.
        other = self.drops["other_incarnation"] + self.drops["other_run"]
        waited = (f"{self.patience.waited:.1f} s awake, {self.silent_for():.1f} s of wall time "
                  f"(feedback_timeout={feedback_timeout})")
        if self.behind is not None and not other:
            (world_e, world_s), (e, s) = self.behind
            return (f"no feedback taken for {waited}, while the world's heartbeats say it is at episode {world_e} "
                    f"step {world_s} and this agent waits for episode {e} step {s}: it takes no feedback (its "
                    "reader or executor stopped): giving up")
        why = (f"; {other} messages came from another world incarnation or run (other_incarnation, other_run): the "
               "world restarted (or another run's messages were replayed), and this run cannot go on with it"
               ) if other else ""
        return f"no valid message from the world (feedback or heartbeat) for {waited}{why}: giving up"

    def _drop_held(self) -> None:
        if self.held is not None:
            stamp, agent, _, _, expected = self.held
            record_sequence(self.drops, stamp, expected, feedback_topic(agent))
            self.held = None

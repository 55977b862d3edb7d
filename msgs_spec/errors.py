"""The one exception of the wire contract, and the counter nodes use to log, count and drop bad messages."""

from __future__ import annotations

import time
from typing import Any, Callable, Mapping, TypeVar

__all__ = ["KINDS", "FLOOD_WINDOW_S", "WireError", "DropCounter"]

FLOOD_WINDOW_S = 1.0  # a source refusing DropCounter.every messages within this long is flooded

# Every reason a message can be refused, with what it means. A `WireError.kind` is always one of these keys,
# so nodes can use it as a counter name ("dropped.<kind>" in their statistics).
KINDS: Mapping[str, str] = {
    "wrong_type": "the ROS message is not of the type the topic carries",
    "wrong_layout": "MultiArray layout is not the documented one (dims, label, size, stride, data_offset), "
    "or a statistics status has the wrong name",
    "wrong_length": "the data array does not hold exactly the documented number of values",
    "not_finite": "a number is NaN or infinite",
    "not_integer": "a field that must hold an integer holds a fraction",
    "out_of_range": "an integer is negative where it must not be, or does not fit the wire type (int32)",
    "malformed": "anything else the layout forbids: a flag that is not 0/1, done and truncated both set, "
    "a statistics key missing, repeated, unknown or unparsable",
    "unknown_agent": "an agent id outside 1..N",
    "wrong_agent": "a valid agent id, but not the agent whose topic the message came on",
    "action_out_of_range": "an action outside 0..3 (NORTH, EAST, SOUTH, WEST)",
    "cell_out_of_range": "a row or column outside the H x W grid",
    "stale_episode": "episode index lower than the one the receiver expects",
    "future_episode": "episode index higher than the one the receiver expects",
    "stale_step": "right episode, step index lower than the one the receiver expects",
    "future_step": "right episode, step index higher than the one the receiver expects",
    "unauthenticated": "the receiver holds the run's key and the message carries no MAC, or one that does not "
    "match (a writer without the key)",
    "other_run": "a sealed message of another run (its MAC matches the key, its run nonce is not the receiver's: "
    "recorded in an earlier run with the same key file), or statistics sealed to no run where the receiver "
    "knows its run",
    "other_incarnation": "a sealed message of this run from another life of its sender: a world other than the "
    "one the receiver is bound to (restarted, or a second one), or an agent's incarnation a newer one replaced",
    "far_ahead": "a feedback more than the agent's max_catch_up episodes past the one it expects, or past the "
    "run's last episode: never caught up to",
    "replayed": "a heartbeat whose beat is not above the last one heard (a replay, or a second world)",
    "conflicting": "a position for a step already heard from that peer, with another cell (a second writer), or "
    "statistics of an episode already heard that say otherwise (the launcher keeps the first)",
}


class WireError(ValueError):
    """A message that breaks the wire contract. `kind` is a key of `KINDS`; `detail` says what was seen."""

    def __init__(self, kind: str, detail: str = "") -> None:
        if kind not in KINDS:
            raise ValueError(f"unknown WireError kind {kind!r}; known kinds: {', '.join(KINDS)}")
        self.kind = kind
        self.detail = detail
        super().__init__(f"{kind}: {detail}" if detail else kind)

    def __reduce__(self):  # picklable (multiprocessing, logging handlers)
        return (type(self), (self.kind, self.detail))


T = TypeVar("T")


class DropCounter:
    """Count refused messages by kind and by source (`by_source`); log the first of each kind and then every
    `every`-th. A source refusing `every` messages within FLOOD_WINDOW_S is flooded: said once, with its rate
    (`floods`), then only counted. Nodes route every decode through `guard` (msgs_spec/README.md, "Validation
    and dropping"). Not thread-safe: use it from one executor thread (the project's SingleThreadedExecutor)."""

    def __init__(self, log: Callable[[str], Any] | None = None, every: int = 100,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if int(every) < 1:
            raise ValueError("every must be >= 1")
        self._log = log
        self.every = int(every)
        self._clock = clock
        self._counts: dict[str, int] = {}
        self._windows: dict[str, list] = {}  # source -> [its window's start, drops in it]
        self.floods: dict[str, float] = {}  # source -> drops a second when it was reported a flood
        self.by_source: dict[str, int] = {}  # source -> its drops (of any kind)

    def record(self, error: WireError, source: str = "") -> int:
        """Count `error`, logged as the class says; the count of its kind."""
        n = self._counts.get(error.kind, 0) + 1
        self._counts[error.kind] = n
        self.by_source[source] = self.by_source.get(source, 0) + 1
        if self._log is None or source in self.floods:
            return n
        now = self._clock()
        window = self._windows.get(source)
        if window is None or now - window[0] > FLOOD_WINDOW_S:
            window = self._windows[source] = [now, 0]
        window[1] += 1
        where = f" on {source}" if source else ""
        if window[1] >= self.every:
            rate = self.floods[source] = window[1] / max(now - window[0], 1e-3)
            self._log(f"a flood of refused messages{where}: {window[1]} in {now - window[0]:.2f} s (about "
                      f"{rate:.0f} a second; this one {error.kind}); every one is counted, no further line comes "
                      f"for it{where}")
        elif n == 1 or n % self.every == 0:
            seen = "first of this kind" if n == 1 else f"{n} of this kind so far"
            self._log(f"dropped message{where}: {error.kind}: {error.detail} "
                      f"({seen}; logging the first and every {self.every}-th)")
        return n

    def guard(self, fn: Callable[..., T], *args: Any, source: str = "", **kwargs: Any) -> T | None:
        """Call `fn(*args, **kwargs)`; on WireError record it and return None. Other exceptions propagate
        (they are bugs, not bad input: the decoders raise only WireError for any message)."""
        try:
            return fn(*args, **kwargs)
        except WireError as e:
            self.record(e, source)
            return None

    @property
    def counts(self) -> dict[str, int]:
        """A copy of the counts by kind (kinds never seen are absent)."""
        return dict(self._counts)

    @property
    def total(self) -> int:
        return sum(self._counts.values())

    def __getitem__(self, kind: str) -> int:
        return self._counts.get(kind, 0)

    def as_counters(self, prefix: str = "dropped.") -> dict[str, int]:
        """The counts keyed as statistics counters, e.g. {"dropped.stale_step": 3}."""
        return {prefix + k: v for k, v in sorted(self._counts.items())}

    def __repr__(self) -> str:
        return f"DropCounter({self._counts!r}, every={self.every})"

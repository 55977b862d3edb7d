"""The progress of a launch (or a collect) on stderr: a tqdm bar on a terminal, otherwise plain lines."""

from __future__ import annotations

import sys
import time
from typing import Callable

from tqdm import tqdm

__all__ = ["Progress"]

STATUS_S = 5.0  # between two episodes, how often the progress says where the run is


class Progress:
    """A tqdm bar on a terminal; otherwise a plain line every 5% of the episodes (and at the last). It counts
    every episode; the label says "greedy" once the learning episodes (the first `learning`) are over. Between
    them, every STATUS_S at most, where the run is (`within`): how many nodes are up, then the episode and step,
    so a big map shows progress from its first step."""

    def __init__(self, label: str, episodes: int, learning: int, enabled: bool):
        self.label, self.episodes, self.learning, self.enabled = label, episodes, learning, enabled
        self.tty = enabled and sys.stderr.isatty()
        self.bar = tqdm(total=episodes, desc=label, unit="episode", disable=not self.tty)
        self.every = max(1, episodes // 20)
        self.shown = 0
        self.said = time.monotonic()  # when a line (or the bar) last said something

    def within(self, where: Callable[[], str]) -> None:
        """Say where() ('starting: 12/33 nodes up', 'episode 0, step 1200') if nothing was said for STATUS_S."""
        if not self.enabled or time.monotonic() - self.said < STATUS_S:
            return
        self.said = time.monotonic()
        if self.tty:
            self.bar.set_postfix_str(where())
        else:
            print(f"{self.label}: {where()}", file=sys.stderr, flush=True)

    def update(self, done: int, collisions: int, joint_states: int, peer_messages: int) -> None:
        self.said = time.monotonic()
        label = f"{self.label} greedy" if done > self.learning else self.label
        if self.tty:
            self.bar.set_description(label, refresh=False)
            self.bar.set_postfix(collisions=collisions, joint_states=joint_states, peer_msgs=peer_messages,
                                 refresh=False)
            self.bar.update(done - self.shown)
        elif self.enabled and (done // self.every > self.shown // self.every or done == self.episodes):
            print(f"{label}: episodes {done}/{self.episodes}, {collisions} collisions, {joint_states} joint "
                  f"states, {peer_messages} peer messages", file=sys.stderr, flush=True)
        self.shown = done

    def close(self) -> None:
        self.bar.close()

"""What every map generator does with its sizes and its agents: sizes checked as whole numbers of at least 1,
then the agents' starts and goals drawn from the seed among the places the layout has for them."""

from __future__ import annotations

import random
from collections.abc import Sequence
from typing import TypeVar

Place = TypeVar("Place")


def check_sizes(**sizes) -> None:
    """ValueError naming the first size that is not a whole number of at least 1."""
    for name, value in sizes.items():
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be a whole number of at least 1, got {value!r}")


def draw_starts_and_goals(agents: int, seed: int, docks: tuple[str, Sequence[Place]],
                          goals: tuple[str, Sequence[Place]], layout: str,
                          remedy: str) -> tuple[list[Place], list[Place]]:
    """(distinct starts among `docks`, distinct goals among `goals`), each a (what, places) pair, drawn by
    `random.Random(seed)`; ValueError "N agents do not fit: LAYOUT have K WHAT; REMEDY" where there are too few."""
    for what, places in (goals, docks):
        if agents > len(places):
            raise ValueError(f"{agents} agents do not fit: {layout} have {len(places)} {what}; {remedy}")
    rng = random.Random(seed)
    return rng.sample(docks[1], agents), rng.sample(goals[1], agents)

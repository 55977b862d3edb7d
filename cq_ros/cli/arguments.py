"""The argument types and shared options of `cq-ros`'s parsers (offline_parser.py, ros_parser.py): a bad value
is one line naming what is wrong and why, and a count that would run for days or make a map for minutes is
refused before any work starts.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from ..compiled import ENGINES
from ..lab.cluster import scheduler_address
from ..learners import LEARNERS


class Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (with where to find help), not the whole usage."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


# Upper bounds on counts that set how long a command runs: past them it would not finish in a day (episodes, runs)
# or would sit silent for minutes making the map (a warehouse of 1,000 AGVs takes 20 s, growing faster than
# linearly), so a typo gets one line instead of a run that never ends.
MAX_EPISODES = 10_000_000
MAX_RUNS = 10_000
MAX_AGENTS = 256
MAX_WAREHOUSE_SIDE = 256  # aisles, and cells along an aisle


def at_most(high: int, why: str):
    """An argparse type: a whole number from 1 to `high`; past it, one line saying `why`."""
    def parse(text: str) -> int:
        value = positive_int(text)
        if value > high:
            raise argparse.ArgumentTypeError(f"must be at most {high:,}, got {text} ({why})")
        return value
    return parse


episode_count = at_most(MAX_EPISODES, "more would not finish in a day")
run_count = at_most(MAX_RUNS, "more would not finish in a day")
agent_count = at_most(MAX_AGENTS, "a larger map takes minutes to make and far longer to learn")
side_length = at_most(MAX_WAREHOUSE_SIDE, "a larger warehouse takes minutes to make")


def algo_list(text: str) -> list[str]:
    algos = [a.strip() for a in text.split(",") if a.strip()]
    unknown = [a for a in algos if a not in LEARNERS]
    if unknown or not algos:
        what = ", ".join(unknown) if unknown else repr(text)
        raise argparse.ArgumentTypeError(f"unknown algorithm {what}; choose from {','.join(LEARNERS)}")
    if len(set(algos)) != len(algos):  # twice the same runs, and a result folder that holds them once
        raise argparse.ArgumentTypeError(f"an algorithm is given twice in {text!r}")
    return algos


def algo_name(text: str) -> str:
    if text not in LEARNERS:
        raise argparse.ArgumentTypeError(f"unknown algorithm {text!r}; choose one of {','.join(LEARNERS)}")
    return text


def nonempty_path(text: str) -> Path:
    """A path that names something: '' would be the current directory (`--out '' --force` wrote results there)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a path, got an empty one")
    return Path(text)


def size_list(text: str) -> list[int]:
    """Comma-separated fleet sizes, each once."""
    return list(dict.fromkeys(agent_count(part) for part in text.split(",")))


def seed_list(text: str) -> list[int]:
    """Comma-separated whole numbers, none negative (as --seed), each once."""
    try:
        seeds = [int(part) for part in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected whole numbers separated by commas, got {text!r}") from None
    if any(seed < 0 for seed in seeds):
        raise argparse.ArgumentTypeError(f"every seed must be at least 0, got {text}")
    if len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(f"a seed is given twice in {text!r}")
    return seeds


def number(low: float, high: float | None = None, kind: type = float, strict: bool = False):
    """An argparse type: a number of `kind` in [low, high] (low excluded when `strict`)."""
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {'a whole number' if kind is int else 'a number'}, "
                                             f"got {text!r}") from None
        if not math.isfinite(value):  # nan passes every comparison below: a duration of nan never ended
            raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
        if value < low or (strict and value == low) or (high is not None and value > high):
            span = f"more than {low:g}" if strict else f"at least {low:g}"
            raise argparse.ArgumentTypeError(f"must be {span}{f' and at most {high:g}' if high is not None else ''}, "
                                             f"got {text}")
        return value
    return parse


seed_int = number(0, kind=int)  # numpy's SeedSequence takes no negative seed
# ROS_DOMAIN_ID: Fast DDS derives its ports from it; 0..232 is the range that works on Linux.
domain_id = number(0, 232, kind=int)
seconds = number(0, strict=True)


def add_settings_options(p: argparse.ArgumentParser, nodes: bool = False) -> None:
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="change a setting (repeatable); `cq-ros settings` lists them" + (
                       "; a node parameter too (e.g. feedback_timeout=60, heartbeat_period=0.5: the "
                       "tables in node_runtime/parameters.py)" if nodes else ""))
    p.add_argument("--force", action="store_true", help="overwrite an existing result directory")


def add_run_options(p: argparse.ArgumentParser, runs: int, episodes: int) -> None:
    p.add_argument("--runs", type=run_count, default=runs, help=f"independent runs (default {runs})")
    p.add_argument("--episodes", type=episode_count, default=episodes, help=f"episodes per run (default {episodes})")
    p.add_argument("--seed", type=seed_int, default=0, help="master seed (default 0)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--jobs", type=positive_int, default=None, help="worker processes (default: one per core)")
    where.add_argument("--cluster", type=scheduler_address, default=None, metavar="ADDRESS",
                       help="run on the workers of a running Dask scheduler, tcp://HOST:PORT (needs the extra "
                            "cq-ros[cluster]; docs/cluster.md)")
    add_engine_option(p)
    add_settings_options(p)


def add_engine_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--engine", choices=ENGINES, default="compiled",
                   help="the compiled engine (default: numba; the reference plays the learners it does not cover, "
                        "and everything where numba cannot load) or the reference Python engine; both give the same "
                        "results, the manifest says which played")


def add_domain_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--domain-id", type=domain_id, default=None, metavar="N",
                   help="ROS_DOMAIN_ID to use (default: the environment's)")

"""The `cq-ros` command: maps, offline experiments, the paper's reproduction, the planner, and the ROS tools.

Bad arguments print one line naming what is wrong and exit with code 2, as argparse does.
"""

from __future__ import annotations

import argparse
import math
import multiprocessing
import os
import signal
import sys
import threading
from contextlib import contextmanager
from pathlib import Path

from ..compiled import ENGINES
from ..gridmap import MapError
from ..lab.cluster import ClusterError, scheduler_address
from ..lab.runner import RunFailed
from ..learners import DEFAULT_ALGORITHMS, LEARNERS
from ..mapgen.shelves import DEFAULT_SHELF_COLS, DEFAULT_SHELF_ROWS
from ..mapgen.warehouse import DEFAULT_AISLE_LENGTH
from ..settings import SettingsError
from .pipe import reader_may_leave


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (with where to find help), not the whole usage."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _positive(text: str) -> int:
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
DEFAULT_PLAN_SECONDS = 300.0  # a 128-AGV generated warehouse plans in 30 s of CPU (docs/warehouses.md)


def _at_most(high: int, why: str):
    """An argparse type: a whole number from 1 to `high`; past it, one line saying `why`."""
    def parse(text: str) -> int:
        value = _positive(text)
        if value > high:
            raise argparse.ArgumentTypeError(f"must be at most {high:,}, got {text} ({why})")
        return value
    return parse


_episodes = _at_most(MAX_EPISODES, "more would not finish in a day")
_runs = _at_most(MAX_RUNS, "more would not finish in a day")
_agents = _at_most(MAX_AGENTS, "a larger map takes minutes to make and far longer to learn")
_side = _at_most(MAX_WAREHOUSE_SIDE, "a larger warehouse takes minutes to make")


def _algos(text: str) -> list[str]:
    algos = [a.strip() for a in text.split(",") if a.strip()]
    unknown = [a for a in algos if a not in LEARNERS]
    if unknown or not algos:
        what = ", ".join(unknown) if unknown else repr(text)
        raise argparse.ArgumentTypeError(f"unknown algorithm {what}; choose from {','.join(LEARNERS)}")
    if len(set(algos)) != len(algos):  # twice the same runs, and a result folder that holds them once
        raise argparse.ArgumentTypeError(f"an algorithm is given twice in {text!r}")
    return algos


MAX_DPI = 600


def _path(text: str) -> Path:
    """A path that names something: '' would be the current directory (`--out '' --force` wrote results there)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a path, got an empty one")
    return Path(text)


def _sizes(text: str) -> list[int]:
    """Comma-separated fleet sizes, each once."""
    return list(dict.fromkeys(_agents(part) for part in text.split(",")))


def _seeds(text: str) -> list[int]:
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


def _number(low: float, high: float | None = None, kind: type = float, strict: bool = False):
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


def _algo(text: str) -> str:
    if text not in LEARNERS:
        raise argparse.ArgumentTypeError(f"unknown algorithm {text!r}; choose one of {','.join(LEARNERS)}")
    return text


def _add_settings_options(p: argparse.ArgumentParser, nodes: bool = False) -> None:
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="change a setting (repeatable); `cq-ros settings` lists them" + (
                       "; a node parameter too (e.g. feedback_timeout=60, heartbeat_period=0.5: the "
                       "tables in node_runtime/parameters.py)" if nodes else ""))
    p.add_argument("--force", action="store_true", help="overwrite an existing result directory")


def _add_run_options(p: argparse.ArgumentParser, runs: int, episodes: int) -> None:
    p.add_argument("--runs", type=_runs, default=runs, help=f"independent runs (default {runs})")
    p.add_argument("--episodes", type=_episodes, default=episodes, help=f"episodes per run (default {episodes})")
    p.add_argument("--seed", type=_seed, default=0, help="master seed (default 0)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--jobs", type=_positive, default=None, help="worker processes (default: one per core)")
    where.add_argument("--cluster", type=scheduler_address, default=None, metavar="ADDRESS",
                       help="run on the workers of a running Dask scheduler, tcp://HOST:PORT (needs the extra "
                            "cq-ros[cluster]; docs/cluster.md)")
    _add_engine_option(p)
    _add_settings_options(p)


def _add_engine_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--engine", choices=ENGINES, default="compiled",
                   help="the compiled engine (default: numba; the reference plays the learners it does not cover, "
                        "and everything where numba cannot load) or the reference Python engine; both give the same "
                        "results, the manifest says which played")


_seed = _number(0, kind=int)  # numpy's SeedSequence takes no negative seed
# ROS_DOMAIN_ID: Fast DDS derives its ports from it; 0..232 is the range that works on Linux.
_domain_id = _number(0, 232, kind=int)
_seconds = _number(0, strict=True)


def _generator(kinds, name: str, what: str, description: str) -> argparse.ArgumentParser:
    """The parser of `cq-ros generate NAME`, with the agents and the seed that draws their starts and goals."""
    p = kinds.add_parser(name, help=what, description=description)
    p.add_argument("--agents", type=_agents, required=True, metavar="N", help="AGVs, each with its own goal")
    p.add_argument("--seed", type=_seed, default=0, help="draws the starts and goals (default 0)")
    return p


def _add_domain_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--domain-id", type=_domain_id, default=None, metavar="N",
                   help="ROS_DOMAIN_ID to use (default: the environment's)")


def _add_ros_parsers(sub) -> None:
    p = sub.add_parser("launch", help="run one algorithm on one map as ROS 2 nodes (a world process and one "
                                      "process per AGV) and write results and figures",
                       epilog="exit status: 0 every episode played as the offline engine plays it; 3 every episode "
                              "played, but some step was not (a missed or unapplied action, a feedback never "
                              "heard: the last line says how many episodes); 1 the launch failed or ended early; "
                              "2 bad arguments; 130 interrupted. manifest.json says how every launch ended "
                              "(`ended`).")
    p.add_argument("--map", default=None, help="a shipped map name or a path to a map file (required unless "
                                                "--params-file)")
    p.add_argument("--algo", type=_algo, default=None, help=f"one of {','.join(LEARNERS)} (required unless "
                                                             "--params-file)")
    p.add_argument("--out", type=_path, required=True, help="result directory (node logs in its logs/; the "
                                                           "system it ran in its params.yaml)")
    p.add_argument("--params-file", type=_path, default=None, metavar="FILE",
                   help="start the system a params.yaml describes (as every launch writes it: map, algorithm, "
                        "episodes, seed, settings and node parameters, under any namespace) instead of --map, "
                        "--algo, --episodes, --seed, --set")
    p.add_argument("--key", type=_path, default=None, metavar="FILE",
                   help="key the run with this key file (made by `cq-ros key`), named in params.yaml and kept "
                        "(default: a key of the launch's own, in a file without a name)")
    p.add_argument("--restart-agents", type=_number(0, 1000, kind=int), default=0, metavar="N",
                   help="start an agent node that dies again, from its checkpoint, up to N times in all (default 0: "
                        "a node that dies ends the launch); its checkpoint is saved every --set checkpoint_every=E "
                        "learning episodes (default 50), and the episodes it learnt past it are lost: counted per "
                        "restart on stderr and in the manifest (`restarts.learning_lost`)")
    p.add_argument("--view", type=_number(0, 65535, kind=int), default=None, metavar="PORT",
                   help="serve the run live to Foxglove on ws://127.0.0.1:PORT, as cq-ros view (the extra `view`; "
                        "0: any free port, printed at start)")
    p.add_argument("--episodes", type=_episodes, default=None, help="episodes (default 500)")
    p.add_argument("--seed", type=_seed, default=None, help="master seed (default 0)")
    p.add_argument("--domain-id", type=_domain_id, default=None, metavar="N",
                   help="ROS_DOMAIN_ID of the run (default: the environment's ROS_DOMAIN_ID, else random in 100..200)")
    p.add_argument("--namespace", default=None,
                   help="ROS namespace of the run, e.g. /demo or demo (default: random cq_<hex>)")
    p.add_argument("--step-timeout", type=_seconds, default=2.0, metavar="S",
                   help="seconds the world waits for an action before the agent stays (default 2)")
    p.add_argument("--peer-linger-steps", type=_number(0, kind=int), default=None, metavar="N",
                   help="decision steps an agent keeps a peer subscription it no longer needs (default: the "
                        "agent node's, 0)")
    p.add_argument("--compose", action="store_true",
                   help="run every node in one process on one executor (a component container) instead of a "
                        "process per node")
    p.add_argument("--executor", choices=("events", "single"), default=None,
                   help="the nodes' executor: rclpy's EventsExecutor (default) or the SingleThreadedExecutor")
    p.add_argument("--hosts", default=None, metavar="PREFIX",
                   help="run each node on its own host made by `cq-ros hosts up` (root; re-runs itself on the "
                        "world's host)")
    p.add_argument("--discovery", choices=("subnet", "static"), default=None,
                   help="with --hosts: multicast discovery on the subnet (default), or unicast to ROS_STATIC_PEERS "
                        "only")
    p.add_argument("--no-figures", dest="figures", action="store_false", help="write the tables only")
    _add_settings_options(p, nodes=True)

    p = sub.add_parser("collect", help="listen to a system started by hand (its statistics) and write what a "
                                       "launch writes: episodes.csv, greedy.csv, observe.csv, manifest.json")
    p.add_argument("--out", type=_path, required=True, help="result directory")
    p.add_argument("--namespace", default=None, help="the system's namespace (default: the one system on the domain)")
    p.add_argument("--wait", type=_seconds, default=60.0, metavar="S",
                   help="seconds to look for the system before giving up (default 60)")
    p.add_argument("--force", action="store_true", help="overwrite an existing result directory")
    _add_domain_option(p)

    p = sub.add_parser("view", help="a live view in Foxglove: a Foxglove WebSocket server relaying a running "
                                    "system's topics with their ROS 2 schemas, until Ctrl-C (extra `view`)")
    p.add_argument("--namespace", default=None, help="the system's namespace (default: the one system on the domain)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    p.add_argument("--port", type=_number(0, 65535, kind=int), default=8765, help="port (default 8765; 0: any free)")
    p.add_argument("--wait", type=_seconds, default=60.0, metavar="S",
                   help="seconds to look for the system before giving up (default 60)")
    _add_domain_option(p)

    p = sub.add_parser("checkpoint", help="agent checkpoints: convert one of the old pickled format (3) into the "
                                          "current one (.npz, which loads without running code)")
    actions = p.add_subparsers(dest="action", required=True, parser_class=_Parser)
    p = actions.add_parser("convert", help="write a pickled checkpoint (format 3) as an .npz checkpoint",
                           description="Unpickle OLD and write it as the .npz checkpoint NEW. Unpickling runs "
                                       "whatever code the file holds: run it only on a checkpoint you trust (one your "
                                       "own cq-ros wrote).")
    p.add_argument("old", type=_path, metavar="OLD", help="a pickled checkpoint (.pkl) you trust")
    p.add_argument("new", type=_path, metavar="NEW", help="the .npz checkpoint to write (never overwritten)")

    p = sub.add_parser("key", help="make a key file for a system kept in a parameters file (its key_file; "
                                   "cq-ros launch --key FILE)")
    p.add_argument("--out", type=_path, required=True, metavar="FILE", help="the key file to make (mode 0600; "
                                                                            "never overwritten)")

    p = sub.add_parser("hosts", help="make or remove hosts for --hosts: network namespaces joined by a bridge, "
                                     "addresses from 198.18.0.0/15 (root)")
    p.add_argument("action", choices=("up", "down", "list"),
                   help="up: make a world host and one per AGV; down: remove them; list: the sets there are")
    p.add_argument("--agents", type=_positive, default=2, help="up: AGV hosts (default 2)")
    p.add_argument("--prefix", default=None,
                   help="the set's name: cqr and up to 8 letters or digits (up: default random; down: required)")

    p = sub.add_parser("echo", help="print the messages of a topic as YAML, like `ros2 topic echo`")
    p.add_argument("topic", help="topic name, e.g. /cq_1a2b3c4d/agv1/position")
    p.add_argument("--count", type=_positive, default=None, metavar="N", help="exit after N messages")
    p.add_argument("--timeout", type=_seconds, default=None, metavar="S",
                   help="exit after S seconds (code 1 if no message came)")
    _add_domain_option(p)

    for name, what in (("topics", "the live topics, like `ros2 topic list`"),
                       ("nodes", "the live nodes with their namespaces, like `ros2 node list`")):
        p = sub.add_parser(name, help=f"list {what}")
        if name == "topics":
            p.add_argument("-t", "--show-types", dest="show_types", action="store_true", help="show each topic's type")
        else:
            p.add_argument("-a", "--all", dest="all_nodes", action="store_true", help="show hidden nodes too")
        p.add_argument("--wait", type=_seconds, default=None, metavar="S",
                       help="list once the graph has not changed for 1.5 s, waiting S seconds at most (default 15)")
        _add_domain_option(p)

    p = sub.add_parser("record", help="record topics to a rosbag2 file (default: every cq_ros topic)")
    p.add_argument("--out", type=_path, required=True, help="bag directory to create")
    p.add_argument("--topics", nargs="+", default=None, metavar="TOPIC", help="record these topics only")
    p.add_argument("--duration", type=_seconds, default=None, metavar="S", help="stop after S seconds")
    p.add_argument("--count", type=_positive, default=None, metavar="N", help="stop after N messages")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="storage plugin (default mcap)")
    p.add_argument("--namespace", default=None,
                   help="record one system's topics: those under this namespace, against which relative --topics "
                        "resolve (default: every cq_ros topic, under any namespace)")
    _add_domain_option(p)

    p = sub.add_parser("render", help="draw one episode as an animated GIF (or MP4 where ffmpeg is installed): "
                                      "the map, the AGVs, their goals and whom each agent looks at; from the "
                                      "offline engine (--map, --algo) or from a bag of `cq-ros record` (--bag)")
    p.add_argument("--out", type=_path, required=True, help="the animation to write: NAME.gif, or NAME.mp4 (ffmpeg)")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--map", help="run the offline engine on this map (a shipped name or a path)")
    source.add_argument("--bag", type=_path, help="a rosbag2 directory recorded by `cq-ros record`")
    # None until given, so that a bag can refuse them: their defaults are the engine's (_render)
    p.add_argument("--algo", type=_algo, default=None, help=f"with --map: one of {','.join(LEARNERS)} (default cq)")
    p.add_argument("--episodes", type=_episodes, default=None, help="with --map: episodes to learn (default 100)")
    p.add_argument("--seed", type=_seed, default=None, help="with --map: master seed (default 0)")
    p.add_argument("--episode", type=_number(0, kind=int), default=None, metavar="E",
                   help="the episode to draw, from 0 (default: with --map, the last learning episode; with --bag, the "
                        "last episode the bag holds whole)")
    p.add_argument("--greedy", action="store_true",
                   help="with --map: draw the greedy policy's first episode after the learning ones, not a "
                        "learning episode")
    p.add_argument("--fps", type=_seconds, default=4.0, help="frames (steps) per second (default 4)")
    p.add_argument("--dpi", type=_number(0, MAX_DPI, strict=True), default=None,
                   help=f"pixels an inch of the picture, a cell being 0.6 in (default 72, at most {MAX_DPI}: a "
                        "warehouse at more takes gigabytes); fewer make a smaller file")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="with --map: change a setting (repeatable)")
    _add_engine_option(p)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="cq-ros", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)

    sub.add_parser("maps", help="list the shipped maps with their cells and agents")
    p = sub.add_parser("show", help="draw a map in the terminal")
    p.add_argument("map", help="a shipped map name or a path to a map file")
    sub.add_parser("settings", help="list every setting with its default and description")

    p = sub.add_parser("generate", help="generate a map (print it, or write it with --out)")
    kinds = p.add_subparsers(dest="kind", required=True, metavar="KIND", parser_class=_Parser)
    what = ("a warehouse: two-lane cross-aisles (top and bottom), two-lane aisles behind one-lane entrances, "
            "pick stations in bays beside the aisles (cq_ros.mapgen.warehouse)")
    p = _generator(kinds, "warehouse", what, f"Print or write {what}. Starts (docks on the cross-aisles) and goals "
                   "(distinct bays) are drawn from --seed; every agent can reach its goal with the others parked at "
                   "theirs. The map carries `set reward_step=-1`, `set gamma=0.98` and "
                   "`set epsilon_decay_episodes=1500`.")
    p.add_argument("--aisles", type=_side, default=None, metavar="A",
                   help="aisles (default: 2 + ceil(N/4): 4 for 8 AGVs, 6 for 16, 10 for 32, 34 for 128)")
    p.add_argument("--aisle-length", type=_side, default=DEFAULT_AISLE_LENGTH, metavar="L",
                   help=f"cells along each aisle, one pick station per row (default {DEFAULT_AISLE_LENGTH})")
    p.add_argument("--blocks", type=_side, default=1, metavar="B",
                   help="bands of aisles one below the other, sharing their cross-aisles, for a large fleet "
                        "(default 1; the default aisles become 2 + ceil(N/4B))")
    p.add_argument("--slip", type=_number(0.0, 1.0), default=0.0, metavar="P",
                   help="delays: the map's default `slip` (a move fails with probability P; default 0)")
    p.add_argument("--start-hold", type=_number(0, None, int), default=0, metavar="H",
                   help="delays: the map's default `start_hold` (each AGV waits 0..H steps at its dock; default 0)")
    p.add_argument("--out", type=_path, default=None, metavar="FILE", help="write the map here (default: print it)")
    p.add_argument("--force", action="store_true", help="overwrite an existing FILE")
    what = ("a warehouse on a plain cell grid in MovingAI's .map and .scen form, blocks of shelves between "
            "two-cell corridors with docking floor left and right, 160 x 62 cells by default "
            "(cq_ros.mapgen.shelves)")
    p = _generator(kinds, "shelves", what, f"Write {what}. Starts (docking floor) and goals (distinct pick faces, "
                   "the corridor cells below a shelf) are drawn from --seed; every agent can reach its goal with "
                   "the others parked at theirs. `cq-ros import movingai STEM.map --scen STEM.scen --agents N` "
                   "makes it a map of ours.")
    p.add_argument("--shelf-rows", type=_side, default=DEFAULT_SHELF_ROWS, metavar="R",
                   help=f"rows of shelves, each 2 cells deep under a 2-cell corridor (default {DEFAULT_SHELF_ROWS})")
    p.add_argument("--shelf-cols", type=_side, default=DEFAULT_SHELF_COLS, metavar="C",
                   help=f"shelves in a row, each 10 cells long, 2-cell corridors between "
                        f"(default {DEFAULT_SHELF_COLS})")
    p.add_argument("--out", type=_path, required=True, metavar="STEM", help="write STEM.map and STEM.scen")
    p.add_argument("--force", action="store_true", help="overwrite existing files")

    p = sub.add_parser("import", help="convert a map from another format into ours (print it, or write it with --out)")
    kinds = p.add_subparsers(dest="kind", required=True, metavar="FORMAT", parser_class=_Parser)
    p = kinds.add_parser("movingai", help="a MovingAI .map (and the first N tasks of a .scen) as a map of ours",
                         description="Convert a MovingAI grid (. G passable, @ O T blocked; S and W rejected) and, "
                         "with --scen, its first N tasks (x the column, y the row, 0-based from the top left) into "
                         "our map format (cq_ros.mapgen.movingai). A fault is one line naming the file and line.")
    p.add_argument("map", type=_path, metavar="MAP.map", help="a MovingAI map file")
    p.add_argument("--scen", type=_path, default=None, metavar="FILE.scen",
                   help="a MovingAI scenario: its first --agents tasks become the agents (default: none, the "
                        "drawing only, to which agent lines must be added)")
    p.add_argument("--agents", type=_agents, default=None, metavar="N", help="with --scen: the tasks to take")
    p.add_argument("--out", type=_path, default=None, metavar="FILE", help="write the map here (default: print it)")
    p.add_argument("--force", action="store_true", help="overwrite an existing FILE")

    p = sub.add_parser("experiment", help="run algorithms on one map offline and write results and figures")
    p.add_argument("--map", required=True, help="a shipped map name or a path to a map file")
    p.add_argument("--algo", type=_algos, default=list(DEFAULT_ALGORITHMS),
                   help=f"comma-separated, from {','.join(LEARNERS)} (default: the paper's five and ours, "
                        f"{','.join(DEFAULT_ALGORITHMS)})")
    p.add_argument("--out", type=_path, required=True, help="result directory")
    p.add_argument("--no-figures", dest="figures", action="store_false", help="write the tables only")
    _add_run_options(p, runs=10, episodes=10_000)

    p = sub.add_parser("plan", help="plan every AGV's route centrally under the world's rules (the yardstick "
                                    "for the learners): makespan, sum of costs, arrival steps; then the plan "
                                    "executed under the world's delays")
    p.add_argument("--map", required=True, help="a shipped map name or a path to a map file")
    p.add_argument("--seed", type=_seed, default=0, help="seed of the priority orders and LNS rounds (default 0)")
    p.add_argument("--cbs-nodes", type=_number(0, kind=int), default=1000, metavar="N",
                   help="search nodes of the optimal conflict-based search before falling back on prioritized "
                        "planning (default 1000; 0: skip it)")
    p.add_argument("--orders", type=_positive, default=20, metavar="N",
                   help="priority orders prioritized planning tries (default 20)")
    p.add_argument("--rounds", type=_number(0, kind=int), default=300, metavar="N",
                   help="rounds of large neighbourhood search improving a prioritized plan (default 300)")
    p.add_argument("--time-limit", type=_number(0, kind=float, strict=True), default=DEFAULT_PLAN_SECONDS,
                   metavar="S", help="seconds (wall clock) the search may take: conflict-based search stops at "
                   "half of them, LNS rounds stop at the end keeping the plan improved so far, and with no plan "
                   f"by then the command says so and exits 1 (default {DEFAULT_PLAN_SECONDS:g})")
    p.add_argument("--show", action="store_true",
                   help="print every agent's moves (N E S W; lower case: a bump into a wall, i.e. a wait)")
    p.add_argument("--slip", type=_number(0, 1), default=None, metavar="P",
                   help="execute the plan where a move fails with probability P (default: the map's own slip)")
    p.add_argument("--start-hold", type=_number(0, kind=int), default=None, metavar="H",
                   help="execute the plan where each AGV's first 0..H moves fail (default: the map's own)")
    p.add_argument("--executions", type=_number(0, kind=int), default=100, metavar="N",
                   help="seeded executions of the plan under those delays, kept in order by its action "
                        "dependency graph (cq_ros.mapf.execute); execution r draws the delays of a learner's run r "
                        "(default 100; 0: none)")
    p.add_argument("--stop-anywhere", action="store_true",
                   help="let an executing AGV wait in a cell without a wall by sending no action (a stay the "
                        "learners do not have): what the world's lack of a wait action costs the executions")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="change a setting of the executions' world (repeatable); `cq-ros settings` lists them")

    p = sub.add_parser("reproduce", help="the paper's grid (4 maps x 5 algorithms), figures and REPORT.md")
    p.add_argument("--out", type=_path, required=True, help="result directory")
    _add_run_options(p, runs=10, episodes=10_000)
    p.add_argument("--no-sweep", dest="sweep", action="store_false", help="skip the settings sweep")
    p.add_argument("--seeds", type=_seeds, default=None, metavar="S,S,...",
                   help="master seeds, instead of --seed: the grid runs once per seed (the first's in OUT, the "
                        "others' in OUT/seed_S), and when the collision averages settle (claims 1 and 2) is quoted "
                        "as a range over them, which takes at least 3 (e.g. 0,1,2)")
    p = sub.add_parser("study", help="learners on held-out delayed warehouses, frozen greedy policies against the "
                                     "planner: intervals over units, paired differences, ratios (OUT/study.md)",
                       description="Per fleet size, MAPS warehouses generated from held-out generator seeds x RUNS "
                       "runs; every configuration learns EPISODES episodes, then two greedy copies of that run play "
                       "G episodes each, one frozen and one learning; every K learning episodes a frozen copy plays "
                       "the curve's. OUT holds units already played: a rerun with the same protocol plays only the "
                       "missing units. cq_ros.lab.held_out says what it writes.")
    p.add_argument("--agents", type=_sizes, required=True, metavar="N,N,...", help="fleet sizes, e.g. 8,12")
    p.add_argument("--maps", type=_positive, default=10, help="generated maps per size (default 10)")
    p.add_argument("--greedy-episodes", type=_number(1, kind=int), default=100, metavar="G",
                   help="greedy episodes per unit and copy (default 100)")
    p.add_argument("--algos", type=_algos, default=["cq", "indep"],
                   help="comma-separated, the first the reference of differences and ratios (default cq,indep)")
    p.add_argument("--variant", action="append", default=[], metavar="NAME=ALGO:KEY=VALUE,...",
                   help="add a configuration: an algorithm with settings of its own over the study's (repeatable)")
    p.add_argument("--tuning", action="store_true",
                   help="draw the maps from the tuning generator seeds (0, 7), where settings are chosen, instead of "
                        "the held-out ones; the report says so")
    p.add_argument("--slip", type=_number(0, 1), default=0.1, metavar="P", help="the maps' slip (default 0.1)")
    p.add_argument("--curve-every", type=_positive, default=250, metavar="K",
                   help="learning episodes between the curve's points (default 250)")
    p.add_argument("--curve-episodes", type=_positive, default=20, metavar="C",
                   help="frozen greedy episodes per point of the curve (default 20)")
    p.add_argument("--out", type=_path, required=True,
                   help="result directory (study.md, units.csv, curve.csv, planner.csv, maps/); resumed if it holds "
                        "a study of the same protocol")
    _add_run_options(p, runs=10, episodes=2000)
    _add_ros_parsers(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    return reader_may_leave(lambda: _main(argv))


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # `launch --hosts` runs them again on the world's host
    try:
        with _sigterm_as_ctrl_c():
            return _dispatch(args)
    except BrokenPipeError:  # the reader left (`cq-ros maps | head`): main's to end quietly, not an OSError below
        raise
    except (MapError, SettingsError, FileExistsError, ValueError) as e:
        parser.exit(2, f"cq-ros {args.command}: error: {e}\n")
    except RunFailed as e:  # the traceback (the worker's, wherever the run was), then the line naming the run
        parser.exit(1, f"{e.details}cq-ros {args.command}: error: {e}\n")
    except (ClusterError, OSError) as e:  # OSError: a disk that filled after the start's checks, one line
        parser.exit(1, f"cq-ros {args.command}: error: {e}\n")
    except Terminated:  # 130 as for Ctrl-C, as `launch` answers SIGTERM
        print("interrupted by SIGTERM", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C's KeyboardInterrupt would be: a command unwinds as it does on Ctrl-C (an
    experiment cut short removes the folder it made)."""


@contextmanager
def _sigterm_as_ctrl_c():
    """SIGTERM raises Terminated in the main thread and stops this process's worker processes, as Ctrl-C at a
    terminal reaches the whole process group; a ROS command's own StopSignals takes SIGTERM over while it runs."""
    if threading.current_thread() is not threading.main_thread():  # only the main thread may set handlers
        yield
        return

    owner = os.getpid()

    def on_sigterm(signum, _frame):
        if os.getpid() != owner:  # a forked worker inherits the handler: it dies of SIGTERM as it would have
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        for child in multiprocessing.active_children():
            child.terminate()
        raise Terminated

    saved = signal.signal(signal.SIGTERM, on_sigterm)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, saved)


def _dispatch(args) -> int:
    """Run the parsed command: the offline ones (offline.py), the planner (plan.py) and the ROS ones (ros.py),
    each module imported only when one of its commands runs."""
    from . import offline

    if args.command in offline.COMMANDS:
        return offline.COMMANDS[args.command](args)
    if args.command == "plan":
        from .plan import run

        return run(args)
    from . import ros  # imports no ROS until one of its commands runs

    if args.command in ("echo", "topics", "nodes", "record"):
        return ros.ros_tool(args)
    return getattr(ros, args.command)(args)


if __name__ == "__main__":  # `python -m cq_ros.cli.main`, beside `python -m cq_ros.cli` and `cq-ros`
    sys.exit(main())

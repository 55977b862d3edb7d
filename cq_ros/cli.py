"""The `cq-ros` command: maps, offline experiments, the paper's reproduction, the planner, and the ROS tools.

Bad arguments print one line naming what is wrong and exit with code 2, as argparse does.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from tqdm import tqdm

from .gridmap import ACTIONS, MapError, available_maps, load_map
from .learners import ALGORITHMS, LEARNERS
from .settings import Settings, SettingsError, run_settings
from .warehouse import DEFAULT_AISLE_LENGTH, warehouse_text


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


def _algos(text: str) -> list[str]:
    algos = [a.strip() for a in text.split(",") if a.strip()]
    unknown = [a for a in algos if a not in LEARNERS]
    if unknown or not algos:
        what = ", ".join(unknown) if unknown else repr(text)
        raise argparse.ArgumentTypeError(f"unknown algorithm {what}; choose from {','.join(LEARNERS)}")
    return algos


def _number(low: float, high: float | None = None, kind: type = float, strict: bool = False):
    """An argparse type: a number of `kind` in [low, high] (low excluded when `strict`)."""
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {'a whole number' if kind is int else 'a number'}, "
                                             f"got {text!r}") from None
        if value < low or (strict and value == low) or (high is not None and value > high):
            span = f"more than {low:g}" if strict else f"at least {low:g}"
            raise argparse.ArgumentTypeError(f"must be {span}{f' and at most {high:g}' if high is not None else ''}, "
                                             f"got {text}")
        return value
    return parse


def _algo(text: str) -> str:
    if text not in ALGORITHMS:
        raise argparse.ArgumentTypeError(f"unknown algorithm {text!r}; choose one of {','.join(ALGORITHMS)}")
    return text


def _add_settings_options(p: argparse.ArgumentParser, nodes: bool = False) -> None:
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="change a setting (repeatable); `cq-ros settings` lists them" + (
                       "; a node parameter too (e.g. feedback_timeout=60, heartbeat_period=0.5: the "
                       "tables in node_runtime/parameters.py)" if nodes else ""))
    p.add_argument("--force", action="store_true", help="overwrite an existing result directory")


def _add_run_options(p: argparse.ArgumentParser, runs: int, episodes: int) -> None:
    p.add_argument("--runs", type=_positive, default=runs, help=f"independent runs (default {runs})")
    p.add_argument("--episodes", type=_positive, default=episodes, help=f"episodes per run (default {episodes})")
    p.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    p.add_argument("--jobs", type=_positive, default=None, help="worker processes (default: one per core)")
    _add_settings_options(p)


# ROS_DOMAIN_ID: Fast DDS derives its ports from it; 0..232 is the range that works on Linux.
_domain_id = _number(0, 232, kind=int)
_seconds = _number(0, strict=True)


def _add_domain_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--domain-id", type=_domain_id, default=None, metavar="N",
                   help="ROS_DOMAIN_ID to use (default: the environment's)")


def _add_ros_parsers(sub) -> None:
    p = sub.add_parser("launch", help="run one algorithm on one map as ROS 2 nodes (a world process and one "
                                      "process per AGV) and write results and figures")
    p.add_argument("--map", required=True, help="a shipped map name or a path to a map file")
    p.add_argument("--algo", type=_algo, required=True, help=f"one of {','.join(ALGORITHMS)}")
    p.add_argument("--out", type=Path, required=True, help="result directory (node logs in its logs/)")
    p.add_argument("--episodes", type=_positive, default=500, help="episodes (default 500)")
    p.add_argument("--seed", type=_number(0, kind=int), default=0, help="master seed (default 0)")
    p.add_argument("--domain-id", type=_domain_id, default=None, metavar="N",
                   help="ROS_DOMAIN_ID of the run (default: random in 100..200)")
    p.add_argument("--namespace", default=None, help="ROS namespace of the run, e.g. /demo or demo (default: random cq_<hex>)")
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
    p.add_argument("--discovery", choices=("subnet", "static"), default="subnet",
                   help="with --hosts: multicast discovery on the subnet, or unicast to ROS_STATIC_PEERS only")
    p.add_argument("--no-figures", dest="figures", action="store_false", help="write the tables only")
    _add_settings_options(p, nodes=True)

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
                       help="seconds of discovery before listing (default 3)")
        _add_domain_option(p)

    p = sub.add_parser("record", help="record topics to a rosbag2 file (default: every cq_ros topic)")
    p.add_argument("--out", type=Path, required=True, help="bag directory to create")
    p.add_argument("--topics", nargs="+", default=None, metavar="TOPIC", help="record these topics only")
    p.add_argument("--duration", type=_seconds, default=None, metavar="S", help="stop after S seconds")
    p.add_argument("--count", type=_positive, default=None, metavar="N", help="stop after N messages")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="storage plugin (default mcap)")
    _add_domain_option(p)

    p = sub.add_parser("render", help="draw one episode as an animated GIF (or MP4 where ffmpeg is installed): "
                                      "the map, the AGVs, their goals and whom each agent looks at; from the "
                                      "offline engine (--map, --algo) or from a bag of `cq-ros record` (--bag)")
    p.add_argument("--out", type=Path, required=True, help="the animation to write: NAME.gif, or NAME.mp4 (ffmpeg)")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--map", help="run the offline engine on this map (a shipped name or a path)")
    source.add_argument("--bag", type=Path, help="a rosbag2 directory recorded by `cq-ros record`")
    p.add_argument("--algo", type=_algo, default="cq", help=f"with --map: one of {','.join(ALGORITHMS)} (default cq)")
    p.add_argument("--episodes", type=_positive, default=100, help="with --map: episodes to learn (default 100)")
    p.add_argument("--seed", type=_number(0, kind=int), default=0, help="with --map: master seed (default 0)")
    p.add_argument("--episode", type=_number(0, kind=int), default=None, metavar="E",
                   help="the episode to draw, from 0 (default: the last; with --map, of the learning episodes)")
    p.add_argument("--greedy", action="store_true",
                   help="with --map: draw the greedy policy's first episode after the learning ones, not a "
                        "learning episode")
    p.add_argument("--fps", type=_seconds, default=4.0, help="frames (steps) per second (default 4)")
    p.add_argument("--dpi", type=_positive, default=None,
                   help="pixels an inch of the picture, a cell being 0.6 in (default 72); fewer make a smaller file")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="with --map: change a setting (repeatable)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="cq-ros", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)

    sub.add_parser("maps", help="list the shipped maps with their cells and agents")
    p = sub.add_parser("show", help="draw a map in the terminal")
    p.add_argument("map", help="a shipped map name or a path to a map file")
    sub.add_parser("settings", help="list every setting with its default")

    p = sub.add_parser("generate", help="generate a map (print it, or write it with --out)")
    kinds = p.add_subparsers(dest="kind", required=True, metavar="KIND", parser_class=_Parser)
    what = ("a warehouse: two-lane cross-aisles (top and bottom), two-lane aisles behind one-lane entrances, "
            "pick stations in bays beside the aisles (cq_ros.warehouse)")
    p = kinds.add_parser("warehouse", help=what, description=f"Print or write {what}. Starts (docks on the "
                         "cross-aisles) and goals (distinct bays) are drawn from --seed; every agent can reach its "
                         "goal with the others parked at theirs. The map carries `set reward_step=-1`, `set gamma=0.98` "
                         "and `set epsilon_decay_episodes=1500`.")
    p.add_argument("--agents", type=_positive, required=True, metavar="N", help="AGVs, each with its own goal")
    p.add_argument("--aisles", type=_positive, default=None, metavar="A",
                   help="aisles (default: 2 + ceil(N/4): 4 for 8 AGVs, 6 for 16, 10 for 32)")
    p.add_argument("--aisle-length", type=_positive, default=DEFAULT_AISLE_LENGTH, metavar="L",
                   help=f"cells along each aisle, one pick station per row (default {DEFAULT_AISLE_LENGTH})")
    p.add_argument("--seed", type=int, default=0, help="draws the starts and goals (default 0)")
    p.add_argument("--slip", type=_number(0.0, 1.0), default=0.0, metavar="P",
                   help="delays: the map's default `slip` (a move fails with probability P; default 0)")
    p.add_argument("--start-hold", type=_number(0, None, int), default=0, metavar="H",
                   help="delays: the map's default `start_hold` (each AGV waits 0..H steps at its dock; default 0)")
    p.add_argument("--out", type=Path, default=None, metavar="FILE", help="write the map here (default: print it)")
    p.add_argument("--force", action="store_true", help="overwrite an existing FILE")

    p = sub.add_parser("experiment", help="run algorithms on one map offline and write results and figures")
    p.add_argument("--map", required=True, help="a shipped map name or a path to a map file")
    p.add_argument("--algo", type=_algos, default=list(ALGORITHMS),
                   help=f"comma-separated, from {','.join(LEARNERS)} (default: the paper's five; fcq is experimental)")
    p.add_argument("--out", type=Path, required=True, help="result directory")
    p.add_argument("--no-figures", dest="figures", action="store_false", help="write the tables only")
    _add_run_options(p, runs=10, episodes=10_000)

    p = sub.add_parser("plan", help="plan every AGV's route centrally under the world's rules (the yardstick "
                                    "for the learners): makespan, sum of costs, arrival steps")
    p.add_argument("--map", required=True, help="a shipped map name or a path to a map file")
    p.add_argument("--seed", type=int, default=0, help="seed of the priority orders and LNS rounds (default 0)")
    p.add_argument("--cbs-nodes", type=_number(0, kind=int), default=1000, metavar="N",
                   help="search nodes of the optimal conflict-based search before falling back on prioritized "
                        "planning (default 1000; 0: skip it)")
    p.add_argument("--orders", type=_positive, default=20, metavar="N",
                   help="priority orders prioritized planning tries (default 20)")
    p.add_argument("--rounds", type=_number(0, kind=int), default=300, metavar="N",
                   help="rounds of large neighbourhood search improving a prioritized plan (default 300)")
    p.add_argument("--show", action="store_true",
                   help="print every agent's moves (N E S W; lower case: a bump into a wall, i.e. a wait)")

    p = sub.add_parser("reproduce", help="the paper's grid (4 maps x 5 algorithms), figures and REPORT.md")
    p.add_argument("--out", type=Path, required=True, help="result directory")
    _add_run_options(p, runs=10, episodes=10_000)
    p.add_argument("--no-sweep", dest="sweep", action="store_false", help="skip the settings sweep")
    _add_ros_parsers(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # `launch --hosts` runs them again on the world's host
    try:
        return _dispatch(args)
    except (MapError, SettingsError, FileExistsError, ValueError) as e:
        parser.exit(2, f"cq-ros {args.command}: error: {e}\n")
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


def _dispatch(args) -> int:
    if args.command == "maps":
        print(f"{'map':<18} {'cells':>5} {'agents':>6}")
        for name in available_maps():
            m = load_map(name)
            print(f"{name:<18} {m.n_cells:>5} {m.n_agents:>6}")
        return 0
    if args.command == "show":
        m = load_map(args.map)
        print(f"{m.name}: {m.n_cells} cells, {m.n_agents} agents (digits: starts, G: goals)")
        print(m.draw())
        if m.defaults:
            print("map defaults: " + ", ".join(f"{k}={v:g}" for k, v in m.defaults.items()))
        pairs = m.walled_in()
        print("walled in by an early arrival (agent: by the agent parked at its goal): "
              + ("; ".join(f"{i + 1}: by {k + 1} at {'%d,%d' % m.cells[m.goals[k]]}" for i, k in pairs) or "none"))
        return 0
    if args.command == "generate":
        return _generate(args)
    if args.command == "settings":
        for key, value in Settings().as_dict().items():
            print(f"{key} = {value}")
        return 0
    if args.command == "plan":
        return _plan(args)
    if args.command in ("echo", "topics", "nodes", "record"):
        return _ros_tool(args)
    if args.command == "render":
        return _render(args)
    if args.command == "launch":
        return _launch(args)
    if args.command == "hosts":
        return _hosts(args)
    if args.command == "experiment":
        from .experiment import experiment
        from .summary import format_console_table, load_episodes

        # The map is read first: a bad map fails before any work starts, and its defaults join the settings.
        settings = run_settings(load_map(args.map), args.overrides)
        out = experiment(args.map, args.algo, args.runs, args.episodes, args.seed, args.out, settings,
                         workers=args.jobs, force=args.force, figures=args.figures)
        print(format_console_table(load_episodes(out / "episodes.csv")))
        print(f"results: {out}")
        return 0
    if args.command == "reproduce":
        from .reproduce import reproduce

        # The paper's maps carry no defaults of their own.
        report = reproduce(args.out, args.runs, args.episodes, args.seed, Settings().with_overrides(args.overrides),
                           workers=args.jobs, force=args.force, sweep=args.sweep)
        print(f"report: {report}")
        return 0
    raise AssertionError(args.command)


def _plan(args) -> int:
    from .planner import NoPlan, PlanError, distances_to, plan, validate

    gridmap = load_map(args.map)
    started = time.perf_counter()
    progress = _PlanProgress()
    try:
        result = plan(gridmap, args.seed, args.cbs_nodes, args.orders, args.rounds, progress)
    except NoPlan as e:
        print(f"cq-ros plan: {e} (--cbs-nodes and --orders search longer)", file=sys.stderr)
        return 1
    finally:
        progress.close()
    seconds = time.perf_counter() - started
    try:
        arrivals = validate(gridmap, result)
    except PlanError as e:
        print(f"cq-ros plan: the world rejects the plan (a planner bug): {e}", file=sys.stderr)
        return 1
    alone = sum(distances_to(gridmap, goal)[start] for start, goal in zip(gridmap.starts, gridmap.goals))
    least = "the least possible" if result.optimal else f"the least possible is at least {result.lower_bound}"
    print(f"{gridmap.name}: {gridmap.n_agents} agents, {result.method}")
    print(f"makespan {result.makespan}, sum of costs {result.sum_of_costs} ({least}; each agent alone: {alone:g})")
    print("arrival steps: " + ", ".join(f"agv{i + 1} {step}" for i, step in enumerate(arrivals)))
    print(f"planning time {seconds:.2f} s; replayed through the world: every agent at its goal, no collision")
    if args.show:
        for i, (path, actions) in enumerate(zip(result.paths, result.actions)):
            moves = "".join(ACTIONS[a][0] if b != a_cell else ACTIONS[a][0].lower()
                            for a, a_cell, b in zip(actions, path, path[1:]))
            print(f"agv{i + 1} {gridmap.cells[path[0]]} -> {gridmap.cells[path[-1]]}: {moves or '(at its goal)'}")
    return 0


class _PlanProgress:
    """The planner's progress on stderr: a tqdm bar per phase on a terminal, a plain line at most every 30 s
    elsewhere."""

    def __init__(self):
        self.tty = sys.stderr.isatty()
        self.bar = None
        self.phase = None
        self.last_line = time.monotonic()

    def __call__(self, phase: str, done: int, total: int) -> None:
        if self.tty:
            if phase != self.phase:
                self.close()
                self.bar = tqdm(total=total, desc=f"plan: {phase}", leave=False)
            self.bar.update(done - self.bar.n)
        elif time.monotonic() - self.last_line >= 30:
            print(f"cq-ros plan: {phase} {done}/{total}", file=sys.stderr, flush=True)
            self.last_line = time.monotonic()
        self.phase = phase

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def _generate(args) -> int:
    text = warehouse_text(args.agents, args.aisles, args.aisle_length, args.seed, args.slip, args.start_hold)
    if args.out is None:
        sys.stdout.write(text)
        return 0
    if args.out.exists() and not args.out.is_file():
        raise FileExistsError(f"{args.out} is not a file")
    if args.out.exists() and not args.force:
        raise FileExistsError(f"{args.out} exists; pass --force to overwrite it")
    try:
        args.out.write_text(text, encoding="utf-8")
    except OSError as e:
        raise ValueError(f"cannot write {args.out}: {e.strerror or e}") from None
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


# The ROS commands import rclpy (through ros_tools) only when they run: the rest of cq_ros
# works without it.


def _hosts(args) -> int:
    from ros_tools.hosts import HostsError, existing_prefixes, hosts_down, hosts_up

    try:
        if args.action == "up":
            print(hosts_up(args.agents, args.prefix).describe())
        elif args.action == "down":
            if args.prefix is None:
                raise HostsError("down needs --prefix (`cq-ros hosts list` shows the sets)")
            gone = hosts_down(args.prefix)
            print(f"removed {', '.join(gone)}" if gone else f"no hosts {args.prefix}: nothing to remove")
        else:
            for prefix, names in existing_prefixes().items():
                print(f"{prefix}: {', '.join(names)}")
    except HostsError as e:
        print(f"cq-ros hosts: error: {e}", file=sys.stderr)
        return 2
    return 0


def _launch(args) -> int:
    from ros_tools.hosts import HostsError, check_can_make_hosts, find_hosts
    from ros_tools.launch import Interrupted, LaunchError, check_hosts, launch, split_sets

    from .summary import format_console_table, load_episodes

    # Settings fields (over the map's defaults) and node parameters alike
    settings, node_parameters = split_sets(args.overrides, load_map(args.map))
    hosts = None
    if args.hosts is not None:
        try:
            check_can_make_hosts()
            hosts = find_hosts(args.hosts)
        except HostsError as e:
            raise ValueError(e) from None
        check_hosts(hosts, load_map(args.map), args.algo, args.discovery)
        if hosts.current_host() != "world":  # the launcher listens on the world's host: run there
            sys.stdout.flush()
            os.execvp("ip", [*hosts.exec_on("world"), sys.executable, "-m", "cq_ros.cli", *args.argv])
    try:
        result = launch(args.map, args.algo, args.episodes, args.seed, args.out, settings,
                        domain_id=args.domain_id, namespace=args.namespace, step_timeout=args.step_timeout,
                        peer_linger_steps=args.peer_linger_steps, compose=args.compose,
                        executor=args.executor, node_parameters=node_parameters, force=args.force,
                        figures=args.figures, hosts=hosts, discovery=args.discovery)
    except Interrupted as e:
        print(f"cq-ros launch: {e}", file=sys.stderr)
        return 130
    except LaunchError as e:
        print(f"cq-ros launch: error: {e}", file=sys.stderr)
        return 1
    print(format_console_table(load_episodes(result.out / "episodes.csv")))
    if len(result.greedy):
        steps, collisions = result.greedy[:, 0], result.greedy[:, 1]
        print(f"greedy policy, {len(result.greedy)} episodes: {collisions.mean():.2f} collisions/ep, "
              f"{steps.mean():.1f} steps/ep, {int(result.greedy[:, 5].sum())} truncated")
    for node, cost in result.manifest["communication"].items():
        print(f"{node}: {cost['peer_messages']} peer position messages, "
              f"{cost['subscriptions_created']} subscriptions created")
    print(f"results: {result.out}")
    return 0


def _render(args) -> int:
    from .render import DPI, check_output, engine_frames, frames_from, lattice, write_animation

    check_output(args.out)
    if args.map is not None:
        gridmap = load_map(args.map)
        settings = run_settings(gridmap, args.overrides)
        occupancy, goals = lattice(gridmap), tuple(gridmap.cells[g] for g in gridmap.goals)
        title = f"{gridmap.name} {args.algo}"
        _note(f"learning {args.episodes} episodes of {title} offline (seed {args.seed})")
        if args.greedy:
            title += " greedy"
        frames = engine_frames(gridmap, args.algo, settings, args.seed, args.episodes, args.episode,
                               _every_30_s("episode {} learnt"), greedy=args.greedy)
    else:
        from ros_tools import commands as tools

        if args.overrides or args.greedy:
            raise ValueError(f"{'--set' if args.overrides else '--greedy'} applies to --map (the offline engine), "
                             "not to a bag")
        try:
            occupancy, scenes, looks = tools.read_view_bag(args.bag)
        except tools.ToolError as e:
            print(f"cq-ros render: error: {e}", file=sys.stderr)
            return 1
        if occupancy is None or not scenes:
            print(f"cq-ros render: error: {args.bag} holds no {'world/map' if occupancy is None else 'world/markers'}"
                  " message (record while the run starts, with markers on)", file=sys.stderr)
            return 1
        episodes = sorted({s.episode for s in scenes})
        episode = episodes[-1] if args.episode is None else args.episode
        if episode not in episodes:
            raise ValueError(f"episode {episode} is not in {args.bag}: it holds episodes {episodes[0]}..{episodes[-1]}")
        frames = frames_from([s for s in scenes if s.episode == episode], looks)
        occupancy, goals, title = occupancy.lattice, scenes[0].goals, args.bag.name
    _note(f"drawing {len(frames)} steps to {args.out}")
    out = write_animation(args.out, occupancy, goals, frames, title=title, fps=args.fps, dpi=args.dpi or DPI,
                          progress=_every_30_s(f"frame {{}}/{len(frames)} drawn"))
    print(f"{out}: episode {frames[0].episode}, {len(frames)} frames")
    return 0


def _every_30_s(line: str):
    """A progress callback for render's long loops: `line` (with the 1-based count) at most every 30 s."""
    shown = time.monotonic()

    def progress(i: int) -> None:
        nonlocal shown
        if time.monotonic() - shown >= 30:
            shown = time.monotonic()
            _note(line.format(i + 1))

    return progress


def _note(line: str) -> None:
    print(f"cq-ros render: {line}", file=sys.stderr, flush=True)


def _ros_tool(args) -> int:
    from ros_tools import commands as tools

    try:
        if args.command == "echo":
            tools.echo(args.topic, count=args.count, timeout_s=args.timeout, domain_id=args.domain_id)
        elif args.command == "topics":
            tools.topics(show_types=args.show_types, wait_s=args.wait, domain_id=args.domain_id)
        elif args.command == "nodes":
            tools.nodes(all_nodes=args.all_nodes, wait_s=args.wait, domain_id=args.domain_id)
        else:
            tools.record(args.out, topics=args.topics, duration_s=args.duration, count=args.count,
                         storage=args.storage, domain_id=args.domain_id)
    except tools.ToolError as e:
        print(f"cq-ros {args.command}: error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The `cq-ros` command: maps, offline experiments, the paper's reproduction, and the ROS tools.

Bad arguments print one line naming what is wrong and exit with code 2, as argparse does.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .gridmap import MapError, available_maps, load_map
from .learners import ALGORITHMS, LEARNERS
from .settings import Settings, SettingsError


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


def _add_run_options(p: argparse.ArgumentParser, runs: int, episodes: int) -> None:
    p.add_argument("--runs", type=_positive, default=runs, help=f"independent runs (default {runs})")
    p.add_argument("--episodes", type=_positive, default=episodes, help=f"episodes per run (default {episodes})")
    p.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="change a setting (repeatable); `cq-ros settings` lists them")
    p.add_argument("--jobs", type=_positive, default=None, help="worker processes (default: one per core)")
    p.add_argument("--force", action="store_true", help="overwrite an existing result directory")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="cq-ros", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)

    sub.add_parser("maps", help="list the shipped maps with their cells and agents")
    p = sub.add_parser("show", help="draw a map in the terminal")
    p.add_argument("map", help="a shipped map name or a path to a map file")
    sub.add_parser("settings", help="list every setting with its default")

    p = sub.add_parser("experiment", help="run algorithms on one map offline and write results and figures")
    p.add_argument("--map", required=True, help="a shipped map name or a path to a map file")
    p.add_argument("--algo", type=_algos, default=list(ALGORITHMS),
                   help=f"comma-separated, from {','.join(LEARNERS)} (default: the paper's five; fcq is experimental)")
    p.add_argument("--out", type=Path, required=True, help="result directory")
    p.add_argument("--no-figures", dest="figures", action="store_false", help="write the tables only")
    _add_run_options(p, runs=10, episodes=10_000)

    p = sub.add_parser("reproduce", help="the paper's grid (4 maps x 5 algorithms), figures and REPORT.md")
    p.add_argument("--out", type=Path, required=True, help="result directory")
    _add_run_options(p, runs=10, episodes=10_000)
    p.add_argument("--no-sweep", dest="sweep", action="store_false", help="skip the settings sweep")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
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
        return 0
    if args.command == "settings":
        for key, value in Settings().as_dict().items():
            print(f"{key} = {value}")
        return 0
    settings = Settings().with_overrides(args.overrides)
    if args.command == "experiment":
        from .experiment import experiment
        from .summary import format_console_table, load_episodes

        load_map(args.map)  # fail on a bad map before any work starts
        out = experiment(args.map, args.algo, args.runs, args.episodes, args.seed, args.out, settings,
                         workers=args.jobs, force=args.force, figures=args.figures)
        print(format_console_table(load_episodes(out / "episodes.csv")))
        print(f"results: {out}")
        return 0
    if args.command == "reproduce":
        from .reproduce import reproduce

        report = reproduce(args.out, args.runs, args.episodes, args.seed, settings, workers=args.jobs,
                           force=args.force, sweep=args.sweep)
        print(f"report: {report}")
        return 0
    raise AssertionError(args.command)


if __name__ == "__main__":
    sys.exit(main())

"""The limit learner on the held-out study's units: a learner that looks at the right peer at the right cell only.

The learners, `limit` and `limit_cq`, are cq_ros.learners.limit's: an oracle, not a candidate algorithm. It plays on the
reference engine, through cq_ros.lab.held_out.play_unit: the study's units exactly, the same maps (those
`cq-ros study` generated and kept, checked against today's generator), the same learner seed and runs (the same
world delays: world_seed(seed, run)), the same protocol (read from the kept study.json) and near's settings
(checked against the kept study's resolved ones, where it played near).

    python benchmarks/limit_learner.py --agents 8,12 --study DIR --out DIR [--maps 10] [--runs 10]

DIR of --study: what `cq-ros study --agents 8,12 --algos cq,near ... --out DIR` wrote.

OUT/AGENTS keeps units.csv (the columns of the study's units.csv, config `limit`), curve.csv, limit.json (the
protocol and the command) and limit.md: the study's tables (cq_ros.lab.held_out_report.size_tables) over the units the
limit learner played, beside cq's and near's kept rows of the same units (paired differences from cq; and the
limit learner's from near's). Units are written as they finish; the same command again plays only those missing.
`--report` writes limit.md again from what OUT holds.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from cq_ros.gridmap import load_map
from cq_ros.lab.held_out import Unit, config_settings, generated, play_unit
from cq_ros.lab.held_out_protocol import HELD_OUT_SEEDS, KEY, Config, append_rows, read_rows
from cq_ros.lab.held_out_report import FIGURES, curve_table, size_tables
from cq_ros.lab.runner import Progress
from cq_ros.lab.study import paired_difference
from cq_ros.lab.limit import LimitLearning
from cq_ros.learners.limit import LEARNERS

ROOT = Path(__file__).resolve().parent.parent
COMPARED = ("cq", "near")  # the kept study's configurations shown beside it


def units_of(kept: Path, out: Path, agents: int, maps: int, runs: int, learner: str = "limit"
             ) -> tuple[list[Unit], dict]:
    """The limit learner's units of the kept study in `kept` (map-major: the first maps' runs first), their maps
    written to OUT/maps as the study generated them, and the kept protocol."""
    protocol = json.loads((kept / "study.json").read_text())
    if protocol.get("generator_seeds") == "tuning":
        raise SystemExit(f"{kept} is a tuning study; the limit learner is measured on held-out units")
    units = []
    for g in HELD_OUT_SEEDS[:maps]:
        path = generated(out, agents, g, protocol["slip"])
        if path.read_text() != (kept / "maps" / path.name).read_text():
            raise SystemExit(f"{path.name}: the generator makes another map than the kept study's")
        settings = config_settings(Config(learner, "near"), load_map(path), protocol["overrides"],
                                   protocol["greedy_episodes"])[0]
        played = protocol["settings"].get("near")  # the 32-AGV study did not play near
        if played is not None and settings.as_dict() != played:
            raise SystemExit(f"near's settings today are not those of the kept study {kept}")
        units += [Unit(str(path), learner, r, protocol["episodes"], protocol["seed"], settings, learner, agents, g,
                       protocol["greedy_episodes"], protocol["curve_every"], protocol["curve_episodes"])
                  for r in range(runs)]
    return units, protocol


def play(kept: Path, out: Path, agents: int, maps: int, runs: int, learner: str) -> None:
    units, protocol = units_of(kept, out, agents, maps, runs, learner)
    planner = {tuple(int(r[k]) for k in ("agents", "generator_seed", "run")): r["makespan"]
               for r in read_rows(kept / "planner.csv")}
    done = {tuple(r[k] for k in KEY) for r in read_rows(out / "units.csv")}
    todo = [u for u in units if (u.agents, u.generator_seed, u.run, u.config) not in done]
    # a unit of 2,000 episodes takes minutes (hours at 32 AGVs): progress by the episode, as `cq-ros study` shows it
    progress = Progress(f"{learner}: {agents} AGVs", sum(u.episodes for u in todo), len(todo))
    played = [0]

    def on_episode() -> None:
        played[0] += 1
        progress.update(played[0], n)

    for n, u in enumerate(todo):
        result = play_unit({u.map_name: load_map(u.map_name)}, u, on_episode, LimitLearning)
        key = {"agents": u.agents, "generator_seed": u.generator_seed, "run": u.run, "config": u.config}
        append_rows(out / "curve.csv", [{**key, "episode": e, "collisions": c, "home": h}
                                        for e, c, h in result["curve"]])
        append_rows(out / "units.csv", [{**key, **result["row"],
                                         "planner_makespan": planner[(u.agents, u.generator_seed, u.run)]}])
        progress.update(played[0], n + 1)
    progress.close()
    kept_protocol = {k: protocol[k] for k in ("episodes", "greedy_episodes", "curve_every", "curve_episodes", "seed",
                                              "slip", "overrides")}
    study = kept.resolve().relative_to(ROOT) if kept.resolve().is_relative_to(ROOT) else kept
    (out / "limit.json").write_text(json.dumps({**kept_protocol, "settings": units[0].settings.as_dict(),
                                                "study": str(study)}, indent=1) + "\n")


def report(kept: Path, out: Path, agents: int, commands: list[str]) -> str:
    """The study's tables over the units the limit learners played in OUT, beside cq's and near's kept rows."""
    mine = read_rows(out / "units.csv")
    units = {(r["generator_seed"], r["run"]) for r in mine}
    learners = [name for name in LEARNERS if any(r["config"] == name for r in mine)]
    # one row per unit and configuration, the last written (as held_out_report.shown_rows keeps them)
    rows = list({tuple(r[k] for k in KEY): r for r in read_rows(kept / "units.csv") + mine
                 if r["config"] in (*COMPARED, *learners) and (r["generator_seed"], r["run"]) in units}.values())
    compared = [c for c in COMPARED if any(r["config"] == c for r in rows)]  # the 32-AGV study played no near
    curve = read_rows(out / "curve.csv") + [r for r in read_rows(kept / "curve.csv") if r["config"] in compared
                                            and (r["generator_seed"], r["run"]) in units]
    planner = [r for r in read_rows(kept / "planner.csv") if (r["generator_seed"], r["run"]) in units]
    configs = [Config(c, c) for c in (*compared, *learners)]
    maps = sorted({g for g, _ in units})
    shown = kept.resolve().relative_to(ROOT) if kept.resolve().is_relative_to(ROOT) else kept
    lines = [f"# The limit learner, {agents} AGVs", "", *(f"Command: `{c}`" for c in commands), "",
             f"The held-out study's units in {shown}: generator seeds {maps[0]}-{maps[-1]} ({len(maps)} maps), runs "
             f"{', '.join(map(str, sorted({r for _, r in units})))}: {len(units)} units; the study's protocol "
             "(its study.json), on the reference engine: " + ", ".join(
                 f"{name} {sum(r['seconds'] for r in mine if r['config'] == name):.0f} s" for name in learners)
             + " (summed over units); " + " and ".join(c + "'s" for c in compared)
             + " rows are the kept study's, of the same units. "
             "Mean ± half-width of the 95% t interval over units; paired differences from cq"
             + (", and below them from near." if "near" in compared else "."),
             "Units played: " + ", ".join(f"{name} {sum(r['config'] == name for r in mine)}" for name in learners)
             + " (a count \"of N units\" below is over all N units, whichever configuration played fewer)."]
    lines += size_tables(agents, rows, configs, planner)
    for copy in ("frozen", "learning") if "near" in compared else ():
        lines += ["", f"Paired differences from near, {copy}:", "",
                  "| configuration | " + " | ".join(label for label, _, _ in FIGURES) + " |",
                  "| --- |" + " ---: |" * len(FIGURES)]
        for name in learners:
            order = sorted((r["generator_seed"], r["run"]) for r in rows if r["config"] == name)

            def values(config: str, column: str) -> list[float]:
                by_unit = {(r["generator_seed"], r["run"]): r for r in rows if r["config"] == config}
                if column == "makespan_ratio":
                    return [by_unit[u][f"{copy}_makespan"] / by_unit[u]["planner_makespan"] for u in order]
                return [by_unit[u][column if column == "states" else f"{copy}_{column}"] for u in order]

            lines.append(f"| {name} - near | " + " | ".join(
                paired_difference(values(name, c), values("near", c)).show(d) for _, c, d in FIGURES) + " |")
    # a stalled unit's greedy episodes run to the step cap, hearing at every step: the median unit beside the mean
    lines += ["", "Median over units, frozen: " + "; ".join(
        f"{c.name} heard/ep {np.median([r['frozen_heard'] for r in rows if r['config'] == c.name]):.1f}, makespan "
        f"{np.median([r['frozen_makespan'] for r in rows if r['config'] == c.name]):.1f}" for c in configs) + "."]
    lines += curve_table(curve, configs)
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agents", default="8,12", help="fleet sizes, comma-separated (the kept studies')")
    parser.add_argument("--maps", type=int, default=10)
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--learner", choices=list(LEARNERS), default="limit")
    parser.add_argument("--study", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--report", action="store_true", help="write limit.md again from OUT, playing nothing")
    args = parser.parse_args()
    for agents in [int(a) for a in args.agents.split(",")]:
        kept, out = args.study / str(agents), args.out / str(agents)
        out.mkdir(parents=True, exist_ok=True)
        kept_commands = out / "command.txt"  # the commands that played OUT's units, one a line
        commands = kept_commands.read_text().splitlines() if kept_commands.exists() else []
        if not args.report:
            play(kept, out, agents, args.maps, args.runs, args.learner)
            command = (f"python benchmarks/limit_learner.py --agents {agents} --maps {args.maps} --runs {args.runs}"
                       + ("" if args.learner == "limit" else f" --learner {args.learner}"))
            commands = [c for c in commands if c != command] + [command]
            kept_commands.write_text("\n".join(commands) + "\n")
        text = report(kept, out, agents, commands)
        (out / "limit.md").write_text(text)
        print(text, flush=True)


if __name__ == "__main__":
    main()

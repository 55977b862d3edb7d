"""The limit learner on the held-out study's units: a learner that looks at the right peer at the right cell only.

`LimitQ` is near (cq_ros/learners/near.py: Q-learning on its own cell and the cells of the peers it conditions
on, a new joint row a copy of its cell's) with near's "every peer within 2 cells" replaced by an oracle: at each
step it conditions its row on, and hears, exactly the peers that can collide with it this step under the
world's rules (cq_ros/world.py), whatever the two of them and everyone else do and whoever is delayed.
A colliding pair ends the step in one cell, or swaps; each of the two ends either where it stands or in the
cell its move leads to (agents in a collision go back), so agent i in cell s and peer j in cell c can collide
this step exactly when the cells i can end in, REACH(s) = {s} and the cells its four moves lead to (a wall bump
leads to s), and the cells j can end in, REACH(c) (only {c} for a peer at its goal, which never moves again and
stands there as an obstacle), share a cell x, other than a goal the two share (the one cell two agents may
share). Every such x is a collision under some joint move while slip is above 0: both move into x; or x = s and
j moves into s while i is delayed; or x = c and i moves into c while j is delayed; a swap (s -> c, c -> s) needs
s in REACH(c), so it is counted already. Those peers are all within 2 cells (Manhattan): a subset of near's.

It is an oracle, a yardstick, not a candidate algorithm: it reads every peer's cell and goal (ground truth a
deployed AGV does not have) to decide whom it hears, and hears (`heard`) only those. So it is not in the
algorithm registry (no `cq-ros experiment`, ROS node, checkpoint format or compiled twin for it) and plays on the
reference engine, through cq_ros.lab.held_out.play_unit: the study's units exactly, the same maps (those
`cq-ros study` generated and kept, checked against today's generator), the same learner seed and runs (the same
world delays: world_seed(seed, run)), the same protocol (read from the kept study.json) and near's settings
(checked against the kept study's resolved ones, where it played near).

    python benchmarks/limit_learner.py --agents 8,12 [--maps 10] [--runs 10] [--study DIR] [--out DIR]

OUT/AGENTS keeps units.csv (the columns of the study's units.csv, config `limit`), curve.csv, limit.json (the
protocol and the command) and limit.md: the study's tables (cq_ros.lab.held_out.size_tables) over the units the
limit learner played, beside cq's and near's kept rows of the same units (paired differences from cq; and the
limit learner's from near's). Units are written as they finish; the same command again plays only those missing.
`--report` writes limit.md again from what OUT holds.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from cq_ros.engine import Team, learner_seed, world_seed
from cq_ros.gridmap import GridMap, load_map
from cq_ros.lab.held_out import (
    FIGURES, HELD_OUT_SEEDS, KEY, Config, Learning, Unit, append_rows, config_settings, curve_table, generated,
    play_unit, read_rows, size_tables)
from cq_ros.lab.runner import Progress
from cq_ros.lab.study import paired_difference
from cq_ros.learners.base import epsilon_greedy, q_update
from cq_ros.learners.near import NearQ
from cq_ros.settings import Settings
from cq_ros.world import GridWorld

ROOT = Path(__file__).resolve().parent.parent
COMPARED = ("cq", "near")  # the kept study's configurations shown beside it


class LimitQ(NearQ):
    """Near whose joint state holds only the peers that can collide with it this step (the module's docstring)."""

    name = "limit"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        nbr = self.map.neighbours
        self.reach = [frozenset((c, *nbr[c])) for c in range(self.n_cells)]  # REACH(c): c and where its moves lead
        # the cells c whose REACH(c) meets REACH(s): moves are open both ways (x in REACH(c) exactly when c is in
        # REACH(x)), so they are the cells reached from REACH(s)
        self.meet = [frozenset(c for x in self.reach[s] for c in self.reach[x]) for s in range(self.n_cells)]
        self.goals = self.map.goals

    def could_collide(self, cell: int, peer: int, peer_cell: int) -> bool:
        """Whether `peer`, in `peer_cell`, can collide with this agent, in `cell`, this step."""
        goal = self.goals[peer]
        if goal == self.goals[self.agent]:  # a shared goal, the one cell two agents may both end in
            there = (peer_cell,) if peer_cell == goal else self.reach[peer_cell]
            return any(x in self.reach[cell] and x != goal for x in there)
        # at its goal the peer stays for good: only a move into its cell can collide with it
        return peer_cell in (self.reach[cell] if peer_cell == goal else self.meet[cell])

    def act(self, peer_cells):
        s = self.s
        near = tuple((j, c) for j, c in sorted(peer_cells.items()) if self.could_collide(s, j, c))
        self.heard += len(near)
        if near:
            self.joint_plays += 1
            row = self.q_near.get((s, near))
            if row is None:
                row = list(self.q_local[s])
                if self.learning:
                    self.q_near[(s, near)] = row
        else:
            row = self.q_local[s]
        return self.act_on(row)


class LimitCQ(LimitQ):
    """The same oracle's peers, hears the same, but in CQ's tables: a row per (cell, peer, peer's cell), a copy of
    the cell's row when new, acted on through the elementwise minimum of the rows of the peers heard (CQ's
    cq_all_met), the step's update made in each of them (Q_k where nobody can collide). What it learns is then
    what CQ with perfect marks, met everywhere they matter, could learn; near's joint rows need every
    combination of the peers heard."""

    name = "limit_cq"

    def act(self, peer_cells):
        s = self.s
        keys = [(s, j, c) for j, c in sorted(peer_cells.items()) if self.could_collide(s, j, c)]
        self.heard += len(keys)
        rows = [self.q_local[s]]
        if keys:
            self.joint_plays += 1
            rows = []
            for key in keys:
                row = self.q_near.get(key)
                if row is None:
                    row = list(self.q_local[s])
                    if self.learning:
                        self.q_near[key] = row
                rows.append(row)
        acted = rows[0] if len(rows) == 1 else [min(q) for q in zip(*rows)]
        last, self.waiting = self.waiting, None
        if last is not None:
            self._update(last, acted)
        self.row = rows
        self.a = epsilon_greedy(acted, self.epsilon, self.rng)
        return self.a

    def _update(self, step, next_row):
        rows, a, reward = step
        target = reward if next_row is None else reward + self.gamma * max(next_row)
        for row in rows:
            q_update(row, a, target, self.alpha)


LEARNERS = {learner.name: learner for learner in (LimitQ, LimitCQ)}


class LimitLearning(Learning):
    """held_out.Learning with the learners LEARNERS names (the unit's algo) on the reference engine: the world and
    learner seeds a registry learner's run has (cq_ros.engine.run)."""

    def __init__(self, algo: str, gridmap: GridMap, settings: Settings, seed: int, run: int):
        self.kernel = None
        learner = LEARNERS[algo]
        self.team = Team(GridWorld(gridmap, settings, seed=world_seed(seed, run)),
                         [learner(i, gridmap, settings, learner_seed(seed, run, i)) for i in range(gridmap.n_agents)])


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
    # one row per unit and configuration, the last written (as held_out.shown_rows keeps them)
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
    parser.add_argument("--study", type=Path, default=ROOT / "docs" / "data" / "study")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "data" / "limit")
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

"""The parsers of `cq-ros`'s offline commands (their bodies: offline.py, and plan.py for `plan`): the maps and
the settings, generated and imported maps, experiments, the planner, the paper's reproduction, the held-out
study, and `render`, which draws from the offline engine or from a recorded bag.
"""

from __future__ import annotations

import argparse

from ..learners import DEFAULT_ALGORITHMS, LEARNERS
from ..mapgen.shelves import DEFAULT_SHELF_COLS, DEFAULT_SHELF_ROWS
from ..mapgen.warehouse import DEFAULT_AISLE_LENGTH
from .arguments import (Parser, add_engine_option, add_run_options, agent_count, algo_list, algo_name,
                        episode_count, nonempty_path, number, positive_int, seconds, seed_int, seed_list, side_length,
                        size_list)

DEFAULT_PLAN_SECONDS = 300.0  # a 128-AGV generated warehouse plans in 30 s of CPU (docs/warehouses.md)
MAX_DPI = 600


def _generator(kinds, name: str, what: str, description: str) -> argparse.ArgumentParser:
    """The parser of `cq-ros generate NAME`, with the agents and the seed that draws their starts and goals."""
    p = kinds.add_parser(name, help=what, description=description)
    p.add_argument("--agents", type=agent_count, required=True, metavar="N", help="AGVs, each with its own goal")
    p.add_argument("--seed", type=seed_int, default=0, help="draws the starts and goals (default 0)")
    return p


def add_offline_parsers(sub) -> None:
    sub.add_parser("maps", help="list the shipped maps with their cells and agents")
    p = sub.add_parser("show", help="draw a map in the terminal")
    p.add_argument("map", help="a shipped map name or a path to a map file")
    sub.add_parser("settings", help="list every setting with its default and description")

    p = sub.add_parser("generate", help="generate a map (print it, or write it with --out)")
    kinds = p.add_subparsers(dest="kind", required=True, metavar="KIND", parser_class=Parser)
    what = ("a warehouse: two-lane cross-aisles (top and bottom), two-lane aisles behind one-lane entrances, "
            "pick stations in bays beside the aisles (cq_ros.mapgen.warehouse)")
    p = _generator(kinds, "warehouse", what, f"Print or write {what}. Starts (docks on the cross-aisles) and goals "
                   "(distinct bays) are drawn from --seed; every agent can reach its goal with the others parked at "
                   "theirs. The map carries `set reward_step=-1`, `set gamma=0.98` and "
                   "`set epsilon_decay_episodes=1500`.")
    p.add_argument("--aisles", type=side_length, default=None, metavar="A",
                   help="aisles (default: 2 + ceil(N/4): 4 for 8 AGVs, 6 for 16, 10 for 32, 34 for 128)")
    p.add_argument("--aisle-length", type=side_length, default=DEFAULT_AISLE_LENGTH, metavar="L",
                   help=f"cells along each aisle, one pick station per row (default {DEFAULT_AISLE_LENGTH})")
    p.add_argument("--blocks", type=side_length, default=1, metavar="B",
                   help="bands of aisles one below the other, sharing their cross-aisles, for a large fleet "
                        "(default 1; the default aisles become 2 + ceil(N/4B))")
    p.add_argument("--slip", type=number(0.0, 1.0), default=0.0, metavar="P",
                   help="delays: the map's default `slip` (a move fails with probability P; default 0)")
    p.add_argument("--start-hold", type=number(0, None, int), default=0, metavar="H",
                   help="delays: the map's default `start_hold` (each AGV waits 0..H steps at its dock; default 0)")
    p.add_argument("--out", type=nonempty_path, default=None, metavar="FILE",
                   help="write the map here (default: print it)")
    p.add_argument("--force", action="store_true", help="overwrite an existing FILE")
    what = ("a warehouse on a plain cell grid in MovingAI's .map and .scen form, blocks of shelves between "
            "two-cell corridors with docking floor left and right, 160 x 62 cells by default "
            "(cq_ros.mapgen.shelves)")
    p = _generator(kinds, "shelves", what, f"Write {what}. Starts (docking floor) and goals (distinct pick faces, "
                   "the corridor cells below a shelf) are drawn from --seed; every agent can reach its goal with "
                   "the others parked at theirs. `cq-ros import movingai STEM.map --scen STEM.scen --agents N` "
                   "makes it a map of ours.")
    p.add_argument("--shelf-rows", type=side_length, default=DEFAULT_SHELF_ROWS, metavar="R",
                   help=f"rows of shelves, each 2 cells deep under a 2-cell corridor (default {DEFAULT_SHELF_ROWS})")
    p.add_argument("--shelf-cols", type=side_length, default=DEFAULT_SHELF_COLS, metavar="C",
                   help=f"shelves in a row, each 10 cells long, 2-cell corridors between "
                        f"(default {DEFAULT_SHELF_COLS})")
    p.add_argument("--out", type=nonempty_path, required=True, metavar="STEM", help="write STEM.map and STEM.scen")
    p.add_argument("--force", action="store_true", help="overwrite existing files")

    p = sub.add_parser("import", help="convert a map from another format into ours (print it, or write it with --out)")
    kinds = p.add_subparsers(dest="kind", required=True, metavar="FORMAT", parser_class=Parser)
    p = kinds.add_parser("movingai", help="a MovingAI .map (and the first N tasks of a .scen) as a map of ours",
                         description="Convert a MovingAI grid (. G passable, @ O T blocked; S and W rejected) and, "
                         "with --scen, its first N tasks (x the column, y the row, 0-based from the top left) into "
                         "our map format (cq_ros.mapgen.movingai). A fault is one line naming the file and line.")
    p.add_argument("map", type=nonempty_path, metavar="MAP.map", help="a MovingAI map file")
    p.add_argument("--scen", type=nonempty_path, default=None, metavar="FILE.scen",
                   help="a MovingAI scenario: its first --agents tasks become the agents (default: none, the "
                        "drawing only, to which agent lines must be added)")
    p.add_argument("--agents", type=agent_count, default=None, metavar="N", help="with --scen: the tasks to take")
    p.add_argument("--out", type=nonempty_path, default=None, metavar="FILE",
                   help="write the map here (default: print it)")
    p.add_argument("--force", action="store_true", help="overwrite an existing FILE")

    p = sub.add_parser("experiment", help="run algorithms on one map offline and write results and figures")
    p.add_argument("--map", required=True, help="a shipped map name or a path to a map file")
    p.add_argument("--algo", type=algo_list, default=list(DEFAULT_ALGORITHMS),
                   help=f"comma-separated, from {','.join(LEARNERS)} (default: the paper's five and ours, "
                        f"{','.join(DEFAULT_ALGORITHMS)})")
    p.add_argument("--out", type=nonempty_path, required=True, help="result directory")
    p.add_argument("--no-figures", dest="figures", action="store_false", help="write the tables only")
    add_run_options(p, runs=10, episodes=10_000)

    p = sub.add_parser("plan", help="plan every AGV's route centrally under the world's rules (the yardstick "
                                    "for the learners): makespan, sum of costs, arrival steps; then the plan "
                                    "executed under the world's delays")
    p.add_argument("--map", required=True, help="a shipped map name or a path to a map file")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the priority orders and LNS rounds (default 0)")
    p.add_argument("--cbs-nodes", type=number(0, kind=int), default=1000, metavar="N",
                   help="search nodes of the optimal conflict-based search before falling back on prioritized "
                        "planning (default 1000; 0: skip it)")
    p.add_argument("--orders", type=positive_int, default=20, metavar="N",
                   help="priority orders prioritized planning tries (default 20)")
    p.add_argument("--rounds", type=number(0, kind=int), default=300, metavar="N",
                   help="rounds of large neighbourhood search improving a prioritized plan (default 300)")
    p.add_argument("--time-limit", type=number(0, kind=float, strict=True), default=DEFAULT_PLAN_SECONDS,
                   metavar="S", help="seconds (wall clock) the search may take: conflict-based search stops at "
                   "half of them, LNS rounds stop at the end keeping the plan improved so far, and with no plan "
                   f"by then the command says so and exits 1 (default {DEFAULT_PLAN_SECONDS:g})")
    p.add_argument("--show", action="store_true",
                   help="print every agent's moves (N E S W; lower case: a bump into a wall, i.e. a wait)")
    p.add_argument("--slip", type=number(0, 1), default=None, metavar="P",
                   help="execute the plan where a move fails with probability P (default: the map's own slip)")
    p.add_argument("--start-hold", type=number(0, kind=int), default=None, metavar="H",
                   help="execute the plan where each AGV's first 0..H moves fail (default: the map's own)")
    p.add_argument("--executions", type=number(0, kind=int), default=100, metavar="N",
                   help="seeded executions of the plan under those delays, kept in order by its action "
                        "dependency graph (cq_ros.mapf.execute); execution r draws the delays of a learner's run r "
                        "(default 100; 0: none)")
    p.add_argument("--stop-anywhere", action="store_true",
                   help="let an executing AGV wait in a cell without a wall by sending no action (a stay the "
                        "learners do not have): what the world's lack of a wait action costs the executions")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="change a setting of the executions' world (repeatable); `cq-ros settings` lists them")

    p = sub.add_parser("reproduce", help="the paper's grid (4 maps x 5 algorithms), figures and REPORT.md")
    p.add_argument("--out", type=nonempty_path, required=True, help="result directory")
    add_run_options(p, runs=10, episodes=10_000)
    p.add_argument("--no-sweep", dest="sweep", action="store_false", help="skip the settings sweep")
    p.add_argument("--seeds", type=seed_list, default=None, metavar="S,S,...",
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
    p.add_argument("--agents", type=size_list, required=True, metavar="N,N,...", help="fleet sizes, e.g. 8,12")
    p.add_argument("--maps", type=positive_int, default=10, help="generated maps per size (default 10)")
    p.add_argument("--greedy-episodes", type=number(1, kind=int), default=100, metavar="G",
                   help="greedy episodes per unit and copy (default 100)")
    p.add_argument("--algos", type=algo_list, default=["cq", "indep"],
                   help="comma-separated, the first the reference of differences and ratios (default cq,indep)")
    p.add_argument("--variant", action="append", default=[], metavar="NAME=ALGO:KEY=VALUE,...",
                   help="add a configuration: an algorithm with settings of its own over the study's (repeatable)")
    p.add_argument("--tuning", action="store_true",
                   help="draw the maps from the tuning generator seeds (0, 7), where settings are chosen, instead of "
                        "the held-out ones; the report says so")
    p.add_argument("--slip", type=number(0, 1), default=0.1, metavar="P", help="the maps' slip (default 0.1)")
    p.add_argument("--curve-every", type=positive_int, default=250, metavar="K",
                   help="learning episodes between the curve's points (default 250)")
    p.add_argument("--curve-episodes", type=positive_int, default=20, metavar="C",
                   help="frozen greedy episodes per point of the curve (default 20)")
    p.add_argument("--out", type=nonempty_path, required=True,
                   help="result directory (study.md, units.csv, curve.csv, planner.csv, maps/); resumed if it holds "
                        "a study of the same protocol")
    add_run_options(p, runs=10, episodes=2000)


def add_render_parser(sub) -> None:
    p = sub.add_parser("render", help="draw one episode as an animated GIF (or MP4 where ffmpeg is installed): "
                                      "the map, the AGVs, their goals and whom each agent looks at; from the "
                                      "offline engine (--map, --algo) or from a bag of `cq-ros record` (--bag)")
    p.add_argument("--out", type=nonempty_path, required=True,
                   help="the animation to write: NAME.gif, or NAME.mp4 (ffmpeg)")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--map", help="run the offline engine on this map (a shipped name or a path)")
    source.add_argument("--bag", type=nonempty_path, help="a rosbag2 directory recorded by `cq-ros record`")
    # None until given, so that a bag can refuse them: their defaults are the engine's (offline.render)
    p.add_argument("--algo", type=algo_name, default=None, help=f"with --map: one of {','.join(LEARNERS)} (default cq)")
    p.add_argument("--episodes", type=episode_count, default=None, help="with --map: episodes to learn (default 100)")
    p.add_argument("--seed", type=seed_int, default=None, help="with --map: master seed (default 0)")
    p.add_argument("--episode", type=number(0, kind=int), default=None, metavar="E",
                   help="the episode to draw, from 0 (default: with --map, the last learning episode; with --bag, the "
                        "last episode the bag holds whole)")
    p.add_argument("--greedy", action="store_true",
                   help="with --map: draw the greedy policy's first episode after the learning ones, not a "
                        "learning episode")
    p.add_argument("--fps", type=seconds, default=4.0, help="frames (steps) per second (default 4)")
    p.add_argument("--dpi", type=number(0, MAX_DPI, strict=True), default=None,
                   help=f"pixels an inch of the picture, a cell being 0.6 in (default 72, at most {MAX_DPI}: a "
                        "warehouse at more takes gigabytes); fewer make a smaller file")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="with --map: change a setting (repeatable)")
    add_engine_option(p)

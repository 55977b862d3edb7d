"""The data the pages' generated figures are made of, measured again: for each row of a figure, the command
that makes it, its files kept under docs/data/<figure>/<row>/, then the pages' blocks rewritten
(`python docs/figures.py --write`).

    python benchmarks/docs_data.py who-listens [--only ROW ...] [--data DIR]
    python benchmarks/docs_data.py warehouses [--only ROW ...] [--data DIR]
    python benchmarks/docs_data.py cq-choices [--only ROW ...] [--data DIR]

who-listens: one `cq-ros launch` per row (CQ at three lingers, JS, LoC at two), about a minute each on a quiet
2-core machine, with the 1-minute load average before and after it (load.json). warehouses: one `cq-ros
experiment` per row (10 runs x 2,000 episodes of CQ and independent learners), a few minutes each, and what
`cq-ros plan` prints for its map. cq-choices: one `cq-ros experiment` of CQ alone per row (10 runs x 10,000
episodes, the paper's maps at the paper's settings), a choice of docs/choices.md set each way, 10-30 s each
(about 6 minutes in all). Each command shows its own progress on stderr.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "docs" / "data"
CQ_ROS = str(Path(sys.executable).with_name("cq-ros"))


def _launch(map_name: str, algo: str, linger: int) -> list[str]:
    return ["launch", "--map", map_name, "--algo", algo, "--episodes", "300", "--seed", "0",
            "--peer-linger-steps", str(linger), "--no-figures"]


def _experiment(map_name: str, seed: int) -> list[str]:
    return ["experiment", "--map", map_name, "--algo", "cq,indep", "--runs", "10", "--episodes", "2000",
            "--seed", str(seed), "--jobs", "2", "--no-figures"]


def _cq(map_name: str, seed: int, *sets: str) -> list[str]:
    return ["experiment", "--map", map_name, "--algo", "cq", "--runs", "10", "--episodes", "10000",
            "--seed", str(seed), "--jobs", "1", "--no-figures", *[a for s in sets for a in ("--set", s)]]


# figure -> row folder -> the cq-ros command that measures it (its --out added here)
ROWS = {
    "who-listens": {
        "1-tunnel_to_goal-cq-linger0": _launch("tunnel_to_goal", "cq", 0),
        "2-tunnel_to_goal-cq-linger1": _launch("tunnel_to_goal", "cq", 1),
        "3-tunnel_to_goal-cq-linger3": _launch("tunnel_to_goal", "cq", 3),
        "4-tunnel_to_goal-js-linger0": _launch("tunnel_to_goal", "js", 0),
        "5-grid_game_2-loc-linger0": _launch("grid_game_2", "loc", 0),
        "6-grid_game_2-loc-linger3": _launch("grid_game_2", "loc", 3),
    },
    "warehouses": {
        "1-warehouse_8": _experiment("warehouse_8", 0),
        "2-warehouse_16": _experiment("warehouse_16", 0),
        "3-warehouse_16-seed1": _experiment("warehouse_16", 1),
        "4-warehouse_16-seed2": _experiment("warehouse_16", 2),
    },
    # docs/choices.md: CQ's bootstrap both ways on the paper's maps (tunnel_to_goal's seed 0 with ours is also
    # the defaults that the other rows are set against), confidence that fades fast, the greedy copy frozen
    "cq-choices": {
        **{f"bootstrap-{m}-seed{seed}-{who}": _cq(m, seed, f"cq_bootstrap_acted={b}")
           for m, seeds in (("tunnel_to_goal", (0, 1, 2)), ("grid_game_2", (0, 1, 2)), ("tunnel_to_goal_3", (0,)))
           for seed in seeds for who, b in (("ours", 1), ("papers", 0))},
        "confidence-tunnel_to_goal-seed0-fast": _cq("tunnel_to_goal", 0, "conf_down=0.1", "conf_max=2"),
        "frozen-tunnel_to_goal-seed0": _cq("tunnel_to_goal", 0, "eval_learning=0"),
        "frozen-tunnel_to_goal_3-seed0": _cq("tunnel_to_goal_3", 0, "eval_learning=0"),
    },
}
KEPT = ("manifest.json", "greedy.csv")


def measure(figure: str, row: str, data: Path) -> None:
    command = ROWS[figure][row]
    target = data / figure.replace("-", "_") / row
    with tempfile.TemporaryDirectory() as scratch:
        out = Path(scratch) / row
        print(f"docs_data: {figure} {row}: cq-ros {' '.join(command)}", file=sys.stderr, flush=True)
        before = os.getloadavg()[0]
        subprocess.run([CQ_ROS, *command, "--out", str(out)], check=True, cwd=ROOT)
        after = os.getloadavg()[0]
        target.mkdir(parents=True, exist_ok=True)
        for kept in KEPT:
            shutil.copyfile(out / kept, target / kept)
        if figure != "warehouses":
            (target / "load.json").write_text(json.dumps({"before": before, "after": after}) + "\n")
        if figure == "who-listens":
            shutil.copyfile(out / "episodes.csv", target / "episodes.csv")
            return
        # 40,000 rows or more: kept compressed
        (target / "episodes.csv.gz").write_bytes(gzip.compress((out / "episodes.csv").read_bytes(), mtime=0))
        if figure == "cq-choices":  # the joint states each run ends with
            shutil.copyfile(out / "observe.csv", target / "observe.csv")
        else:
            plan = subprocess.run([CQ_ROS, "plan", "--map", command[command.index("--map") + 1]], check=True,
                                  cwd=ROOT, capture_output=True, text=True)
            (target / "plan.txt").write_text(plan.stdout)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("figure", choices=sorted(ROWS))
    parser.add_argument("--only", nargs="+", metavar="ROW", help="measure these rows alone")
    parser.add_argument("--data", type=Path, default=DATA, help=f"where the rows go (default {DATA})")
    args = parser.parse_args()
    unknown = sorted(set(args.only or ()) - set(ROWS[args.figure]))
    if unknown:
        parser.error(f"no row {', '.join(unknown)} in {args.figure}; rows: {', '.join(ROWS[args.figure])}")
    for row in args.only or ROWS[args.figure]:
        try:
            measure(args.figure, row, args.data)
        except subprocess.CalledProcessError as exc:
            print(f"docs_data: {args.figure} {row}: {exc.cmd[1]} exited {exc.returncode}", file=sys.stderr)
            return 1
    if args.data == DATA:
        return subprocess.run([sys.executable, str(ROOT / "docs" / "figures.py"), "--write"]).returncode
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Who listens to whom, measured: one `cq-ros launch` per row of docs/ros.md's table (CQ at three lingers, JS,
LoC at two), each written into docs/data/who_listens/<row>/ (manifest.json, episodes.csv, greedy.csv, and
load.json, the machine's 1-minute load average before and after it), then the table regenerated from them.

    python benchmarks/who_listens.py [--only NAME ...] [--data DIR]

Each launch shows its own progress on stderr; about a minute each on a quiet 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "docs" / "data" / "who_listens"
KEPT = ("manifest.json", "episodes.csv", "greedy.csv")

# row folder -> (map, algo, peer_linger_steps); 300 episodes, seed 0 each
ROWS = {
    "1-tunnel_to_goal-cq-linger0": ("tunnel_to_goal", "cq", 0),
    "2-tunnel_to_goal-cq-linger1": ("tunnel_to_goal", "cq", 1),
    "3-tunnel_to_goal-cq-linger3": ("tunnel_to_goal", "cq", 3),
    "4-tunnel_to_goal-js-linger0": ("tunnel_to_goal", "js", 0),
    "5-grid_game_2-loc-linger0": ("grid_game_2", "loc", 0),
    "6-grid_game_2-loc-linger3": ("grid_game_2", "loc", 3),
}


def measure(name: str, data: Path) -> None:
    map_name, algo, linger = ROWS[name]
    with tempfile.TemporaryDirectory() as scratch:
        out = Path(scratch) / name
        command = [str(Path(sys.executable).with_name("cq-ros")), "launch", "--map", map_name, "--algo", algo,
                   "--episodes", "300", "--seed", "0", "--peer-linger-steps", str(linger), "--out", str(out),
                   "--no-figures"]
        before = os.getloadavg()[0]
        print(f"who_listens: {name}: {' '.join(command[1:])}", file=sys.stderr, flush=True)
        subprocess.run(command, check=True, cwd=ROOT)
        after = os.getloadavg()[0]
        target = data / name
        target.mkdir(parents=True, exist_ok=True)
        for kept in KEPT:
            shutil.copyfile(out / kept, target / kept)
        (target / "load.json").write_text(json.dumps({"before": before, "after": after}) + "\n")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="+", choices=sorted(ROWS), help="measure these rows alone")
    parser.add_argument("--data", type=Path, default=DATA, help=f"where the rows go (default {DATA})")
    args = parser.parse_args()
    for name in args.only or ROWS:
        try:
            measure(name, args.data)
        except subprocess.CalledProcessError as exc:
            print(f"who_listens: {name}: the launch exited {exc.returncode}", file=sys.stderr)
            return 1
    if args.data == DATA:
        return subprocess.run([sys.executable, str(ROOT / "docs" / "figures.py"), "--write"]).returncode
    return 0


if __name__ == "__main__":
    sys.exit(main())

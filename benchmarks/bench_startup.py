"""Start-up of a launch as a process per node: seconds from `cq-ros launch` to the world's first step ("every agent
is connected: stepping" in its log) and to the end, on this machine as it is (the load average is printed: a
busy machine is the case that matters).

    python benchmarks/bench_startup.py [--map warehouse_32] [--algo cq] [--episodes 1] [--domain-id N]
        [--timeout 900] [--out DIR]

One launch without greedy episodes (eval_episodes=0: the start is what is measured), its output in DIR (kept: the
nodes' logs say why a start failed) or in a temporary folder; the launch's own progress lines pass through on
stderr, and one line of figures goes to stdout. Every wait is bounded by --timeout (the launch is stopped then,
with Ctrl-C's signal).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

STEPPING = "every agent is connected: stepping"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--map", default="warehouse_32")
    ap.add_argument("--algo", default="cq")
    ap.add_argument("--episodes", type=int, default=1)
    ap.add_argument("--domain-id", type=int, default=None, help="default: the environment's, else the launch draws")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds before the launch is stopped")
    ap.add_argument("--out", type=Path, default=None, help="the result folder, kept (default: a temporary one)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_startup_") as tmp:
        out = args.out if args.out is not None else Path(tmp) / "result"
        command = [sys.executable, "-m", "cq_ros.cli", "launch", "--map", args.map, "--algo", args.algo, "--episodes",
                   str(args.episodes), "--out", str(out), "--no-figures", "--force", "--set", "eval_episodes=0",
                   *(["--domain-id", str(args.domain_id)] if args.domain_id is not None else [])]
        load = os.getloadavg()[0]
        started, started_wall = time.monotonic(), time.time()
        launch = subprocess.Popen(command, stdout=subprocess.DEVNULL)  # its summary is not this script's figure
        stepping = None

        def stepped() -> bool:  # in this launch's world log, not one an earlier launch left in DIR
            log = out / "logs" / "world.log"
            try:
                return log.stat().st_mtime >= started_wall and STEPPING in log.read_text(errors="replace")
            except OSError:
                return False

        try:
            while launch.poll() is None and time.monotonic() - started < args.timeout:
                if stepping is None and stepped():
                    stepping = time.monotonic() - started
                time.sleep(0.2)
            if launch.poll() is None:
                launch.send_signal(signal.SIGINT)
                launch.wait(timeout=60)
        finally:
            if launch.poll() is None:
                launch.kill()
                launch.wait()
        ended = time.monotonic() - started
        if stepping is None and stepped():
            stepping = ended  # seen only at the end (the last poll missed it)
    to_step = "never" if stepping is None else f"{stepping:.1f} s"
    print(f"{args.map} {args.algo}, {args.episodes} episode(s), a process per node, load {load:.1f} at start: "
          f"stepping after {to_step}, ended after {ended:.1f} s with exit status {launch.returncode}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Why CQ's state count climbs (the paper's Fig. 5a): one run of CQ, with the joint states marked and dropped
in every block of episodes, and at the end each kept joint state's confidence beside how often its cell was
visited in the last block (a joint state loses confidence only when its cell is visited without it).

    python benchmarks/joint_state_churn.py --map tunnel_to_goal_3 [--seed 0 --run 0 --episodes 10000
        --block 1000] [--set conf_down=0.1 ...]

Prints one line per block (joint states marked / dropped, exploring collisions per episode) and the kept
joint states by how often their cell was visited, after the machine and its load average (and the load again at
the end); progress on stderr. A run of 10,000 episodes takes about half a minute on a quiet core.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from cq_ros.engine import Team, make_learners, world_seed  # noqa: E402
from cq_ros.gridmap import MapError, load_map  # noqa: E402
from cq_ros.settings import SettingsError, run_settings  # noqa: E402
from cq_ros.world import GridWorld  # noqa: E402

VISITS = ((0, 1), (1, 10), (10, 100), (100, 1000), (1000, None))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--map", required=True)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--run", type=int, default=0)
    p.add_argument("--episodes", type=int, default=10_000)
    p.add_argument("--block", type=int, default=1000)
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = p.parse_args(argv)
    if args.episodes < 1 or args.block < 1:
        p.exit(2, "joint_state_churn: error: --episodes and --block must be at least 1\n")
    try:
        gridmap = load_map(args.map)
        settings = run_settings(gridmap, args.overrides)
    except (MapError, SettingsError) as e:
        p.exit(2, f"joint_state_churn: error: {e}\n")
    team = Team(GridWorld(gridmap, settings, seed=world_seed(args.seed, args.run)),
                make_learners("cq", gridmap, settings, args.seed, args.run))
    visits: Counter = Counter()  # (agent, cell) -> decisions taken there in the last block
    last_block = (args.episodes - 1) // args.block

    def counting(learner):
        observe = learner.observe

        def observe_and_count(cell):
            visits[(learner.agent, cell)] += 1
            return observe(cell)
        return observe_and_count

    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
          f"load average {os.getloadavg()[0]:.2f}")
    print(f"cq on {gridmap.name}, seed {args.seed} run {args.run}: conf_init {settings.conf_init}, "
          f"conf_up {settings.conf_up}, conf_down {settings.conf_down}, conf_max {settings.conf_max}, "
          f"conf_drop {settings.conf_drop}, epsilon {settings.epsilon}")
    print("episodes       marked  dropped  kept  collisions/ep")
    kept = {(learner.agent, js) for learner in team.learners for js in learner.confidence}
    marked = dropped = collisions = 0
    for e in range(args.episodes):
        if e // args.block == last_block and e % args.block == 0:
            for learner in team.learners:
                learner.observe = counting(learner)
        collisions += team.episode().collisions
        now = {(learner.agent, js) for learner in team.learners for js in learner.confidence}
        marked, dropped, kept = marked + len(now - kept), dropped + len(kept - now), now
        if (e + 1) % args.block == 0 or e + 1 == args.episodes:
            done = e + 1 - e // args.block * args.block
            print(f"{e // args.block * args.block + 1:>5}-{e + 1:<7} {marked:>6}  {dropped:>7}  {len(kept):>4}  "
                  f"{collisions / done:.3f}", flush=True)
            print(f"joint_state_churn: {e + 1}/{args.episodes} episodes", file=sys.stderr, flush=True)
            marked = dropped = collisions = 0
    conf = {(learner.agent, js): c for learner in team.learners for js, c in learner.confidence.items()}
    print(f"kept at the end: {len(conf)} joint states, {sum(c >= settings.conf_max for c in conf.values())} at "
          f"conf_max; by visits of their cell in the last {args.block} episodes:")
    for lo, hi in VISITS:
        sel = [c for (agent, js), c in conf.items()
               if visits[(agent, js[0])] >= lo and (hi is None or visits[(agent, js[0])] < hi)]
        span = f"{lo}+" if hi is None else f"{lo}-{hi - 1}"
        print(f"  visited {span:>8}: {len(sel):>3} joint states"
              + (f", confidence {min(sel):.2f}-{max(sel):.2f}" if sel else ""))
    print(f"load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

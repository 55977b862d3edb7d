#!/usr/bin/env python3
"""ROS mode speed: lockstep steps per second of `cq-ros launch` (one world process and one process per AGV)
for 2 agents (tunnel_to_goal: indep, cq, js, and cq with its peer subscriptions kept 3 steps longer) and
8 agents (warehouse_8: indep, cq), beside the rclpy round trip between two processes measured in the same
run (a lockstep step is at least one round trip: feedback out, action back), the step rate that round trip
allows (1 / median) and the ratio; then CQ's step rate and communication against JS's on tunnel_to_goal.

    python benchmarks/bench_ros.py [--tunnel-episodes 300] [--warehouse-episodes 10] [--warehouse-step-cap 300]

Steps per second are the world's: steps over the summed wall-clock length of its episodes (WorldStats
duration_s), so process start-up and discovery are left out; the wall time of each launch is shown beside.
warehouse_8's episodes are capped (every early episode would run to the 5000-step cap).
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
from pathlib import Path

from bench_roundtrip import measure_roundtrip

from cq_ros.settings import Settings
from world_node.launch import launch


def lockstep(map_name: str, algo: str, episodes: int, settings: Settings, linger: int | None = None,
             seed: int = 0) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench_ros_") as tmp:
        result = launch(map_name, algo, episodes, seed, Path(tmp) / "out", settings, peer_linger_steps=linger,
                        figures=False, progress=False)
    m = result.manifest
    steps = int(result.episodes[:, 0].sum())
    comm = m["communication"].values()
    return {"map": map_name, "agents": m["n_agents"], "algo": algo, "linger": m["peer_linger_steps"],
            "episodes": episodes, "steps": steps,
            "stepping_s": m["world"]["stepping_s"], "steps_per_s": steps / m["world"]["stepping_s"],
            "wall_s": m["wall_time_s"], "peer_messages": sum(c["peer_messages"] for c in comm),
            "subscriptions": sum(c["subscriptions_created"] for c in comm),
            "missed_actions": m["world"]["missed_actions"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tunnel-episodes", type=int, default=300)
    parser.add_argument("--warehouse-episodes", type=int, default=10)
    parser.add_argument("--warehouse-step-cap", type=int, default=300)
    parser.add_argument("--pings", type=int, default=2000, help="round trips to time (default 2000)")
    args = parser.parse_args()

    rt = measure_roundtrip(n=args.pings, qos=("reliable",))["reliable"]
    allowed = 1000.0 / rt["median_ms"]
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}")
    print(f"rclpy round trip between two processes (our position message, reliable, {rt['n']} pings): "
          f"median {rt['median_ms']:.3f} ms, p90 {rt['p90_ms']:.3f} ms -> at most {allowed:,.0f} lockstep steps/s")

    # Learning episodes only: the greedy evaluation would add episodes of another kind.
    tunnel = Settings().with_overrides({"eval_episodes": 0})
    warehouse = tunnel.with_overrides({"step_cap": args.warehouse_step_cap})
    cases = [("tunnel_to_goal", a, args.tunnel_episodes, tunnel, None) for a in ("indep", "cq", "js")]
    cases += [("tunnel_to_goal", "cq", args.tunnel_episodes, tunnel, 3)]  # subscriptions kept 3 steps longer
    cases += [("warehouse_8", a, args.warehouse_episodes, warehouse, None) for a in ("indep", "cq")]
    print(f"{'map':<15} {'agent procs':>11} {'algo':<6} {'linger':>6} {'episodes':>8} {'steps':>7} {'steps/s':>8} "
          f"{'of round-trip rate':>18} {'wall s':>7} {'peer msgs':>9} {'subs made':>9} {'missed':>6}")
    rows = {}
    for map_name, algo, episodes, settings, linger in cases:
        r = rows[map_name, algo, linger] = lockstep(map_name, algo, episodes, settings, linger)
        print(f"{map_name:<15} {r['agents']:>11} {algo:<6} {r['linger']:>6} {episodes:>8} {r['steps']:>7} "
              f"{r['steps_per_s']:>8,.0f} {r['steps_per_s'] / allowed:>18.0%} {r['wall_s']:>7.1f} "
              f"{r['peer_messages']:>9} {r['subscriptions']:>9} {r['missed_actions']:>6}", flush=True)

    cq, js = rows["tunnel_to_goal", "cq", None], rows["tunnel_to_goal", "js", None]
    print(f"tunnel_to_goal, CQ against JS over {args.tunnel_episodes} episodes: "
          f"{cq['steps_per_s']:,.0f} vs {js['steps_per_s']:,.0f} steps/s "
          f"({cq['steps_per_s'] / js['steps_per_s']:.2f}x); peer messages {cq['peer_messages']} vs "
          f"{js['peer_messages']} (JS/CQ {js['peer_messages'] / cq['peer_messages']:.1f}x; "
          f"{cq['peer_messages'] / cq['steps']:.3f} vs {js['peer_messages'] / js['steps']:.3f} "
          f"per step); peer subscriptions made {cq['subscriptions']} vs {js['subscriptions']}")


if __name__ == "__main__":
    main()

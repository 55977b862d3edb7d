#!/usr/bin/env python3
"""ROS mode speed: lockstep steps per second of `cq-ros launch` composed (every node in one process) and with a
process per node, each against the messaging-only ceiling of the same topology measured in the same run
(benchmarks/ceiling.py: the same nodes, topics, QoS and message sizes with no decoding, checking or learning;
and beside it the same with the wire contract put back, every message encoded and decoded as the nodes do, and
with every message's MAC alone made and checked, the floor of any contract with that MAC in Python),
with the ratios to it and to each other, for independent learners, for a CQ that has learnt (its agents start
from checkpoints of an offline run of the same map, so joint states are marked and peers subscribed: peer
messages a step printed beside) and for JS (every peer all the time, against the ceiling with every peer
subscribed); beside the rclpy round trip between two processes (a step across processes is at least one).
The learnt CQ is also set against the ceiling making as many peer subscriptions a step as it does (ceiling.py
--churn; one launch, not timed, counts them): a subscription costs the middleware milliseconds.

    python benchmarks/bench_ros.py [--maps tunnel_to_goal,warehouse_16] [--episodes 200,3] [--step-cap 300]
                                   [--algos indep,cq,js] [--repeats 3] [--train-episodes 300] [--extras]

Every mode of a map (the ceilings, and each algorithm composed and with a process per node) runs once in each of
`--repeats` blocks, the order turned by one each block, so every mode sees the same load on a shared machine; the
summary gives the medians, their ratios and every block's rate.

`--extras` adds the earlier comparisons: the executors (EventsExecutor against SingleThreadedExecutor) in both
modes, markers on with nobody subscribed against off, CQ from scratch and with linger 3.

Steps per second are the world's: steps over the summed wall-clock length of its episodes (WorldStats
duration_s), so process start-up and discovery are left out; the wall time of each launch is shown beside.
The episodes are capped at --step-cap (every early warehouse episode would run to the 5000-step cap). The
world waits --step-timeout for an action (the launch's 2 s would end a loaded 17-process JS run); a launch
that fails anyway is a row saying why, and the rows after it still run.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
from functools import partial
from pathlib import Path

from bench_roundtrip import measure_roundtrip
from ceiling import PEERS, ceiling, kind

from agent_node.checkpoint import save_checkpoints
from cq_ros.engine import Team, make_learners, world_seed
from cq_ros.gridmap import load_map
from cq_ros.settings import Settings, run_settings
from cq_ros.world import GridWorld
from ros_tools.launch import launch
from ros_tools.launch_end import LaunchError
from ros_tools.launch_nodes import agent_nodes


ROUND_TRIP_REPEATS = 3
ALGOS = ("indep", "cq", "js")  # cq: learnt (started from an offline run's checkpoints)


def lockstep(map_name: str, algo: str, episodes: int, settings: Settings, linger: int | None = None,
             seed: int = 0, compose: bool = False, executor: str = "events", markers: bool = True,
             start_from: Path | None = None, step_timeout: float = 2.0) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench_ros_") as tmp:
        result = launch(map_name, algo, episodes, seed, Path(tmp) / "out", settings, peer_linger_steps=linger,
                        compose=compose, executor=executor, markers=markers, figures=False, progress=False,
                        start_from=start_from, step_timeout=step_timeout)
    m = result.manifest
    steps = int(result.episodes["steps"].sum())
    comm = m["communication"].values()
    return {"map": m["map"], "agents": m["n_agents"], "algo": algo + (" learnt" if start_from else ""),
            "linger": m["peer_linger_steps"], "mode": "composed" if compose else "processes",
            "executor": executor, "markers": markers, "episodes": episodes, "steps": steps,
            "stepping_s": m["world"]["stepping_s"], "steps_per_s": steps / m["world"]["stepping_s"],
            "wall_s": m["wall_time_s"], "peer_messages": sum(c["peer_messages"] for c in comm),
            "subscriptions": sum(c["subscriptions_created"] for c in comm),
            "missed_actions": m["world"]["missed_actions"]}


def load() -> str:
    return f"load average {os.getloadavg()[0]:.2f}"


def trained(map_name: str, settings: Settings, episodes: int, seed: int, folder: Path) -> Path:
    """Checkpoints of CQ learners after `episodes` offline episodes on the map, for the agent nodes to start from."""
    gridmap = load_map(map_name)
    team = Team(GridWorld(gridmap, settings, seed=world_seed(seed, 0)), make_learners("cq", gridmap, settings, seed, 0))
    for _ in range(episodes):
        team.episode()
    save_checkpoints(folder, [name for name, _ in agent_nodes(gridmap, "cq")], team.learners, episodes - 1)
    return folder


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--maps", default="tunnel_to_goal,warehouse_16")
    parser.add_argument("--episodes", default="200,3", help="learning episodes per map, in --maps' order")
    parser.add_argument("--algos", default=",".join(ALGOS), help=f"of {', '.join(ALGOS)} (default all)")
    parser.add_argument("--repeats", type=int, default=3, help="blocks of every mode, rotated; medians printed")
    parser.add_argument("--step-cap", type=int, default=300)
    parser.add_argument("--train-episodes", type=int, default=300, help="offline CQ episodes before the learnt runs")
    parser.add_argument("--ceiling-steps", type=int, default=2000)
    parser.add_argument("--pings", type=int, default=2000, help="round trips to time (default 2000)")
    parser.add_argument("--step-timeout", type=float, default=10.0, help="the world's wait for an action, s")
    parser.add_argument("--extras", action="store_true", help="also the executors, markers and linger rows")
    args = parser.parse_args()
    maps = args.maps.split(",")
    episodes = [int(e) for e in args.episodes.split(",")]
    algos = args.algos.split(",")
    if len(episodes) != len(maps):
        parser.error(f"--episodes gives {len(episodes)} counts for {len(maps)} maps")
    if not set(algos) <= set(ALGOS) or args.repeats < 1:
        parser.error(f"--algos: choose from {', '.join(ALGOS)}; --repeats at least 1")

    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, {load()}")
    medians = []
    for _ in range(ROUND_TRIP_REPEATS):  # it moves by a third within a minute here: the fastest is the floor
        rt = measure_roundtrip(n=args.pings, qos=("reliable",), stack="nodes")["reliable"]
        medians.append(rt["median_ms"])
    allowed = 1000.0 / min(medians)
    print(f"rclpy round trip between two processes (nodes' stack, {args.pings} pings, fastest median of "
          f"{ROUND_TRIP_REPEATS}: {', '.join(f'{m:.3f}' for m in medians)} ms) -> at most {allowed:,.0f} steps/s "
          "across processes", flush=True)

    print(f"{'block':>5} {'map':<15} {'agents':>6} {'algo':<10} {'mode':<9} {'executor':<8} {'markers':<7} "
          f"{'episodes':>8} {'steps':>6} {'steps/s':>8} {'wall s':>7} {'peer msgs/step':>14} {'subs made':>9} "
          f"{'missed':>6}")
    rates: dict[tuple, list[float]] = {}  # (map, what) -> steps/s of each block
    rows: dict[tuple, dict] = {}  # (map, what) -> the last row of a launch
    loads: list[float] = []
    # The maps' own settings; learning episodes only (the greedy evaluation would add episodes of another kind).
    settings = {m: run_settings(load_map(m), {"eval_episodes": 0, "step_cap": args.step_cap}) for m in maps}

    def row(block, map_name, n_episodes, algo, linger=None, **how) -> None:
        mode = "composed" if how.get("compose") else "processes"
        name = algo + (" learnt" if how.get("start_from") else "")
        try:
            r = lockstep(map_name, algo, n_episodes, settings[map_name], linger, step_timeout=args.step_timeout,
                         **how)
        except LaunchError as e:
            print(f"{block:>5} {map_name:<15} {'':>6} {name:<10} {mode:<9} failed: {e}", flush=True)
            return
        what = (r["algo"], linger, r["mode"], r["executor"], r["markers"])
        rates.setdefault((map_name, what), []).append(r["steps_per_s"])
        rows[map_name, what] = r
        print(f"{block:>5} {r['map']:<15} {r['agents']:>6} {r['algo']:<10} {r['mode']:<9} {r['executor']:<8} "
              f"{'on' if r['markers'] else 'off':<7} {n_episodes:>8} {r['steps']:>6} {r['steps_per_s']:>8,.0f} "
              f"{r['wall_s']:>7.1f} {r['peer_messages'] / r['steps']:>14.2f} {r['subscriptions']:>9} "
              f"{r['missed_actions']:>6}", flush=True)

    def top(block, map_name, agents, peers, contract, churn=0.0, mac_only=False) -> None:
        steps = args.ceiling_steps if peers == "none" else max(args.ceiling_steps // 4, 100)
        c = ceiling(agents, steps, peers, contract=contract, churn=churn, mac_only=mac_only)
        what = ("ceiling", peers, "mac" if mac_only else contract, bool(churn))
        rates.setdefault((map_name, what), []).append(c["steps_per_s"])
        loads.append(os.getloadavg()[0])
        made = f", {churn:.3f} subscriptions made a step (CQ's)" if churn else ""
        print(f"{block:>5} {map_name:<15} {agents:>6} {kind(contract, mac_only)}, peers {peers}{made}: "
              f"{c['steps_per_s']:,.0f} steps/s ({c['deliveries_per_step']} deliveries a step, "
              f"{c['cpu_ms_per_step']:.3f} ms of CPU a step; {load()})", flush=True)

    summary = []
    churn: dict[str, float] = {}  # map -> the learnt CQ's peer subscriptions a step
    with tempfile.TemporaryDirectory(prefix="bench_ros_ck_") as ck:
        for map_name, n_episodes in zip(maps, episodes):
            agents = load_map(map_name).n_agents
            folder = Path(ck) / map_name
            folder.mkdir()
            trained(map_name, settings[map_name], args.train_episodes, 0, folder)
            runs = {"indep": (None, "none"), "cq": (folder, "none"), "js": (None, "all")}
            peer_sets = sorted({runs[a][1] for a in algos}, key=PEERS.index)
            # Every mode once a block, the order turned by one each block: each mode sees every part of the load.
            # The ceiling, the contract's row, and between them the floor of any contract with the run's MAC in
            # Python (every message's MAC made and checked, nothing else)
            modes = [partial(top, map_name=map_name, agents=agents, peers=peers, contract=contract,
                             mac_only=mac_only)
                     for peers in peer_sets for contract, mac_only in ((False, False), (False, True), (True, False))]
            if "cq" in algos:
                # The learnt CQ's peer subscriptions, the same in every launch of it (one, not timed, says how
                # many): its ceiling makes as many a step, each for one decision step.
                r = lockstep(map_name, "cq", n_episodes, settings[map_name], compose=True, start_from=folder,
                             step_timeout=args.step_timeout)
                churn[map_name] = min(r["subscriptions"] / r["steps"], 1.0)
                print(f"{'':>5} {map_name:<15} {agents:>6} cq learnt makes {r['subscriptions']} peer subscriptions in "
                      f"{r['steps']} steps (a launch not timed)", flush=True)
                if churn[map_name]:
                    modes.append(partial(top, map_name=map_name, agents=agents, peers="none", contract=False,
                                         churn=churn[map_name]))
            modes += [partial(row, map_name=map_name, n_episodes=n_episodes, algo=algo, compose=compose,
                              start_from=runs[algo][0]) for algo in algos for compose in (False, True)]
            for block in range(args.repeats):
                turn = block % len(modes)
                for mode in modes[turn:] + modes[:turn]:
                    mode(block + 1)
            summary += [(map_name, agents, algo, runs[algo][1]) for algo in algos]
            if args.extras:
                row(0, map_name, n_episodes, "cq")  # from scratch
                row(0, map_name, n_episodes, "cq", 3)  # subscriptions kept 3 steps longer
                for compose in (False, True):
                    row(0, map_name, n_episodes, "indep", compose=compose, executor="single")
                row(0, map_name, n_episodes, "indep", compose=True, markers=False)

    def med(map_name, what) -> float | None:
        got = rates.get((map_name, what))
        return statistics.median(got) if got else None

    def each(map_name, what) -> str:
        return ", ".join(f"{x:,.0f}" for x in rates.get((map_name, what), []))

    print(f"\nagainst the messaging-only ceiling of the same topology, medians of {args.repeats} rotated blocks "
          f"in this run (load average {min(loads, default=0):.2f}-{max(loads, default=0):.2f} at the ceilings, "
          f"{load()} now):")
    for map_name, agents, algo, peers in summary:
        name = algo + (" learnt" if algo == "cq" else "")
        ceil = med(map_name, ("ceiling", peers, False, False))
        contract = med(map_name, ("ceiling", peers, True, False))
        macs = med(map_name, ("ceiling", peers, "mac", False))
        composed = med(map_name, (name, None, "composed", "events", True))
        apart = med(map_name, (name, None, "processes", "events", True))
        if composed is None or apart is None:
            continue
        r = rows[map_name, (name, None, "composed", "events", True)]
        print(f"  {map_name:<15} {agents:>2} agents {name:<10} ceiling (peers {peers}) "
              f"{ceil:>6,.0f} steps/s; with the contract {contract:>6,.0f} ({contract / ceil:.0%}); "
              f"its MACs alone {macs:>6,.0f} ({macs / ceil:.0%}); "
              f"composed {composed:>6,.0f} ({composed / ceil:.0%} of it); "
              f"processes {apart:>5,.0f} ({apart / ceil:.0%} of it, "
              f"{apart / allowed:.0%} of the round-trip rate); composed / processes "
              f"{composed / apart:.1f}x; peer messages a step {r['peer_messages'] / r['steps']:.2f}", flush=True)
        churned = med(map_name, ("ceiling", peers, False, True)) if algo == "cq" else None
        if churned is not None:
            print(f"      with CQ's peer subscriptions ({churn[map_name]:.3f} made a step) the ceiling is "
                  f"{churned:,.0f} steps/s: composed {composed / churned:.0%} of it, processes "
                  f"{apart / churned:.0%}", flush=True)
        print(f"      each block: ceiling {each(map_name, ('ceiling', peers, False, False))}; contract "
              f"{each(map_name, ('ceiling', peers, True, False))}; MACs alone "
              f"{each(map_name, ('ceiling', peers, 'mac', False))}; "
              + (f"ceiling with CQ's subscriptions {each(map_name, ('ceiling', peers, False, True))}; "
                 if churned is not None else "")
              + f"composed {each(map_name, (name, None, 'composed', 'events', True))}; processes "
              f"{each(map_name, (name, None, 'processes', 'events', True))}", flush=True)
    if args.extras:
        for name in maps:
            for mode in ("processes", "composed"):
                events = med(name, ("indep", None, mode, "events", True))
                single = med(name, ("indep", None, mode, "single", True))
                if events is None or single is None:
                    continue
                print(f"  executors, {name} indep, {mode}: EventsExecutor {events:,.0f} steps/s, "
                      f"SingleThreadedExecutor {single:,.0f} ({events / single:.1f}x)")
            on = med(name, ("indep", None, "composed", "events", True))
            off = med(name, ("indep", None, "composed", "events", False))
            if on is None or off is None:
                continue
            print(f"  markers with nobody subscribed, {name} indep composed: on {on:,.0f} steps/s, "
                  f"off {off:,.0f} ({on / off - 1:+.1%})")


if __name__ == "__main__":
    main()

"""Wall time of one reproduce-sized grid played three ways: in one local process (--jobs 1), on two (--jobs 2), and
on a Dask cluster of two workers on this machine (a scheduler and two worker processes of one thread, talking
TCP on 127.0.0.1: what `--cluster` reaches on other machines), with the result files checked identical.

    python benchmarks/bench_cluster.py [--runs 5] [--episodes 1000] [--sweep]

Prints the machine, the cluster's start (timed on its own, not in the grid's wall time), then a table with the
load average before and after each way; reproduce's progress on stderr.
"""

from __future__ import annotations

import argparse
import filecmp
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

from cq_ros.lab.reproduce import reproduce


def load() -> str:
    return "/".join(f"{x:.1f}" for x in os.getloadavg())


def same_results(a: Path, b: Path) -> bool:
    """Every episodes.csv, greedy.csv and observe.csv of `a` equals `b`'s, byte for byte."""
    names = sorted(p.relative_to(a) for p in a.rglob("*.csv"))
    return names == sorted(p.relative_to(b) for p in b.rglob("*.csv")) and all(
        filecmp.cmp(a / n, b / n, shallow=False) for n in names)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--sweep", action="store_true", help="the settings sweep too (as cq-ros reproduce does)")
    args = parser.parse_args()
    from distributed import LocalCluster

    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; grid: "
          f"cq-ros reproduce --runs {args.runs} --episodes {args.episodes}{'' if args.sweep else ' --no-sweep'}")
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_cluster_") as scratch:
        grid = {"runs": args.runs, "episodes": args.episodes, "sweep": args.sweep, "figures": False}
        for name, where in (("1 local process (--jobs 1)", {"workers": 1}),
                            ("2 local processes (--jobs 2)", {"workers": 2}),
                            ("Dask, 2 workers on 127.0.0.1 (--cluster)", None)):
            before = load()
            started = time.perf_counter()
            if where is None:
                with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c:
                    up = time.perf_counter() - started
                    print(f"cluster (a scheduler, 2 worker processes of one thread) up in {up:.1f} s, not counted "
                          "in its wall time", flush=True)
                    started = time.perf_counter()
                    reproduce(Path(scratch) / "cluster", cluster=c.scheduler_address, **grid)
                    wall = time.perf_counter() - started
            else:
                reproduce(Path(scratch) / f"jobs{where['workers']}", **where, **grid)
                wall = time.perf_counter() - started
            rows.append((name, wall, before, load()))
        same = same_results(Path(scratch) / "jobs1", Path(scratch) / "jobs2") and same_results(
            Path(scratch) / "jobs1", Path(scratch) / "cluster")
    print("| where the runs go | wall time | load before | load after |")
    print("| --- | ---: | --- | --- |")
    for name, wall, before, after in rows:
        print(f"| {name} | {wall:.0f} s | {before} | {after} |")
    print(f"result files identical in all three: {'yes' if same else 'NO'}")
    sys.exit(0 if same else 1)


if __name__ == "__main__":
    main()

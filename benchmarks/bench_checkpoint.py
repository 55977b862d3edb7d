#!/usr/bin/env python3
"""What a checkpoint costs as data (agent_node.checkpoint, an .npz of cq_ros.learners.state's arrays) against the
pickle it replaced: its size, and the median time to make one (what the agent node does on its executor every
`checkpoint_every` episodes) and to load and check one (once per start), on a fresh learner of one map.

    python benchmarks/bench_checkpoint.py [--map warehouse_32] [--algo cq] [--repeat 7]
"""

from __future__ import annotations

import argparse
import os
import pickle
import statistics
import tempfile
import time

from agent_node.checkpoint import checkpoint_bytes, load_checkpoint, write_checkpoint
from cq_ros.engine import make_learner
from cq_ros.gridmap import load_map
from cq_ros.settings import run_settings


def median_ms(work, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        work()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default="warehouse_32")
    parser.add_argument("--algo", default="cq")
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args()
    gridmap = load_map(args.map)
    settings = run_settings(gridmap)
    learner = make_learner(args.algo, gridmap, settings, 0, 0, 0)
    data, pickled = checkpoint_bytes(learner, 0), pickle.dumps(learner)
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "agv1.npz")
        write_checkpoint(path, data)
        load_ms = median_ms(lambda: load_checkpoint(path, args.algo, gridmap, 0, settings), args.repeat)
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}")
    print(f"{args.map} {args.algo} ({gridmap.n_cells} cells), median of {args.repeat}")
    print(f"npz     {len(data):>9,} bytes  make {median_ms(lambda: checkpoint_bytes(learner, 0), args.repeat):6.1f} ms"
          f"  load {load_ms:6.1f} ms")
    print(f"pickle  {len(pickled):>9,} bytes  make {median_ms(lambda: pickle.dumps(learner), args.repeat):6.1f} ms"
          f"  load {median_ms(lambda: pickle.loads(pickled), args.repeat):6.1f} ms")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""What a peer subscription costs, made and dropped as a CQ agent makes and drops one at each conflict state.

One process, one EventsExecutor (as the nodes run), a writer holding a latched position (msgs_spec's POSITION
QoS) and a reader node. A cycle publishes the next position and waits until the reader has it; the modes differ
only in the reader's subscription:
- `default`: made anew each cycle with rclpy's default event handlers (incompatible QoS, incompatible type);
- `none`: made anew each cycle with no event handler, as agent_node.peer_subscriptions makes them;
- `kept`: made once and kept: the same messages with no subscription made, the floor of the other two.
The modes run in turn, a block of cycles each, round after round, so the machine's drift falls on all of them.
Printed per mode: the median over rounds of the process's CPU time (every thread's: DDS's too) and of the wall
time per cycle, in microseconds.

    python benchmarks/peer_churn.py                 # 10 rounds of 200 cycles a mode
    python benchmarks/peer_churn.py --rounds 4 -n 100

Isolation: its own rclpy Context on --domain, else the environment's ROS_DOMAIN_ID, else a random one in
40..99, discovery on this host; progress on stderr after each round.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

from ros_tools.launch import BENCH_DOMAINS, run_domain

MODES = ("default", "none", "kept")
WAIT_S = 5.0  # for one position; a cycle that waits longer ends the run with an error


def measure(rounds: int, n: int, domain_id: int) -> dict[str, list[tuple[float, float]]]:
    """mode -> (CPU s, wall s) per cycle, one pair a round."""
    import rclpy
    from rclpy.context import Context
    from rclpy.event_handler import SubscriptionEventCallbacks

    from msgs_spec import POSITION, Position, encode
    from node_runtime.qos import profile
    from node_runtime.run import make_executor

    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    writer = rclpy.create_node("writer", context=ctx)
    reader = rclpy.create_node("reader", context=ctx)
    executor = make_executor("events", ctx)
    executor.add_node(writer)
    executor.add_node(reader)
    position = writer.create_publisher(POSITION.msg_type, "position", profile(POSITION.qos))
    got = {"step": -1}
    events = {"default": SubscriptionEventCallbacks(), "none": SubscriptionEventCallbacks(use_default_callbacks=False)}

    def subscribe(mode: str):
        return reader.create_subscription(POSITION.msg_type, "position", lambda m: got.__setitem__("step", m.data[2]),
                                          profile(POSITION.reader_qos), event_callbacks=events.get(mode))

    step = 0
    figures: dict[str, list[tuple[float, float]]] = {mode: [] for mode in MODES}
    try:
        for r in range(rounds):
            for mode in MODES:
                kept = subscribe(mode) if mode == "kept" else None
                cpu, wall = time.process_time(), time.monotonic()
                for _ in range(n):
                    sub = kept or subscribe(mode)
                    step += 1
                    position.publish(encode(Position(agent=1, episode=0, step=step, row=0, col=0)))
                    deadline = time.monotonic() + WAIT_S
                    while got["step"] != step:
                        if time.monotonic() > deadline:
                            raise RuntimeError(f"{mode}: position {step} did not come within {WAIT_S} s")
                        executor.spin_once(timeout_sec=0.01)
                    if kept is None:
                        reader.destroy_subscription(sub)
                if kept is not None:
                    reader.destroy_subscription(kept)
                figures[mode].append(((time.process_time() - cpu) / n, (time.monotonic() - wall) / n))
            print(f"peer_churn: round {r + 1}/{rounds}", file=sys.stderr, flush=True)
    finally:
        executor.shutdown()
        writer.destroy_node()
        reader.destroy_node()
        rclpy.try_shutdown(context=ctx)
    return figures


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=10, help="rounds, each a block of cycles a mode (default 10)")
    ap.add_argument("-n", type=int, default=200, help="cycles a block (default 200)")
    ap.add_argument("--domain", type=int, default=None,
                    help="ROS_DOMAIN_ID (default: the environment's, else random in 40..99)")
    args = ap.parse_args()
    if args.rounds < 1 or args.n < 1:
        ap.error("--rounds and -n must be at least 1")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    figures = measure(args.rounds, args.n, run_domain(args.domain, BENCH_DOMAINS))
    print(f"mode     cycles  CPU us/cycle  wall us/cycle   (medians over {args.rounds} rounds of {args.n})")
    for mode, rows in figures.items():
        cpu, wall = (statistics.median(col) * 1e6 for col in zip(*rows))
        print(f"{mode:<8} {args.rounds * args.n:>6} {cpu:>13.0f} {wall:>14.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

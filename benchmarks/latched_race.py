#!/usr/bin/env python3
"""How often a new subscription's latched sample is never announced to the executor, in one process.

What an agent node does at a conflict state, over and over: a writer holds a latched position (transient local,
depth 1: msgs_spec's POSITION), a subscriber node on the same executor makes a new subscription to it from
inside a callback and waits for the sample; then drops the subscription, and the writer moves on. Counted per
executor: samples that did not come within `--wait` seconds (and whether they were in the reader all along,
taken directly as agent_node.peer_subscriptions takes them), and those that took over 100 ms.

rclpy's EventsExecutor sets the middleware's new-message callback on a subscription after the node made it;
rmw_fastrtps (Jazzy) reads the unread count before it turns its data-available listener on, so a sample landing
between the two is never announced (docs/ros.md, "Composed mode"). A waitset executor asks the reader itself.

    python benchmarks/latched_race.py                      # 20000 subscriptions, both executors
    python benchmarks/latched_race.py -n 5000 --executors events

Isolation: its own rclpy Context on --domain, else the environment's ROS_DOMAIN_ID, else a random one in 40..99,
discovery on this host; progress on stderr every 10 s.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from ros_tools.launch import BENCH_DOMAINS, run_domain

EXECUTORS = ("events", "single")
PROGRESS_S = 10.0


def measure(kind: str, n: int, wait_s: float, domain_id: int) -> dict:
    import rclpy
    from rclpy.context import Context
    from std_msgs.msg import Empty

    from msgs_spec import POSITION, QOS_FEEDBACK, Position, encode
    from node_runtime.qos import profile
    from node_runtime.rclpy_workarounds import take_now
    from node_runtime.run import make_executor

    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    writer = rclpy.create_node("writer", context=ctx)
    reader = rclpy.create_node("reader", context=ctx)
    executor = make_executor(kind, ctx)
    executor.add_node(writer)
    executor.add_node(reader)
    got: dict = {"sub": None, "step": None}

    def on_position(msg) -> None:
        got["step"] = msg.data[2]

    def subscribe(_msg) -> None:  # as AgentNode does it: from inside a callback
        if got["sub"] is not None:
            reader.destroy_subscription(got["sub"])
        got["sub"] = reader.create_subscription(POSITION.msg_type, "position", on_position,
                                                profile(POSITION.reader_qos))

    position = writer.create_publisher(POSITION.msg_type, "position", profile(POSITION.qos))
    kick = writer.create_publisher(Empty, "kick", profile(QOS_FEEDBACK))
    reader.create_subscription(Empty, "kick", subscribe, profile(QOS_FEEDBACK))
    lost = in_reader = slow = 0
    try:
        deadline = time.monotonic() + 5.0
        while kick.get_subscription_count() == 0 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.01)
        next_line = time.monotonic() + PROGRESS_S
        for step in range(n):
            position.publish(encode(Position(agent=1, episode=0, step=step, row=0, col=0)))
            got["step"] = None
            start = time.monotonic()
            kick.publish(Empty())
            while got["step"] != step and time.monotonic() - start < wait_s:
                executor.spin_once(timeout_sec=0.01)
            if got["step"] != step:
                lost += 1
                sub = got["sub"]
                in_reader += take_now(sub) is not None
            elif time.monotonic() - start > 0.1:
                slow += 1
            if time.monotonic() > next_line:
                print(f"latched_race: {kind} {step + 1}/{n}, {lost} lost", file=sys.stderr, flush=True)
                next_line += PROGRESS_S
    finally:
        executor.shutdown()
        writer.destroy_node()
        reader.destroy_node()
        rclpy.try_shutdown(context=ctx)
    return {"executor": kind, "subscriptions": n, "lost": lost, "in_reader": in_reader, "slow": slow}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=20000, help="new subscriptions per executor (default 20000)")
    ap.add_argument("--wait", type=float, default=0.5, help="seconds to wait for a sample (default 0.5)")
    ap.add_argument("--executors", default=",".join(EXECUTORS), help="comma-separated: events, single")
    ap.add_argument("--domain", type=int, default=None,
                    help="ROS_DOMAIN_ID (default: the environment's, else random in 40..99)")
    args = ap.parse_args()
    kinds = args.executors.split(",")
    if args.n < 1 or args.wait <= 0 or not set(kinds) <= set(EXECUTORS):
        ap.error(f"-n >= 1, --wait > 0, executors from {', '.join(EXECUTORS)}")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    domain = run_domain(args.domain, BENCH_DOMAINS)
    print("executor  subscriptions  lost  of which in the reader  over 100 ms")
    for kind in kinds:
        r = measure(kind, args.n, args.wait, domain)
        print(f"{r['executor']:<9} {r['subscriptions']:>13} {r['lost']:>5} {r['in_reader']:>23} {r['slow']:>12}",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

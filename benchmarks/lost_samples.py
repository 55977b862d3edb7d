#!/usr/bin/env python3
"""What the middleware reports of a flood: messages a slow reader's queue evicted against the samples its
message-lost event counts.

A writer process floods `-n` messages on one topic (std_msgs/Int32MultiArray of `--size` ints, as fast as
rclpy publishes); a reader in this process keeps `--depth` of them (KEEP_LAST) and takes each with a
callback that sleeps `--work` seconds, standing for a node busy with other work; it listens to the
subscription's message-lost event (rclpy's SubscriptionEventCallbacks(message_lost=...)). Printed per
reliability: delivered, not delivered, and the total the event reported. With the pip Fast DDS of ROS 2 Jazzy
the event reports nothing for messages that a KEEP_LAST queue (the writer's or the reader's) replaced, which is
all a flood loses on one host, so the nodes count the real messages lost by their own sequence checks
(docs/faults.md: `missed_feedback`, `caught_up`, `missed_actions`, `dropped.*`), not by this event.

    python benchmarks/lost_samples.py [-n 5000] [--depth 5] [--work 0.001]

Isolation: ROS_DOMAIN_ID from the environment, else a random one in 40..99, discovery on this host; every wait is
bounded.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time

from ros_tools.launch import BENCH_DOMAINS, run_domain

TOPIC = "flood"
DISCOVERY_TIMEOUT_S = 20.0


def qos(reliability: str, depth: int):
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE if reliability == "reliable"
                      else ReliabilityPolicy.BEST_EFFORT)


def write(reliability: str, n: int, size: int, depth: int) -> None:
    """The writer process: wait for the reader, flood, linger so that a reliable writer can deliver."""
    import rclpy
    from std_msgs.msg import Int32MultiArray

    rclpy.init()
    node = rclpy.create_node("flood_writer")
    pub = node.create_publisher(Int32MultiArray, TOPIC, qos(reliability, depth))
    deadline = time.monotonic() + DISCOVERY_TIMEOUT_S
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    for i in range(n):
        pub.publish(Int32MultiArray(data=[i] * size))
    time.sleep(1.0)
    node.destroy_node()
    rclpy.shutdown()


def read(reliability: str, n: int, size: int, depth: int, work_s: float, domain: int) -> dict:
    import rclpy
    from rclpy.event_handler import SubscriptionEventCallbacks
    from std_msgs.msg import Int32MultiArray

    env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
    rclpy.init(domain_id=domain)
    node = rclpy.create_node("flood_reader")
    got, lost = [], [0]

    def take(msg) -> None:
        got.append(msg.data[0])
        time.sleep(work_s)

    events = SubscriptionEventCallbacks(message_lost=lambda info: lost.__setitem__(0, info.total_count))
    node.create_subscription(Int32MultiArray, TOPIC, take, qos(reliability, depth), event_callbacks=events)
    writer = subprocess.Popen([sys.executable, __file__, "--write", reliability, "-n", str(n), "--size", str(size),
                               "--depth", str(depth)], env=env)
    try:
        quiet_since = time.monotonic()
        deadline = quiet_since + DISCOVERY_TIMEOUT_S + n * (work_s + 0.001) + 10
        while time.monotonic() < deadline:
            before = len(got)
            rclpy.spin_once(node, timeout_sec=0.1)
            if len(got) != before:
                quiet_since = time.monotonic()
            elif got and writer.poll() is not None and time.monotonic() - quiet_since > 1.0:
                break
    finally:
        if writer.poll() is None:
            writer.kill()
        writer.wait(timeout=10)
        node.destroy_node()
        rclpy.shutdown()
    return {"reliability": reliability, "sent": n, "delivered": len(got), "lost_event_total": lost[0]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=5000, help="messages in the flood (default 5000)")
    ap.add_argument("--size", type=int, default=8, help="ints a message (default 8, a keyed action's size)")
    ap.add_argument("--depth", type=int, default=5, help="KEEP_LAST depth of writer and reader (default 5)")
    ap.add_argument("--work", type=float, default=0.001, help="seconds the reader spends a message (default 0.001)")
    ap.add_argument("--write", choices=("reliable", "best_effort"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.n < 1 or args.size < 1 or args.depth < 1 or args.work < 0:
        ap.error("-n, --size and --depth must be at least 1, --work at least 0")
    if args.write:
        write(args.write, args.n, args.size, args.depth)
        return 0
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    domain = run_domain(None, BENCH_DOMAINS)
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}")
    print(f"flood of {args.n} messages, KEEP_LAST {args.depth}, reader busy {args.work * 1e3:g} ms a message")
    print("reliability   delivered  not delivered  message-lost event total")
    for reliability in ("reliable", "best_effort"):
        print(f"lost_samples: flooding ({reliability})", file=sys.stderr, flush=True)
        r = read(reliability, args.n, args.size, args.depth, args.work, domain)
        print(f"{r['reliability']:<13} {r['delivered']:>9} {r['sent'] - r['delivered']:>14} "
              f"{r['lost_event_total']:>25}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

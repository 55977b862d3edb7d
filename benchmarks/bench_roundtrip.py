#!/usr/bin/env python3
"""rclpy round trip between two processes on this machine: the floor under one lockstep step.

A ping process (this one) and an echo process (this file, started with `sys.executable`) exchange
back-to-back messages after discovery: ping publishes on `bench/<type>/<qos>/ping`, echo republishes
the same message on `.../pong`, ping waits for it (bounded) before sending the next. Reported per
(message type, QoS): median, p90, p99, min, max in ms, and pings lost (best effort may lose some).

    python benchmarks/bench_roundtrip.py                       # 2000 pings, our position type, both QoS
    python benchmarks/bench_roundtrip.py -n 5000 --types position,point_stamped --json
    python benchmarks/bench_roundtrip.py --stack nodes          # as the nodes talk: EventsExecutor, raw bytes

Other benchmarks call `measure_roundtrip(n=2000) -> dict` (it runs in its own rclpy Context, so it
does not disturb an rclpy already initialised in the caller).

Isolation: --domain, else the environment's ROS_DOMAIN_ID, else a random one in 40..99,
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, ROS_LOG_DIR in a temporary directory; every wait is bounded.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from ros_tools.launch import BENCH_DOMAINS, run_domain

QOS_NAMES = ("reliable", "best_effort")
TYPE_NAMES = ("position", "point_stamped")
# How both ends talk: `message`, rclpy's SingleThreadedExecutor with message objects; `nodes`, as the cq_ros
# nodes do (EventsExecutor, our position published as serialized bytes and read by raw subscriptions).
STACKS = ("message", "nodes")


def _executor(stack: str, context=None):
    """The executor the stack spins: the nodes' own choice (node_runtime.run.make_executor) or rclpy's default."""
    from node_runtime.run import make_executor
    return make_executor("events" if stack == "nodes" else "single", context)


def _qos(name: str):
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    rel = {"reliable": ReliabilityPolicy.RELIABLE, "best_effort": ReliabilityPolicy.BEST_EFFORT}[name]
    return QoSProfile(reliability=rel, durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST,
                      depth=10)


def _msg_type(name: str):
    if name == "position":
        from msgs_spec import POSITION
        return POSITION.msg_type
    from geometry_msgs.msg import PointStamped
    return PointStamped


def _make(type_name: str, seq: int, raw: bool = False):
    """A ping carrying `seq`: our real position payload (`raw`: serialized, as the nodes publish it), or a
    PointStamped as in docs/design.md's field notes."""
    if type_name == "position":
        from msgs_spec import Position, encode_position, serialize
        position = Position(agent=1, episode=0, step=seq, row=2, col=3)
        return serialize(position) if raw else encode_position(position)
    from geometry_msgs.msg import PointStamped
    m = PointStamped()
    m.header.frame_id = "grid"
    m.point.x, m.point.y = float(seq), 2.0
    return m


def _seq(type_name: str, msg) -> int:
    if type(msg) is bytes:
        from msgs_spec import decode_position
        return decode_position(msg).step
    return int(msg.data[2]) if type_name == "position" else int(msg.point.x)


def _topics(type_name: str, qos_name: str) -> tuple[str, str]:
    base = f"bench/{type_name}/{qos_name}"
    return f"{base}/ping", f"{base}/pong"


# --------------------------------------------------------------------------------------------------------
# Echo process


def _echo_main(domain_id: int, pairs: list[tuple[str, str]], lifetime_s: float, stack: str = "message") -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException

    stop = threading.Event()

    def wait_stdin_eof() -> None:  # the parent closes our stdin to stop us (or dies, which closes it too)
        try:
            sys.stdin.buffer.read()
        finally:
            stop.set()

    reader = threading.Thread(target=wait_stdin_eof, daemon=True)
    rclpy.init(args=None, domain_id=domain_id)
    node = None
    ex = None
    try:
        node = rclpy.create_node("bench_echo")
        ex = _executor(stack)
        ex.add_node(node)
        for type_name, qos_name in pairs:
            ping, pong = _topics(type_name, qos_name)
            msg_type, qos = _msg_type(type_name), _qos(qos_name)
            pub = node.create_publisher(msg_type, pong, qos)
            node.create_subscription(msg_type, ping, lambda m, p=pub: p.publish(m), qos, raw=stack == "nodes")
        reader.start()
        print("ready", flush=True)
        deadline = time.monotonic() + lifetime_s
        while not stop.is_set() and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        stop.set()
        reader.join(timeout=0.1)  # daemon; it has returned if stdin reached EOF
        if ex is not None:
            ex.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


# --------------------------------------------------------------------------------------------------------
# Ping side


def _percentile(sorted_ms: list[float], q: float) -> float:
    import numpy as np
    return float(np.percentile(np.asarray(sorted_ms), q)) if sorted_ms else float("nan")


def measure_roundtrip(n: int = 2000, types: tuple[str, ...] = ("position",),
                      qos: tuple[str, ...] = QOS_NAMES, warmup: int = 200, domain_id: int | None = None,
                      ping_timeout_s: float = 1.0, discovery_timeout_s: float = 30.0,
                      stack: str = "message") -> dict[str, Any]:
    """Round trip ping -> echo process -> ping, `n` back-to-back pings per (type, QoS) after `warmup`, both
    ends talking as `stack` says (STACKS).

    Returns {"n", "domain_id", "discovery_s", "rmw", "rclpy", "python", "cpus", "machine",
             "pairs": {"<type>/<qos>": {"median_ms", "p90_ms", "p99_ms", "mean_ms", "min_ms", "max_ms",
                                        "lost", "n", "type", "qos"}},
             "reliable": <pairs entry of types[0]/reliable>, "best_effort": <... best_effort>}
    Raises RuntimeError if the echo process does not start or is not discovered in time.
    """
    import importlib.metadata

    import rclpy

    if stack not in STACKS:
        raise ValueError(f"stack {stack!r}: choose from {STACKS}")
    if stack == "nodes" and types != ("position",):
        raise ValueError("the nodes' stack carries our position message only")
    for t in types:
        if t not in TYPE_NAMES:
            raise ValueError(f"type {t!r}: choose from {TYPE_NAMES}")
    for q in qos:
        if q not in QOS_NAMES:
            raise ValueError(f"qos {q!r}: choose from {QOS_NAMES}")
    if domain_id is None:
        domain_id = run_domain(None, BENCH_DOMAINS)
    pairs = [(t, q) for t in types for q in qos]
    # the echo lives at most as long as a slow run could take, even if we die without closing its stdin
    lifetime = discovery_timeout_s + len(pairs) * (n + warmup) * 0.05 + 30.0

    from ros_tools.session import environment

    with tempfile.TemporaryDirectory(prefix="bench_rt_") as tmp, environment(
            ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_LOG_DIR=tmp):
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        cmd = [sys.executable, str(Path(__file__).resolve()), "--echo", "--domain", str(domain_id),
               "--types", ",".join(types), "--qos", ",".join(qos), "--lifetime", f"{lifetime:.0f}",
               "--stack", stack]
        err_path = Path(tmp) / "echo.stderr"
        t_start = time.monotonic()
        with open(err_path, "wb") as err:
            child = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=err, env=env)
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain_id)
        node = ex = None
        try:
            node = rclpy.create_node("bench_ping", context=ctx)
            ex = _executor(stack, ctx)
            ex.add_node(node)
            inbox: dict[tuple[str, str], list[int]] = {p: [] for p in pairs}
            ends = {}
            for t, q in pairs:
                ping, pong = _topics(t, q)
                pub = node.create_publisher(_msg_type(t), ping, _qos(q))
                sub = node.create_subscription(
                    _msg_type(t), pong, lambda m, key=(t, q): inbox[key].append(_seq(key[0], m)), _qos(q),
                    raw=stack == "nodes")
                ends[(t, q)] = (pub, sub)

            # discovery: every ping publisher matched by the echo's subscription, every pong subscription
            # matched by the echo's publisher
            deadline = time.monotonic() + discovery_timeout_s
            while any(p.get_subscription_count() < 1 or s.get_publisher_count() < 1 for p, s in ends.values()):
                if child.poll() is not None:
                    raise RuntimeError(f"echo process exited with {child.returncode}: "
                                       f"{err_path.read_text(errors='replace')[-2000:]}")
                if time.monotonic() > deadline:
                    raise RuntimeError(f"echo process not discovered within {discovery_timeout_s} s")
                ex.spin_once(timeout_sec=0.01)
            discovery_s = time.monotonic() - t_start

            results = {}
            for t, q in pairs:
                pub, _ = ends[(t, q)]
                box = inbox[(t, q)]
                rtts: list[float] = []
                lost = 0
                for i in range(warmup + n):
                    msg = _make(t, i, raw=stack == "nodes")
                    box.clear()
                    t0 = time.perf_counter_ns()
                    pub.publish(msg)
                    stop_at = time.monotonic() + ping_timeout_s
                    while i not in box:
                        left = stop_at - time.monotonic()
                        if left <= 0:
                            break
                        ex.spin_once(timeout_sec=left)
                    t1 = time.perf_counter_ns()
                    if i < warmup:
                        continue
                    if i in box:
                        rtts.append((t1 - t0) / 1e6)
                    else:
                        lost += 1
                        if child.poll() is not None:
                            raise RuntimeError(f"echo process died (exit {child.returncode})")
                rtts.sort()
                results[f"{t}/{q}"] = {
                    "type": f"{t} ({_msg_type(t).__module__.split('.')[0]}/msg/{_msg_type(t).__name__})",
                    "qos": q, "n": len(rtts), "lost": lost,
                    "median_ms": _percentile(rtts, 50), "p90_ms": _percentile(rtts, 90),
                    "p99_ms": _percentile(rtts, 99), "mean_ms": sum(rtts) / len(rtts) if rtts else float("nan"),
                    "min_ms": rtts[0] if rtts else float("nan"), "max_ms": rtts[-1] if rtts else float("nan"),
                }
        finally:
            # stop the echo first (close its stdin), bounded; then our own executor, node, context
            try:
                if child.stdin:
                    child.stdin.close()
                child.wait(timeout=10)
            except subprocess.TimeoutExpired:
                child.terminate()
                try:
                    child.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    child.kill()
                    child.wait(timeout=5)
            if child.stdout:
                child.stdout.close()
            if ex is not None:
                ex.shutdown()
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown(context=ctx)

    out: dict[str, Any] = {
        "n": n, "warmup": warmup, "domain_id": domain_id, "discovery_s": discovery_s, "stack": stack,
        "rmw": rclpy.utilities.get_rmw_implementation_identifier(),
        "rclpy": importlib.metadata.version("ros-jazzy-rclpy"), "python": platform.python_version(),
        "cpus": os.cpu_count(), "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "pairs": results,
    }
    for q in qos:
        out[q] = results[f"{types[0]}/{q}"]
    return out


def format_report(r: dict[str, Any]) -> str:
    lines = [f"rclpy {r['rclpy']} ({r['rmw']}), Python {r['python']}, {r['cpus']} CPUs, {r['machine']}; "
             f"domain {r['domain_id']}; {r['stack']} stack; echo process started and discovered in "
             f"{r['discovery_s']:.2f} s; "
             f"{r['n']} back-to-back pings per row after {r['warmup']} warm-up",
             f"{'message type':<48} {'QoS':<12} {'median ms':>9} {'p90 ms':>8} {'p99 ms':>8} {'min ms':>8} "
             f"{'max ms':>8} {'lost':>5}"]
    for v in r["pairs"].values():
        lines.append(f"{v['type']:<48} {v['qos']:<12} {v['median_ms']:>9.3f} {v['p90_ms']:>8.3f} "
                     f"{v['p99_ms']:>8.3f} {v['min_ms']:>8.3f} {v['max_ms']:>8.1f} {v['lost']:>5}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-n", type=int, default=2000, help="timed pings per (type, QoS) (default 2000)")
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--types", default="position", help=f"comma list of {', '.join(TYPE_NAMES)}")
    ap.add_argument("--qos", default=",".join(QOS_NAMES), help=f"comma list of {', '.join(QOS_NAMES)}")
    ap.add_argument("--domain", type=int, default=None,
                    help="ROS_DOMAIN_ID (default: the environment's, else random in 40..99)")
    ap.add_argument("--stack", choices=STACKS, default="message",
                    help="message: SingleThreadedExecutor, message objects (default); nodes: as the cq_ros nodes "
                         "talk (EventsExecutor, serialized bytes, raw subscriptions; position only)")
    ap.add_argument("--json", action="store_true", help="print the result dict as JSON too")
    ap.add_argument("--echo", action="store_true", help=argparse.SUPPRESS)  # the child role
    ap.add_argument("--lifetime", type=float, default=300.0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    types = tuple(t for t in args.types.split(",") if t)
    qos = tuple(q for q in args.qos.split(",") if q)
    if args.echo:
        return _echo_main(args.domain, [(t, q) for t in types for q in qos], args.lifetime, args.stack)
    r = measure_roundtrip(n=args.n, types=types, qos=qos, warmup=args.warmup, domain_id=args.domain,
                          stack=args.stack)
    print(format_report(r))
    if args.json:
        print(json.dumps(r, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

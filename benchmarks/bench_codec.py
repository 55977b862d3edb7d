#!/usr/bin/env python3
"""The wire contract's cost per message (msgs_spec.arrays, the one codec): CPU microseconds to serialize and to
decode (with every check and the run's sealed MAC) one keyed feedback, position, action and heartbeat as the
nodes do, and one MAC alone. Each figure is the fastest of --repeat timeit repeats on process_time (CPU, so
other sessions' load moves it less; the fastest, as timeit advises: load only ever adds, and the median of 5
moved by half between two runs a minute apart here).

    python benchmarks/bench_codec.py [--number 5000] [--repeat 25]
"""

from __future__ import annotations

import argparse
import os
import platform
import secrets
import time
import timeit

from msgs_spec import (
    ACTION_LAYOUT, FEEDBACK_LAYOUT, HEARTBEAT_LAYOUT, POSITION_LAYOUT, Action, Bounds, Feedback, Heartbeat, Position,
    decode_action, decode_feedback, decode_heartbeat, decode_position,
)
from msgs_spec.auth import WORLD, RunKey, mac_words


def cases() -> dict:
    """name -> a call, as a node makes it."""
    secret, bounds = secrets.token_bytes(32), Bounds(16, 20, 20)
    world, agent = RunKey(secret, run=12345), RunKey(secret, run=12345)
    fb, pos = Feedback(3, 5, 7, 2, 4, -1.0, False, False, 1), Position(3, 5, 7, 2, 4)
    act, hb = Action(3, 5, 7, 2), Heartbeat(9, 5, 7)
    raw = {Feedback: FEEDBACK_LAYOUT.serialize(fb, world), Position: POSITION_LAYOUT.serialize(pos, world),
           Heartbeat: HEARTBEAT_LAYOUT.serialize(hb, world), Action: ACTION_LAYOUT.serialize(act, agent)}
    agent.accept(12345, world.incarnation, WORLD)  # bound, as after the world's first message
    world.accept(12345, agent.incarnation, 3)
    expect = {"bounds": bounds, "agent": 3, "episode": 5, "step": 7}
    return {
        "serialize feedback": lambda: FEEDBACK_LAYOUT.serialize(fb, world),
        "serialize position": lambda: POSITION_LAYOUT.serialize(pos, world),
        "serialize action": lambda: ACTION_LAYOUT.serialize(act, agent),
        "serialize heartbeat": lambda: HEARTBEAT_LAYOUT.serialize(hb, world),
        "decode feedback": lambda: decode_feedback(raw[Feedback], **expect, key=agent),
        "decode position": lambda: decode_position(raw[Position], **expect, key=agent),
        "decode action": lambda: decode_action(raw[Action], **expect, key=world),
        # the values and the seal without a payload object (the world node's read: world_node.wire_reading)
        "decode action's value": lambda: ACTION_LAYOUT.read(raw[Action], bounds, 3, key=world)[0][3],
        "decode heartbeat": lambda: decode_heartbeat(raw[Heartbeat], key=agent),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--number", type=int, default=5000, help="calls per repeat")
    parser.add_argument("--repeat", type=int, default=25, help="repeats; the fastest is printed")
    args = parser.parse_args()
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}")
    print(f"fastest of {args.repeat} repeats of {args.number} calls, us CPU per call")

    def fastest(call) -> float:
        return min(timeit.repeat(call, number=args.number, repeat=args.repeat,
                                 timer=time.process_time)) / args.number * 1e6

    for name, call in cases().items():
        print(f"{name:<22}{fastest(call):8.2f}", flush=True)
    secret = secrets.token_bytes(32)
    print(f"{'MAC alone':<22}{fastest(lambda: mac_words(secret, 'agent,episode,step,action', bytes(28))):8.2f}")
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()

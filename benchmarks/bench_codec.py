#!/usr/bin/env python3
"""The wire contract's cost per message, for the fast codec the nodes call (msgs_spec.fast) and the reference
codec (msgs_spec.arrays) from one run: CPU microseconds to serialize and to decode (with every check and the
run's sealed MAC) one keyed feedback, position, action and heartbeat as the nodes do, and one MAC alone. Each
figure is the fastest of --repeat timeit repeats on process_time (CPU, so other sessions' load moves it less;
the fastest, as timeit advises: load only ever adds, and the median of 5 moved by half between two runs a minute
apart here).

    python benchmarks/bench_codec.py [--number 5000] [--repeat 25]
"""

from __future__ import annotations

import argparse
import os
import platform
import secrets
import time
import timeit

from msgs_spec import Action, Bounds, Feedback, Heartbeat, Position
from msgs_spec import arrays as reference
from msgs_spec import fast
from msgs_spec.auth import WORLD, RunKey, mac_words


def cases(codec) -> dict:
    """name -> a call, for one codec module (both have serialize_array and the four decoders)."""
    secret, bounds = secrets.token_bytes(32), Bounds(16, 20, 20)
    world, agent = RunKey(secret, run=12345), RunKey(secret, run=12345)
    fb, pos = Feedback(3, 5, 7, 2, 4, -1.0, False, False, 1), Position(3, 5, 7, 2, 4)
    act, hb = Action(3, 5, 7, 2), Heartbeat(9, 5, 7)
    lay = reference.LAYOUT_BY_PAYLOAD
    raw = {type(p): reference.serialize_array(lay[type(p)], p, world) for p in (fb, pos, hb)}
    raw[Action] = reference.serialize_array(lay[Action], act, agent)
    agent.accept(12345, world.incarnation, WORLD)  # bound, as after the world's first message
    world.accept(12345, agent.incarnation, 3)
    expect = {"bounds": bounds, "agent": 3, "episode": 5, "step": 7}
    return {
        "serialize feedback": lambda: codec.serialize_array(lay[Feedback], fb, world),
        "serialize position": lambda: codec.serialize_array(lay[Position], pos, world),
        "serialize action": lambda: codec.serialize_array(lay[Action], act, agent),
        "serialize heartbeat": lambda: codec.serialize_array(lay[Heartbeat], hb, world),
        "decode feedback": lambda: codec.decode_feedback(raw[Feedback], **expect, key=agent),
        "decode position": lambda: codec.decode_position(raw[Position], **expect, key=agent),
        "decode action": lambda: codec.decode_action(raw[Action], **expect, key=world),
        # the world keeps the action alone (msgs_spec.fast.action_of; the reference has no such call)
        "decode action's value": (lambda: codec.action_of(raw[Action], **expect, key=world)) if codec is fast else
        (lambda: codec.decode_action(raw[Action], **expect, key=world).action),
        "decode heartbeat": lambda: codec.decode_heartbeat(raw[Heartbeat], after=8, key=agent),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--number", type=int, default=5000, help="calls per repeat")
    parser.add_argument("--repeat", type=int, default=25, help="repeats; the fastest is printed")
    args = parser.parse_args()
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}")
    print(f"fastest of {args.repeat} repeats of {args.number} calls, us CPU per call")
    print(f"{'call':<22}{'fast':>8}{'reference':>11}{'ratio':>8}")
    ours, theirs = cases(fast), cases(reference)

    def fastest(call) -> float:
        return min(timeit.repeat(call, number=args.number, repeat=args.repeat,
                                 timer=time.process_time)) / args.number * 1e6

    for name in ours:
        f, r = fastest(ours[name]), fastest(theirs[name])
        print(f"{name:<22}{f:8.2f}{r:11.2f}{r / f:7.1f}x", flush=True)
    secret = secrets.token_bytes(32)
    print(f"{'MAC alone':<22}{fastest(lambda: mac_words(secret, 'agent,episode,step,action', bytes(28))):8.2f}")
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""The wire contract's cost per message: CPU microseconds to serialize and to decode (with every check and the
run's MAC) one keyed feedback, position and action as the nodes do, and one MAC alone; the best of five
timeit repeats on process_time (CPU, so other sessions' load moves it less).

    python benchmarks/bench_codec.py [--number 20000]
"""

from __future__ import annotations

import argparse
import os
import secrets
import time
import timeit

from msgs_spec import Action, Bounds, Feedback, Position, decode_action, decode_feedback, decode_position, serialize
from msgs_spec.auth import mac_words


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--number", type=int, default=20000, help="calls per repeat")
    args = parser.parse_args()
    key, bounds = secrets.token_bytes(32), Bounds(16, 20, 20)
    fb, pos, act = Feedback(3, 5, 7, 2, 4, -1.0, False, False), Position(3, 5, 7, 2, 4), Action(3, 5, 7, 2)
    raw = {p: serialize(p, key=key) for p in (fb, pos, act)}
    expect = {"bounds": bounds, "agent": 3, "episode": 5, "step": 7, "key": key}
    cases = {"serialize feedback": lambda: serialize(fb, key=key),
             "serialize position": lambda: serialize(pos, key=key),
             "serialize action": lambda: serialize(act, key=key),
             "decode feedback": lambda: decode_feedback(raw[fb], **expect),
             "decode position": lambda: decode_position(raw[pos], **expect),
             "decode action": lambda: decode_action(raw[act], **expect),
             "MAC alone": lambda: mac_words(key, "agent,episode,step,action", bytes(16))}
    print(f"load average {os.getloadavg()[0]:.2f}")
    for name, call in cases.items():
        best = min(timeit.repeat(call, number=args.number, repeat=5, timer=time.process_time)) / args.number
        print(f"{name:<20} {best * 1e6:6.2f} us CPU", flush=True)
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()

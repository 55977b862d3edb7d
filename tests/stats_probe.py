"""Test helper, run as a process (on a network-namespace host): print every WorldStats of a run's namespace
as one JSON line, until `episodes` were heard or `timeout` seconds passed."""

import json
import sys

from msgs_spec import WORLD_STATS, WORLD_STATS_TOPIC, decode_world_stats
from msgs_spec.tools import ros_session, spin_until


def main(namespace: str, episodes: int, timeout: float) -> int:
    heard = set()

    def on_stats(msg):
        s = decode_world_stats(msg)
        if s.episode not in heard:
            heard.add(s.episode)
            print(json.dumps({"episode": s.episode, "steps": s.steps, "collisions": s.collisions,
                              "truncated": s.truncated, "missed_actions": s.missed_actions}), flush=True)

    with ros_session("stats_probe", namespace=namespace) as (node, executor):
        node.create_subscription(WORLD_STATS.msg_type, WORLD_STATS_TOPIC, on_stats, WORLD_STATS.qos)
        return 0 if spin_until(executor, lambda: len(heard) >= episodes, timeout) else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], int(sys.argv[2]), float(sys.argv[3])))

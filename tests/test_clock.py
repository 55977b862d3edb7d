"""Time as a ROS user reads it: statistics' headers are stamped from the publishing node's clock, use_sim_time is
refused in one line naming it (docs/ros.md says why), and what docs/ros.md says statistics keep for a late
subscriber is what their QoS keeps."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rclpy.qos import DurabilityPolicy

from helpers import finish
from msgs_spec import AGENT_STATS, WORLD_STATS, WORLD_STATS_TOPIC, agent_stats_topic
from node_runtime.qos import profile

ROOT = Path(__file__).resolve().parent.parent


def test_statistics_are_stamped_with_the_nodes_clock(system_in, ros_context, spin_until):
    import rclpy

    before = time.time_ns()
    system = system_in("indep", "grid_game_2", 0, 3, {"eval_episodes": 1})
    stamps: dict[str, list[int]] = {"world": [], "agv1": [], "agv2": []}
    stamp = lambda m: m.header.stamp.sec * 10**9 + m.header.stamp.nanosec  # noqa: E731
    probe = system.add(rclpy.create_node("stamps", context=ros_context))
    probe.create_subscription(WORLD_STATS.msg_type, WORLD_STATS_TOPIC, lambda m: stamps["world"].append(stamp(m)),
                              profile(WORLD_STATS.qos))
    for k in (1, 2):
        probe.create_subscription(AGENT_STATS.msg_type, agent_stats_topic(k),
                                  lambda m, k=k: stamps[f"agv{k}"].append(stamp(m)), profile(AGENT_STATS.qos))
    finish(system)
    after = time.time_ns()
    assert spin_until(system.executor, lambda: all(len(got) >= 4 for got in stamps.values()), 30.0), stamps
    for who, got in stamps.items():  # 3 learning episodes and 1 greedy, each stamped when it was sent
        assert len(got) == 4 and got == sorted(got) and before <= got[0] and got[-1] <= after, (who, got)


@pytest.mark.ros
@pytest.mark.parametrize("program, given", [("world_node", []), ("agent_node", ["-p", "agent_id:=1"])])
def test_use_sim_time_is_refused_in_one_line_naming_it(program, given):
    done = subprocess.run([sys.executable, "-m", program, "--ros-args", "-p", "map:=grid_game_2", *given, "-p",
                           "use_sim_time:=true"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{program}: parameter use_sim_time: true is refused"), lines


def test_the_docs_say_what_statistics_keep_for_a_late_subscriber():
    ros_md = " ".join((ROOT / "docs" / "ros.md").read_text().split())
    said = re.search(r"Statistics are kept for late subscribers: each writer keeps its last ([\d,]+) episodes",
                     ros_md)
    assert said and int(said.group(1).replace(",", "")) == WORLD_STATS.qos.depth == AGENT_STATS.qos.depth
    assert (profile(WORLD_STATS.qos).durability == profile(AGENT_STATS.qos).durability
            == DurabilityPolicy.TRANSIENT_LOCAL)

"""Several hosts for real: the world and each AGV in a network namespace of its own, on one bridge, with
addresses from 198.18.0.0/15 (world_node.hosts). Discovery over the subnet and, separately, by unicast to
ROS_STATIC_PEERS only: the run equals the offline engine's. One AGV's cable out for 2 s: the run finishes
with the misses counted. One AGV's host cut for good: the world plays on without it, as it does for a lost
agent, the agent gives up, and what was written before is intact. Every namespace is removed, even when a
test fails; the tests skip, with the reason, where root or `ip` is missing."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from test_faults import CASE, offline_steps_and_collisions
from world_node.hosts import Hosts, available

pytestmark = pytest.mark.skipif(available() is not None, reason=f"network namespaces: {available()}")

PROBE = str(Path(__file__).with_name("stats_probe.py"))
LEARN = (CASE[0], CASE[1], (*CASE[2], ("eval_episodes", 0)))  # learning episodes only: the probe counts them
NS = "/hosts"
WAIT_S = 120.0


def settings_args(settings) -> list[str]:
    return [a for k, v in settings for a in ("-p", f"{k}:={float(v) if isinstance(v, float) else v}")]


class System:
    """A world, two CQ agents and a statistics probe, each on its own host, started as processes."""

    def __init__(self, hosts: Hosts, env: dict, episodes: int, settings, tmp: Path, world=(), agent=()):
        common = ["-p", f"map:={LEARN[0]}", "-p", f"seed:={LEARN[1]}", "-p", f"episodes:={episodes}",
                  *settings_args(settings)]
        ros = ["--ros-args", "-r", f"__ns:={NS}"]
        self.logs = tmp
        self.heard: list[dict] = []
        self.processes = {
            "world": self._start(hosts, "world", [sys.executable, "-m", "world_node", *ros, *common,
                                                  "-p", "min_stats_subscribers:=1", *world], env),
            "probe": self._start(hosts, "probe", [sys.executable, PROBE, NS, str(episodes), str(WAIT_S)], env),
        }
        for k in (1, 2):
            self.processes[f"agv{k}"] = self._start(hosts, f"agv{k}", [
                sys.executable, "-m", "agent_node", *ros, "-r", f"__node:=agv{k}", *common, "-p", "algo:=cq",
                "-p", f"agent_id:={k}", *agent], env)

    def _start(self, hosts, name, argv, env):
        with open(self.logs / f"{name}.log", "wb") as log:
            return subprocess.Popen(hosts.command(name, argv), env=env, stdout=subprocess.PIPE if name == "probe"
                                    else log, stderr=log)

    def heard_episode(self, episode: int) -> None:
        """Read the probe's lines until `episode` has ended."""
        deadline = time.monotonic() + WAIT_S
        while not self.heard or self.heard[-1]["episode"] < episode:
            line = self.processes["probe"].stdout.readline()
            assert line and time.monotonic() < deadline, "the probe stopped before that episode"
            self.heard.append(json.loads(line))

    def episodes_heard(self) -> list[dict]:
        out = self.processes["probe"].communicate(timeout=WAIT_S)[0]
        return self.heard + [json.loads(line) for line in out.decode().splitlines()]

    def wait(self, name: str) -> int:
        return self.processes[name].wait(timeout=WAIT_S)

    def kill(self) -> None:
        for p in self.processes.values():
            if p.poll() is None:
                p.kill()
                p.wait(timeout=30)


@pytest.fixture
def hosts():
    with Hosts(["world", "agv1", "agv2", "probe"]) as h:
        yield h
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    assert h.prefix not in listed  # nothing left behind


@pytest.fixture
def system(hosts, tmp_path):
    started = []

    def start(env_extra, *args, **kwargs) -> System:
        env = {**os.environ, "ROS_LOG_DIR": str(tmp_path), **env_extra}
        if "ROS_STATIC_PEERS" not in env_extra:
            env.pop("ROS_STATIC_PEERS", None)
        started.append(System(hosts, env, *args, tmp=tmp_path, **kwargs))
        return started[-1]

    yield start
    for s in started:
        s.kill()


def log(tmp_path: Path, name: str) -> str:
    return (tmp_path / f"{name}.log").read_text(errors="replace")


@pytest.mark.parametrize("discovery", ["subnet", "static_peers"])
def test_a_run_across_hosts_equals_the_offline_one(hosts, system, tmp_path, discovery):
    env = ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"} if discovery == "subnet" else
           {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_STATIC_PEERS": ";".join(hosts.addresses.values())})
    episodes = 8
    run = system(env, episodes, LEARN[2])
    heard = run.episodes_heard()
    assert [run.wait(n) for n in ("world", "agv1", "agv2")] == [0, 0, 0], log(tmp_path, "world")
    offline = offline_steps_and_collisions("cq", LEARN, episodes)
    assert [(e["steps"], e["collisions"], e["truncated"]) for e in heard] == offline
    assert all(e["missed_actions"] == 0 for e in heard)


def test_a_link_down_for_2_s_costs_missed_steps_and_the_run_finishes(hosts, system, tmp_path):
    episodes = 40
    run = system({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}, episodes, LEARN[2],
                 world=["-p", "step_timeout:=0.5"], agent=["-p", "feedback_timeout:=20.0"])
    run.heard_episode(2)
    hosts.link("agv1", up=False)
    time.sleep(2.0)
    hosts.link("agv1", up=True)
    heard = run.episodes_heard()
    assert [run.wait(n) for n in ("world", "agv1", "agv2")] == [0, 0, 0], log(tmp_path, "agv1")
    assert [e["episode"] for e in heard] == list(range(episodes))
    assert sum(e["missed_actions"] for e in heard) >= 1, "the cable was out for 2 s: the world missed agv1"


def test_a_host_cut_for_good_loses_its_agent_and_the_world_plays_on(hosts, system, tmp_path):
    episodes = 8
    settings = (*LEARN[2], ("step_cap", 20))
    run = system({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}, episodes, settings,
                 world=["-p", "step_timeout:=0.2"], agent=["-p", "feedback_timeout:=3.0"])
    run.heard_episode(2)
    hosts.link("agv2", up=False)
    assert run.wait("agv2") == 1 and "giving up" in log(tmp_path, "agv2")
    heard = run.episodes_heard()
    assert run.wait("world") == 0 and run.wait("agv1") == 0
    assert [e["episode"] for e in heard] == list(range(episodes))
    offline = offline_steps_and_collisions("cq", (*LEARN[:2], settings), episodes)
    cut = next(i for i, e in enumerate(heard) if e["missed_actions"])
    assert [(e["steps"], e["collisions"], e["truncated"]) for e in heard[:cut]] == offline[:cut]
    assert all(e["missed_actions"] > 0 for e in heard[cut + 1:])  # agv2 never came back

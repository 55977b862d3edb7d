"""A launch's start on a big fleet: the start-up waits grow with the number of nodes (a busy 2-core machine starts
warehouse_32's 33 processes in tens of seconds), an agent process whose start is stuck is started again, and the
progress says where the run is from its first step (benchmarks/bench_startup.py measures the start)."""

from __future__ import annotations

import signal
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

import ros_tools.launch_watch as launch_watch
import ros_tools.progress as progress
from cq_ros.gridmap import load_map
from cq_ros.settings import run_settings
from helpers import alive_with, unique, wait_until
from node_runtime.parameters import AGENT_PARAMETERS
from ros_tools.children import Child
from ros_tools.launch import launch
from ros_tools.launch_nodes import STARTUP_TIMEOUT_S, node_specs, startup_wait
from ros_tools.progress import Progress


def _specs(map_name: str, tmp_path: Path, **node_parameters):
    return node_specs(map_name, "cq", 1, 0, run_settings(load_map(map_name)), tmp_path, 2.0,
                      node_parameters=node_parameters)


def test_start_up_waits_grow_with_the_fleet_and_stay_as_they_were_on_a_small_one(tmp_path):
    small, big = _specs("grid_game_2", tmp_path), _specs("warehouse_32", tmp_path)
    assert small["world"][1]["startup_timeout"] == STARTUP_TIMEOUT_S
    assert "feedback_timeout" not in small["agv1"][1]  # the agent's own default, 30 s
    wait = big["world"][1]["startup_timeout"]
    assert wait == startup_wait(33) > AGENT_PARAMETERS["feedback_timeout"][0] >= STARTUP_TIMEOUT_S
    assert {spec[1]["feedback_timeout"] for name, spec in big.items() if name != "world"} == {wait}
    given = _specs("warehouse_32", tmp_path, feedback_timeout=7.0)  # --set feedback_timeout=7 wins
    assert given["agv32"][1]["feedback_timeout"] == 7.0


def test_an_agent_that_said_nothing_in_its_start_is_started_again_twice_at_most(tmp_path, monkeypatch):
    monkeypatch.setattr(launch_watch, "NODE_UP_S", 0.0)
    sleeper = [sys.executable, "-c", "import time; time.sleep(60)"]
    talker = [sys.executable, "-c", "import time; print('up', flush=True); time.sleep(60)"]
    children = [Child(name, command, tmp_path / f"{name}.log")
                for name, command in (("world", sleeper), ("agv1", sleeper), ("agv2", talker))]
    waiting = SimpleNamespace(world={}, at=None)  # no step yet
    try:
        for child in children:
            child.start({})
        world_pid, talker_pid = children[0].process.pid, children[2].process.pid
        wait_until(children[2].said_anything, 30.0, "agv2's first line")
        pids = []
        for _ in range(3):
            pids.append(children[1].process.pid)
            launch_watch._unstick(children, {}, waiting)
        assert children[1].stuck_starts == 2 and len(set(pids)) == 3 and children[1].running
        assert children[0].process.pid == world_pid and children[2].process.pid == talker_pid  # left alone
        launch_watch._unstick(children, {}, SimpleNamespace(world={0: object()}, at=(1, 0)))  # stepping: no more
        assert children[1].stuck_starts == 2
    finally:
        for child in children:
            if child.running:
                child.signal_group(signal.SIGKILL)
                child.process.wait(timeout=10)


def test_between_episodes_the_progress_says_where_the_run_is(capsys, monkeypatch):
    monkeypatch.setattr(progress, "STATUS_S", 0.0)
    bar = Progress("warehouse_32 cq", 21, 1, True)
    bar.within(lambda: "starting: 12/33 nodes up")
    bar.within(lambda: "episode 0, step 40")
    assert capsys.readouterr().err.splitlines() == ["warehouse_32 cq: starting: 12/33 nodes up",
                                                    "warehouse_32 cq: episode 0, step 40"]


@pytest.mark.ros
@pytest.mark.slow
def test_a_launch_shows_its_start_and_its_steps_before_its_first_episode_ends(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(progress, "STATUS_S", 0.2)
    namespace = unique("progress")
    # One long first episode (agents that know nothing wander tunnel_to_goal: 1,144 steps at seed 3), and the
    # world's heartbeat, which says where it is, every 0.1 s.
    launch("tunnel_to_goal", "indep", 1, 3, tmp_path / "out", run_settings(load_map("tunnel_to_goal"),
           ["eval_episodes=0"]), namespace=namespace, figures=False, node_parameters={"heartbeat_period": 0.1})
    err = capsys.readouterr().err
    assert "tunnel_to_goal indep: starting: " in err and " nodes up" in err
    steps = [int(line.rsplit("step ", 1)[1]) for line in err.splitlines()
             if line.startswith("tunnel_to_goal indep: episode 0, step ")]
    assert steps and max(steps) > 0, err
    assert not alive_with(namespace)

"""Composed mode: the world and every agent node in one process on one EventsExecutor (ros_tools.compose, as
`cq-ros launch --compose` runs it, each node reading its parameters under its own name from the params file)
give exactly the offline engine's episodes for all five algorithms' kinds of node on two maps; the launch
writes the same results as a process per node; a bad parameter, a bad node name and Ctrl-C end it cleanly."""

from __future__ import annotations

import csv
import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rclpy.context import Context

from cq_ros.engine import run
from cq_ros.gridmap import load_map
from cq_ros.settings import Settings, run_settings
from cq_ros.mapgen.warehouse import warehouse_text
from msgs_spec import AGENT_STATS, WORLD_STATS, WORLD_STATS_TOPIC, agent_stats_topic, decode_agent_stats, \
    decode_world_stats
from node_runtime.qos import profile
from node_runtime.run import make_executor, spin_nodes
from helpers import SEED, alive_with, launch_command, ours_without, run_as, spin_until, unique, wait_for_line
from ros_tools.compose import make_nodes
from ros_tools.launch_nodes import compose_command, node_specs

RUN_TIMEOUT_S = 60.0  # a bound for one composed run; each below takes a second or two
# Short runs: on grid_game_2 CQ marks joint states (and so subscribes to its peer) within 30 episodes;
# tunnel_to_goal's early episodes run to the step cap. A greedy episode or two after the learning ones.
CASES = {"grid_game_2": (30, {"window": 5, "eval_episodes": 2}),
         "tunnel_to_goal": (6, {"step_cap": 100, "eval_episodes": 1})}
ALGOS = ("cq", "js", "loc", "jsa", "indep")


def composed_run(map_name: str, algo: str, tmp_path: Path, domain_id: int) -> tuple[list, dict]:
    """Run the nodes of a launch of (map, algo) composed in this process, as the container does; return
    (WorldStats by episode, {agent: AgentStats by episode}) heard by a probe node beside them."""
    episodes, overrides = CASES[map_name]
    nodes = node_specs(map_name, algo, episodes, SEED, Settings().with_overrides(overrides), tmp_path,
                       step_timeout=30.0)
    (tmp_path / "checkpoints").mkdir()
    command = compose_command(nodes, "composed", tmp_path).command
    ctx = Context()  # the container's arguments: its namespace and the params file with every node's parameters
    rclpy.init(context=ctx, domain_id=domain_id, args=["container", *command[command.index("--ros-args"):]])
    n = load_map(map_name).n_agents
    world_stats, agent_stats = [], {k: [] for k in range(1, n + 1)}
    probe = rclpy.create_node("probe", context=ctx)
    probe.create_subscription(WORLD_STATS.msg_type, WORLD_STATS_TOPIC,
                              lambda m: world_stats.append(decode_world_stats(m)), profile(WORLD_STATS.qos))
    for k in agent_stats:
        probe.create_subscription(AGENT_STATS.msg_type, agent_stats_topic(k),
                                  lambda m, k=k: agent_stats[k].append(decode_agent_stats(m)), profile(AGENT_STATS.qos))
    executor = make_executor("events", ctx)
    composed = []
    try:
        composed = make_nodes(list(nodes), context=ctx)
        for node in (*composed, probe):
            executor.add_node(node)
        deadline = time.monotonic() + RUN_TIMEOUT_S
        assert spin_nodes(executor, composed, lambda: time.monotonic() > deadline) == 0
        total = episodes + overrides["eval_episodes"]
        spin_until(executor, lambda: min(len(world_stats), *map(len, agent_stats.values())) >= total, 30.0)
    finally:
        executor.shutdown()
        for node in (*composed, probe):
            node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    return world_stats, agent_stats


@pytest.mark.parametrize("map_name", list(CASES))
@pytest.mark.parametrize("algo", ALGOS)
@pytest.mark.slow
def test_composed_nodes_give_exactly_the_offline_engines_episodes(map_name, algo, tmp_path, ros_domain_id):
    episodes, overrides = CASES[map_name]
    world_stats, agent_stats = composed_run(map_name, algo, tmp_path, ros_domain_id)
    offline = run(algo, load_map(map_name), Settings().with_overrides(overrides), SEED, 0, episodes)
    table = np.concatenate([offline.episodes, offline.greedy])
    assert [(s.episode, s.steps, s.collisions, s.truncated) for s in world_stats] == \
        [(e, int(r["steps"]), int(r["collisions"]), bool(r["truncated"])) for e, r in enumerate(table)]
    assert all(s.missed_actions == 0 and not s.counters for s in world_stats)
    reporters = [1] if algo == "jsa" else list(agent_stats)  # the central node reports alike on every agv<k>
    assert all(len(agent_stats[k]) == len(table) for k in agent_stats)
    assert [(sum(agent_stats[k][e].joint_plays for k in reporters),
             sum(agent_stats[k][e].local_states + agent_stats[k][e].joint_states for k in reporters),
             sum(agent_stats[k][e].heard for k in reporters))
            for e in range(len(table))] == [(int(r["joint_plays"]), int(r["states"]), int(r["heard"])) for r in table]
    if (map_name, algo) == ("grid_game_2", "cq"):  # its peer subscriptions come and go under this executor
        assert all(agent_stats[k][-1].subscriptions_created > 0 for k in agent_stats)


def composed_launch(out: Path, namespace: str, episodes: int, *extra: str) -> list[str]:
    return launch_command(out, namespace, "grid_game_2", "cq", episodes, ("window=5",), "--compose", *extra)


@pytest.mark.ros
@pytest.mark.slow
def test_a_composed_launch_writes_the_offline_engines_episodes_from_one_process(tmp_path):
    out, namespace = tmp_path / "result", unique("composed")
    done = subprocess.run(composed_launch(out, namespace, 30, "--set", "eval_episodes=2", "--no-figures"),
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert not alive_with(namespace)
    offline = run("cq", load_map("grid_game_2"), Settings().with_overrides({"window": 5, "eval_episodes": 2}),
                  SEED, 0, 30)
    with open(out / "episodes.csv", newline="") as f:
        rows = [(int(r["steps"]), int(r["collisions"]), int(r["joint_plays"])) for r in csv.DictReader(f)]
    assert rows == [(int(e["steps"]), int(e["collisions"]), int(e["joint_plays"])) for e in offline.episodes]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["composed"] is True and manifest["executor"] == "events"
    assert set(manifest["nodes"]) == {"container"} and manifest["nodes"]["container"]["exit_code"] == 0
    assert set(manifest["communication"]) == {"agv1", "agv2"}  # still one node per AGV, each its own counts
    assert all(c["subscriptions_created"] > 0 for c in manifest["communication"].values())
    log = (out / "logs" / "container.log").read_text()
    assert all(f"[{namespace}.{node}]" in log for node in ("world", "agv1", "agv2"))


@pytest.mark.ros
@pytest.mark.slow
def test_nodes_done_in_a_composed_launch_never_stall_the_agents_still_playing(tmp_path):
    """A node that has played its last episode gives its last messages up to 2 s to be acknowledged, on a
    timer: waiting inside its callback stalled the whole container, and the world timed out the agents
    still playing (warehouse_8's last greedy episode). The AGVs here reach their goals at
    different steps of the last episode, the others subscribing to a peer whenever one is close (LoC), and
    the world gives an action 1 s."""
    out, namespace = tmp_path / "result", unique("ending")
    sets = ("eval_episodes=0", "step_timeout=1.0")
    done = subprocess.run(launch_command(out, namespace, "warehouse_8", "loc", 1, sets, "--compose", "--no-figures"),
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["world"]["missed_actions"] == 0
    gridmap = load_map("warehouse_8")
    offline = run("loc", gridmap, run_settings(gridmap, ["eval_episodes=0"]), SEED, 0, 1)  # the map's `set` lines
    with open(out / "episodes.csv", newline="") as f:
        assert [(int(r["steps"]), int(r["collisions"])) for r in csv.DictReader(f)] == \
            [(int(e["steps"]), int(e["collisions"])) for e in offline.episodes]


@pytest.mark.ros
@pytest.mark.slow
def test_sigint_to_a_composed_launch_stops_the_container_cleanly(tmp_path):
    out, namespace, err = tmp_path / "result", unique("stopme"), tmp_path / "launch.stderr"
    with open(err, "wb") as f:
        launcher = subprocess.Popen(composed_launch(out, namespace, 100_000), stdout=subprocess.DEVNULL, stderr=f)
    try:
        log = out / "logs" / "container.log"
        wait_for_line(log, "stepping", 120.0, launcher, detail=err)
        launcher.send_signal(signal.SIGINT)
        assert launcher.wait(timeout=30) == 130
    finally:
        if launcher.poll() is None:
            launcher.kill()
            launcher.wait(timeout=30)
    assert not alive_with(namespace)
    assert re.search(r"interrupted by SIGINT after \d+/100020 episodes; stopped container", err.read_text())
    assert "Traceback" not in log.read_text()  # the container ended through its own Ctrl-C path


@pytest.mark.parametrize("args, message", [
    (["world", "agv1", "--ros-args", "-p", "map:=nowhere"], "parameter map: nowhere: no such map"),
    (["world", "world"], "node names must be distinct, repeated: world"),
    (["world", "agv-1"], "node name 'agv-1'"),
    ([], "no node names"),
])
@pytest.mark.ros
def test_the_container_exits_2_with_one_line_for_bad_input(args, message):
    done = subprocess.run([sys.executable, "-m", "ros_tools.compose", *args], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and message in done.stderr, done.stderr



# (agents, generator arguments, learning episodes, composed): 3 AGVs both ways with a start hold; 32 AGVs at the
# held-out study's slip, composed (33 processes would mostly time start-up), long enough that CQ marks joint states
# and hears its peers (from episode 4 on this map, offline)
DELAYED = {"3_composed": (3, {"aisles": 2, "aisle_length": 3, "slip": 0.2, "start_hold": 2}, 12, True),
           "3_process_per_node": (3, {"aisles": 2, "aisle_length": 3, "slip": 0.2, "start_hold": 2}, 12, False),
           "32_composed": (32, {"slip": 0.1}, 20, True)}


@pytest.mark.parametrize("case", list(DELAYED))
@pytest.mark.ros
@pytest.mark.slow
def test_a_delayed_warehouse_launch_equals_the_offline_run(tmp_path, case):
    """Delays come from the world's own seeded RNG (cq_ros.world, "Delays"), so a launch of a delayed warehouse
    file (its `set slip` and `set start_hold` lines) draws exactly the offline run's delays, greedy episodes
    included, and CQ's agents hear the peers the offline learners hear."""
    agents, generated, episodes, compose = DELAYED[case]
    path = tmp_path / "delayed.txt"
    path.write_text(warehouse_text(agents, seed=5, **generated))
    out, namespace = tmp_path / "result", unique("delayed")
    sets = ["eval_episodes=2", "step_cap=300", "epsilon_decay_episodes=0"]
    done = subprocess.run(launch_command(out, namespace, str(path), "cq", episodes, sets, *(["--compose"] * compose),
                                         "--no-figures"), capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr
    gridmap = load_map(path)
    settings = run_settings(gridmap, sets)
    assert (settings.slip, settings.start_hold) == (generated["slip"], generated.get("start_hold", 0))
    offline = run("cq", gridmap, settings, SEED, 0, episodes)
    if agents == 32:
        assert offline.episodes["heard"].sum() > 0
    for name, table in (("episodes.csv", offline.episodes), ("greedy.csv", offline.greedy)):
        with open(out / name, newline="") as f:
            rows = [(int(r["steps"]), int(r["collisions"]), int(r["joint_plays"]), int(r["heard"]))
                    for r in csv.DictReader(f)]
        assert rows == [(int(e["steps"]), int(e["collisions"]), int(e["joint_plays"]), int(e["heard"]))
                        for e in table], name
    assert json.loads((out / "manifest.json").read_text())["world"]["missed_actions"] == 0


@pytest.mark.ros
@pytest.mark.slow
def test_a_launch_where_cq_looks_only_where_it_is_decisive_equals_the_offline_run(tmp_path):
    """Our CQ decides in observe() whether to look (not where looking cannot change its greedy action), so a CQ
    agent node subscribes to what its learner asks for and a composed launch plays the offline run, episode by
    episode; exploration ends at episode 20 of 60, so the rule acts (the offline run's joint plays differ from
    those of ours looking always)."""
    path = tmp_path / "delayed.txt"
    path.write_text(warehouse_text(3, aisles=2, aisle_length=3, seed=5, slip=0.2))
    out = tmp_path / "result"
    sets = ["eval_episodes=2", "step_cap=300", "epsilon_decay_episodes=20", "window=10", "conf_down=0.1"]
    command = launch_command(out, unique("decisive"), str(path), "cq", 60, sets, "--compose", "--no-figures")
    done = subprocess.run(command, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr
    gridmap = load_map(path)
    offline = run("cq", gridmap, run_settings(gridmap, sets), SEED, 0, 60)
    looking_always = run_as(ours_without("look_if_decisive"), gridmap, run_settings(gridmap, sets), SEED, 0, 60)
    assert offline.episodes["joint_plays"].sum() != looking_always["joint_plays"].sum()
    assert offline.episodes["heard"].sum() > 0
    with open(out / "episodes.csv", newline="") as f:
        rows = [(int(r["steps"]), int(r["collisions"]), int(r["joint_plays"]), int(r["heard"]))
                for r in csv.DictReader(f)]
    assert rows == [(int(e["steps"]), int(e["collisions"]), int(e["joint_plays"]), int(e["heard"]))
                    for e in offline.episodes]

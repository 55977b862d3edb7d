"""`cq-ros launch` as a process: a world and one process per AGV (or the central JSA node) give exactly the
offline engine's episodes and greedy episodes, CQ's agents talk less than JS's, a killed agent or Ctrl-C
stops every process with one clear line, bad arguments exit 2 before anything starts, and no process
outlives its test."""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest

from cq_ros.cli.main import main
from cq_ros.engine import run
from cq_ros.episode import COLUMNS, table
from cq_ros.lab.results import write_results
from cq_ros.gridmap import load_map
from cq_ros.settings import Settings, run_settings
from cq_ros.mapgen.warehouse import warehouse_text
from helpers import SEED, WaitTimeout, alive_with, launch_command, read_episodes, unique, \
    wait_for_line, wait_until
from agent_node.checkpoint import save_checkpoints
from cq_ros.engine import Team, make_learners, world_seed
from cq_ros.world import GridWorld
from ros_tools.launch import DOMAIN_IDS, launch, run_domain
from ros_tools.launch_nodes import agent_nodes, node_commands, node_specs

LAUNCH_TIMEOUT_S = 120.0  # bound on one launch; each below takes about 10 s on 2 busy cores
# (map, algorithm) -> (episodes, settings): short episodes on tunnel_to_goal (early ones wander for
# thousands of steps; a negative float also checks that settings reach the nodes typed right), and on
# grid_game_2 a window CQ fills within 40 episodes, so it marks joint states and subscribes to its peer.
# A few greedy episodes after them (a barely trained greedy policy may run to step_cap).
CASES = {
    **{("tunnel_to_goal", a): (20, ("step_cap=100", "reward_step=-1", "eval_episodes=2"))
       for a in ("cq", "js", "loc")},
    **{("grid_game_2", a): (40, ("window=10", "eval_episodes=3")) for a in ("cq", "js", "loc", "jsa")},
}


@pytest.fixture(scope="module")
def launched(tmp_path_factory):
    """launched(map, algo) -> the result directory of that case's launch (run once per module)."""
    cache: dict[tuple[str, str], Path] = {}

    def get(map_name: str, algo: str) -> Path:
        if (map_name, algo) not in cache:
            episodes, sets = CASES[map_name, algo]
            out = tmp_path_factory.mktemp(f"{map_name}_{algo}") / "result"
            namespace = unique("launch")
            done = subprocess.run(launch_command(out, namespace, map_name, algo, episodes, sets),
                                  capture_output=True, text=True, timeout=LAUNCH_TIMEOUT_S)
            assert done.returncode == 0, done.stderr
            assert not alive_with(namespace)
            (out.parent / "stdout.txt").write_text(done.stdout)
            cache[map_name, algo] = out
        return cache[map_name, algo]

    return get


@pytest.mark.parametrize("map_name, algo", list(CASES))
@pytest.mark.ros
@pytest.mark.slow
def test_a_launch_gives_exactly_the_offline_engines_episodes(launched, map_name, algo, tmp_path):
    out = launched(map_name, algo)
    episodes, sets = CASES[map_name, algo]
    gridmap = load_map(map_name)
    offline = run(algo, gridmap, Settings().with_overrides(list(sets)), SEED, 0, episodes)

    ros = read_episodes(out)
    assert ros.shape == offline.episodes.shape
    for column in COLUMNS:  # steps and collisions first: the transport adds and loses nothing
        np.testing.assert_array_equal(ros[column], offline.episodes[column], err_msg=column)
    with open(out / "episodes.csv", newline="") as f:  # numbered from 0, as the world's stats on the wire
        assert [int(r["episode"]) for r in csv.DictReader(f)] == list(range(episodes))

    with open(out / "observe.csv", newline="") as f:
        marked = [(int(r["agent"]) - 1, gridmap.index(int(r["row"]), int(r["col"])), int(r["peer"]) - 1,
                   gridmap.index(int(r["peer_row"]), int(r["peer_col"])), float(r["confidence"]))
                  for r in csv.DictReader(f)]
    assert marked == [(a, s, j, c, pytest.approx(conf, rel=1e-5)) for a, s, j, c, conf in offline.joint_states]
    if algo == "cq" and map_name == "grid_game_2":
        assert marked, "this case is chosen so that CQ marks joint states"

    # greedy.csv: the engine's greedy episodes, written as `cq-ros experiment` writes them
    assert len(offline.greedy) == Settings().with_overrides(list(sets)).eval_episodes > 0
    write_results(tmp_path, gridmap, [offline], {})
    assert (out / "greedy.csv").read_text() == (tmp_path / "greedy.csv").read_text()

    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["mode"] == "ros" and manifest["seed"] == SEED and manifest["episodes"] == episodes
    assert "greedy" not in manifest  # as cq-ros experiment's: greedy.csv holds them
    assert manifest["ended"] == {"how": "finished", "reason": "every episode played as the offline engine plays it",
                                 "exit_status": 0} and manifest["departures"] == {}
    assert manifest["settings"] == Settings().with_overrides(list(sets)).as_dict()
    learners = ["jsa"] if algo == "jsa" else [f"agv{k}" for k in range(1, gridmap.n_agents + 1)]
    assert set(manifest["communication"]) == set(learners)
    assert all(node["exit_code"] == 0 for node in manifest["nodes"].values())
    assert set(manifest["nodes"]) == {"world", *learners}
    assert manifest["world"]["missed_actions"] == 0
    # the peer messages are one figure: the positions the learners' decisions took in, as the engine counts them
    assert sum(c["peer_messages"] for c in manifest["communication"].values()) == \
        offline.episodes["heard"].sum() + offline.greedy["heard"].sum()
    for node in manifest["nodes"]:
        assert (out / "logs" / f"{node}.log").exists()
    for png in ("collisions.png", "steps.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.ros
def test_a_launch_started_from_an_offline_runs_checkpoints_goes_on_as_that_run(tmp_path):
    # the learners of 60 offline episodes, checkpointed, then 15 more episodes offline and over ROS (composed)
    gridmap = load_map("tunnel_to_goal")
    settings = Settings().with_overrides(["step_cap=100", "reward_step=-1", "window=10", "eval_episodes=0"])
    team = Team(GridWorld(gridmap, settings, seed=world_seed(SEED, 0)), make_learners("cq", gridmap, settings, SEED, 0))
    for _ in range(60):
        team.episode()
    assert any(learner.joint_states() for learner in team.learners)  # it has learnt where to look
    save_checkpoints(tmp_path, [name for name, _ in agent_nodes(gridmap, "cq")], team.learners, 59)
    with pytest.raises(ValueError, match="no checkpoint agv1.npz"):
        launch("tunnel_to_goal", "cq", 15, SEED, tmp_path / "never", settings, start_from=tmp_path / "empty")
    result = launch("tunnel_to_goal", "cq", 15, SEED, tmp_path / "ros", settings, compose=True, figures=False,
                    progress=False, start_from=tmp_path)
    team.world = GridWorld(gridmap, settings, seed=world_seed(SEED, 0))  # a fresh world, as the launch's
    offline = table(team.episode() for _ in range(15))
    np.testing.assert_array_equal(result.episodes, offline)
    # composed too, the peer messages are the positions the learners took in, as the engine counts them
    assert sum(c["peer_messages"] for c in result.manifest["communication"].values()) == offline["heard"].sum() > 0


@pytest.mark.ros
@pytest.mark.slow
def test_a_launch_on_a_copied_map_file_with_a_namespace_written_as_ros_writes_it(tmp_path):
    """--map a path (named unlike any shipped map) is the map used to the last figure; --namespace /name is
    the namespace name, as `-r __ns:=/name` is for a node. Exploration falls to 0 on the nodes' schedule as it
    does offline."""
    copied = tmp_path / "my" / "mymap.txt"
    copied.parent.mkdir()
    copied.write_text(Path(load_map("tunnel_to_goal").source).read_text())
    episodes, sets = CASES["tunnel_to_goal", "cq"]
    sets = (*sets, "epsilon_decay_episodes=10")
    out, namespace = tmp_path / "result", unique("slash")
    done = subprocess.run(launch_command(out, f"/{namespace}", str(copied), "cq", episodes, sets),
                          capture_output=True, text=True, timeout=LAUNCH_TIMEOUT_S)
    assert done.returncode == 0, done.stderr
    assert not alive_with(namespace)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["namespace"] == f"/{namespace}" and manifest["map"] == "mymap"
    offline = run("cq", load_map(copied), Settings().with_overrides(list(sets)), SEED, 0, episodes)
    np.testing.assert_array_equal(read_episodes(out), offline.episodes)
    for png in ("collisions.png", "joint_plays.png", "state_space.png", "observe_map.png", "steps.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", png


def test_progress_lines_say_greedy_for_the_episodes_after_the_learning_ones(capsys):
    from ros_tools.progress import Progress

    bar = Progress("tunnel_to_goal cq", episodes=6, learning=4, enabled=True)  # stderr is not a terminal here
    for done in range(1, 7):
        bar.update(done, collisions=done, joint_states=1, peer_messages=2 * done)
    bar.close()
    lines = capsys.readouterr().err.splitlines()
    assert [line.split(":")[0] for line in lines] == ["tunnel_to_goal cq"] * 4 + ["tunnel_to_goal cq greedy"] * 2
    assert lines[-1] == "tunnel_to_goal cq greedy: episodes 6/6, 6 collisions, 1 joint states, 12 peer messages"


@pytest.mark.ros
@pytest.mark.slow
def test_a_launch_ends_with_the_summary_the_greedy_policy_and_the_communication_cost(launched):
    out = launched("tunnel_to_goal", "cq")
    stdout = (out.parent / "stdout.txt").read_text()
    with open(out / "greedy.csv", newline="") as f:
        greedy = list(csv.DictReader(f))
    communication = json.loads((out / "manifest.json").read_text())["communication"]
    assert "collisions/ep (last 10%)" in stdout and f"results: {out}" in stdout
    collisions, steps = (sum(float(r[c]) for r in greedy) / len(greedy) for c in ("collisions", "steps"))
    assert re.search(rf"greedy policy, cq, 1 run x {len(greedy)} episodes: {collisions:.2f} "
                     rf"collisions/ep, {steps:.1f} steps/ep", stdout)
    for node, cost in communication.items():
        assert (f"{node}: {cost['peer_messages']} peer position messages ({cost['peer_deliveries']} delivered), "
                f"{cost['subscriptions_created']} subscriptions created") in stdout


@pytest.mark.parametrize("map_name", ["tunnel_to_goal", "grid_game_2"])
@pytest.mark.ros
@pytest.mark.slow
def test_cq_agents_receive_fewer_peer_messages_than_js_agents(launched, map_name):
    def peer_messages(algo: str) -> int:
        manifest = json.loads((launched(map_name, algo) / "manifest.json").read_text())
        return sum(agent["peer_messages"] for agent in manifest["communication"].values())

    cq, js = peer_messages("cq"), peer_messages("js")
    assert 0 < js and cq < js


def _start_long_launch(tmp_path: Path, *extra: str) -> tuple[subprocess.Popen, Path, str, Path]:
    """A launch that would run for minutes, once its world is stepping: (process, out, namespace, stderr)."""
    out, namespace, err = tmp_path / "result", unique("stopme"), tmp_path / "launch.stderr"
    with open(err, "wb") as f:
        launcher = subprocess.Popen([*launch_command(out, namespace, "tunnel_to_goal", "cq", 100_000, ()), *extra],
                                    stdout=subprocess.DEVNULL, stderr=f)
    try:
        wait_for_line(out / "logs" / "world.log", "stepping", LAUNCH_TIMEOUT_S, launcher, detail=err)
    except WaitTimeout:
        launcher.kill()
        launcher.wait(timeout=30)
        raise
    return launcher, out, namespace, err


def _wait(launcher: subprocess.Popen, namespace: str) -> int:
    try:
        return launcher.wait(timeout=30)
    finally:
        if launcher.poll() is None:
            launcher.kill()
            launcher.wait(timeout=30)
        for cmdline in alive_with(namespace):  # clean up after a failure, then fail
            os.kill(int(cmdline.split(":")[0]), signal.SIGKILL)


@pytest.mark.ros
@pytest.mark.slow
def test_a_killed_agent_stops_the_launch_with_one_line_naming_it(tmp_path):
    launcher, out, namespace, err = _start_long_launch(tmp_path)
    agent = [p for p in alive_with(f"__ns:=/{namespace}") if "__node:=agv1" in p]
    assert len(agent) == 1
    os.kill(int(agent[0].split(":")[0]), signal.SIGKILL)
    code = _wait(launcher, namespace)
    assert not alive_with(namespace)
    assert code == 1
    last = err.read_text().strip().splitlines()[-1]
    # out of 100,000 learning episodes and the default 20 greedy ones
    assert re.fullmatch(r"cq-ros launch: error: agv1 \(pid \d+\) exited with code -9 \(killed by SIGKILL\) "
                        r"after \d+/100020 episodes \(its log: .*agv1\.log\); stopped world, agv2 \(logs in .*\)",
                        last), last
    # what was heard is kept (the launcher writes each episode's row as it comes), and the manifest says how the
    # run ended, with the counters of each node
    heard = int(re.search(r"after (\d+)/100020 episodes", last)[1])
    assert len((out / "episodes.csv").read_text().splitlines()) == 1 + heard
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["ended"]["how"] == "node_failed" and manifest["ended"]["exit_status"] == 1
    assert "agv1" in manifest["ended"]["reason"] and "SIGKILL" in manifest["ended"]["reason"]
    assert manifest["ended_early"]["episodes_written"] == heard
    assert manifest["nodes"]["agv1"]["exit_code"] == -9
    assert set(manifest["communication"]) <= {"agv1", "agv2"} and "counters" in manifest["world"]
    # the nodes the launcher stopped said what they had counted at their exit; the killed one could not
    assert manifest["world"]["counters_as_of"] == manifest["communication"]["agv2"]["counters_as_of"] == "exit"
    assert manifest["communication"].get("agv1", {}).get("counters_as_of", "episode") != "exit"
    assert not (out / ".reserve").exists()
    _assert_no_key_left(manifest)


def _assert_no_key_left(manifest: dict) -> None:
    """The launch's own key was a file without a name, read through the launcher's descriptor: gone with it."""
    key_files = {arg.split(":=", 1)[1] for node in manifest["nodes"].values() for arg in node["command"]
                 if arg.startswith("key_file:=")}
    assert len(key_files) == 1, key_files
    (key_file,) = key_files
    assert key_file.startswith("/proc/") and not os.path.exists(key_file), key_file


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_a_launcher_ended_by_a_signal_leaves_no_key_and_says_how_it_ended(tmp_path, sig):
    """SIGTERM: every node stopped, exit 130, the manifest written (how: interrupted, with each node's counters
    at its exit).
    kill -9: nothing can be written, but the nodes go with the launcher (PR_SET_PDEATHSIG) and the key with
    them: it was never a file with a name."""
    launcher, out, namespace, err = _start_long_launch(tmp_path)
    key = next(arg.split(":=", 1)[1] for p in alive_with(f"__ns:=/{namespace}") for arg in p.split()
               if arg.startswith("key_file:="))
    assert key.startswith(f"/proc/{launcher.pid}/fd/") and os.path.exists(key)
    launcher.send_signal(sig)
    code = _wait(launcher, namespace)
    wait_until(lambda: not alive_with(namespace), 30, "the nodes gone with the launcher")
    assert not os.path.exists(key)
    if sig == signal.SIGKILL:
        return
    assert code == 130
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["ended"]["how"] == "interrupted" and manifest["ended"]["exit_status"] == 130
    assert "interrupted by SIGTERM" in manifest["ended"]["reason"]
    heard = len((out / "episodes.csv").read_text().splitlines()) - 1
    assert manifest["ended_early"]["episodes_written"] == heard
    # every node stopped said what it had counted at its exit, after its last statistics too
    assert {manifest["world"]["counters_as_of"]} | {c["counters_as_of"] for c in manifest["communication"].values()} \
        == {"exit"} and set(manifest["communication"]) == {"agv1", "agv2"}
    _assert_no_key_left(manifest)


@pytest.mark.ros
@pytest.mark.slow
def test_sigint_to_the_launcher_stops_every_node_cleanly(tmp_path):
    launcher, out, namespace, err = _start_long_launch(tmp_path)
    launcher.send_signal(signal.SIGINT)
    code = _wait(launcher, namespace)
    assert not alive_with(namespace)
    assert code == 130
    assert re.search(r"cq-ros launch: interrupted by SIGINT after \d+/100020 episodes; stopped world, agv1, agv2",
                     err.read_text())
    for log in (out / "logs").iterdir():  # each node ended through its own Ctrl-C path, not a crash
        assert "Traceback" not in log.read_text(), log.name


@pytest.mark.slow
def test_a_second_launch_in_a_running_systems_namespace_refuses_before_it_plays(tmp_path, ros_domain_id):
    """the second launch looks at the namespace once discovery has settled there and refuses in one line, exit 1,
    before any process of its own starts, leaving nothing. It used to start its world, which stepped the first
    system's agents before it heard the first world and yielded 4 episodes later ('a second system started
    together with this one'); the first system's run stays the engine's."""
    shared = ("--domain-id", str(ros_domain_id))
    first, out, namespace, err = _start_long_launch(tmp_path, *shared)
    try:
        # until the first system has episodes to be mistaken for
        wait_until(lambda: len((out / "episodes.csv").read_text().splitlines()) >= 4, LAUNCH_TIMEOUT_S,
                   "the first launch's fourth row", ended=lambda: first.poll() is not None, detail=err.read_text)
        other = tmp_path / "second"
        second = subprocess.run([*launch_command(other, namespace, "tunnel_to_goal", "cq", 100_000, ()), *shared,
                                 "--seed", str(SEED + 1)], capture_output=True, text=True, timeout=LAUNCH_TIMEOUT_S)
        assert first.poll() is None, err.read_text()
    finally:
        if first.poll() is None:  # also where a check above failed: the first system would run on for long
            first.send_signal(signal.SIGINT)
        code = _wait(first, namespace)
    assert second.returncode == 1, second.stderr
    assert re.fullmatch(rf"cq-ros launch: error: namespace /{namespace} on ROS_DOMAIN_ID {ros_domain_id} already "
                        r"holds a running system \(nodes \w+(, \w+)*\): refusing to start; give this launch "
                        rf"another --namespace or --domain-id; {re.escape(str(other))} removed\n", second.stderr), \
        second.stderr
    assert not other.exists()
    assert code == 130
    heard = read_episodes(out)
    offline = run("cq", load_map("tunnel_to_goal"), Settings(), SEED, 0, len(heard)).episodes
    np.testing.assert_array_equal(heard, offline)


def test_nodes_are_given_the_settings_that_differ_from_the_maps_own(tmp_path):
    # warehouse_8 carries reward_step=-1, gamma=0.98 and epsilon_decay_episodes=1500: the nodes take them from the
    # map unless the launch's differ.
    def given(settings):
        children = node_commands(node_specs("warehouse_8", "cq", 5, 0, settings, tmp_path, 2.0), "ns", tmp_path)
        return [{a.split(":=")[0] for a in c.command if ":=" in a} & set(Settings().as_dict()) for c in children]

    gridmap = load_map("warehouse_8")
    assert given(run_settings(gridmap)) == [set()] * 9
    assert given(run_settings(gridmap, ["reward_step=0", "alpha=0.2"])) == [{"reward_step", "alpha"}] * 9
    assert given(Settings()) == [{"reward_step", "gamma", "epsilon_decay_episodes"}] * 9


@pytest.mark.ros
def test_a_generated_warehouse_file_launches_with_its_defaults_and_equals_the_offline_run(tmp_path):
    path = tmp_path / "w2.txt"
    path.write_text(warehouse_text(2, aisles=1, aisle_length=2, seed=3))
    sets, episodes = ("step_cap=60", "eval_episodes=1"), 4
    out, namespace = tmp_path / "result", unique("warehouse")
    done = subprocess.run(launch_command(out, namespace, str(path), "indep", episodes, sets),
                          capture_output=True, text=True, timeout=LAUNCH_TIMEOUT_S)
    assert done.returncode == 0, done.stderr
    assert not alive_with(namespace)
    settings = run_settings(load_map(path), list(sets))
    assert settings.reward_step == -1.0
    offline = run("indep", load_map(path), settings, SEED, 0, episodes)
    np.testing.assert_array_equal(read_episodes(out), offline.episodes)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["settings"] == settings.as_dict()
    assert manifest["settings_from_map"] == {"reward_step": -1.0, "gamma": 0.98, "epsilon_decay_episodes": 1500}


@pytest.mark.ros
@pytest.mark.slow
def test_cq_on_a_four_agv_warehouse_file_equals_the_offline_run_joint_states_included(tmp_path):
    """CQ's AGVs over ROS on a generated warehouse, with a window short enough that an agent marks
    a joint state and subscribes to a peer within the run, give the offline engine's episodes exactly."""
    path = tmp_path / "w4.txt"
    path.write_text(warehouse_text(4, aisles=2, aisle_length=2, seed=0))
    sets, episodes = ("step_cap=100", "window=2", "eval_episodes=1"), 8
    settings = run_settings(load_map(path), list(sets))
    offline = run("cq", load_map(path), settings, SEED, 0, episodes)
    assert offline.episodes["joint_plays"].sum() > 0  # the premise: some agent acted on a joint state
    out, namespace = tmp_path / "result", unique("warehouse_cq")
    done = subprocess.run(launch_command(out, namespace, str(path), "cq", episodes, sets),
                          capture_output=True, text=True, timeout=LAUNCH_TIMEOUT_S)
    assert done.returncode == 0, done.stderr
    assert not alive_with(namespace)
    np.testing.assert_array_equal(read_episodes(out), offline.episodes)


@pytest.mark.parametrize("args, phrase", [
    (["--algo", "sarsa"], "unknown algorithm 'sarsa'"),
    (["--algo", "cq", "--domain-id", "300"], "at most 232"),
    (["--algo", "cq", "--namespace", "9lives"], "is not a ROS name"),
    (["--algo", "cq", "--set", "alhpa=1"], "unknown setting 'alhpa'"),
    (["--algo", "cq", "--step-timeout", "0"], "must be more than 0"),
    (["--algo", "jsa", "--map", "warehouse_8"], "jsa supports at most 5 agents"),
    (["--algo", "cq", "--map", "nowhere"], "no such map"),
])
def test_bad_arguments_give_one_line_and_exit_2_before_any_process_starts(tmp_path, capsys, args, phrase):
    if "--map" not in args:
        args = [*args, "--map", "grid_game_2"]
    with pytest.raises(SystemExit) as exit_:
        main(["launch", *args, "--out", str(tmp_path / "X")])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert phrase in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "X").exists()


@pytest.mark.parametrize("value", ["abc", "233", "-1"])
def test_a_launch_on_a_ros_domain_id_that_is_no_domain_is_one_line_naming_the_variable(tmp_path, capsys,
                                                                                         monkeypatch, value):
    monkeypatch.setenv("ROS_DOMAIN_ID", value)
    with pytest.raises(SystemExit) as exit_:
        main(["launch", "--map", "grid_game_2", "--algo", "cq", "--out", str(tmp_path / "X")])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip()
    assert f"ROS_DOMAIN_ID={value!r} in the environment" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "X").exists()


def test_a_launch_takes_its_domain_from_the_option_then_the_environment_and_draws_one_only_without_either(
        monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", "17")
    assert (run_domain(None), run_domain(5)) == (17, 5)
    for unset in (None, "", " "):  # rcl reads an empty ROS_DOMAIN_ID as none given
        if unset is None:
            monkeypatch.delenv("ROS_DOMAIN_ID")
        else:
            monkeypatch.setenv("ROS_DOMAIN_ID", unset)
        drawn = {run_domain(None) for _ in range(200)}
        assert min(drawn) >= DOMAIN_IDS[0] and max(drawn) <= DOMAIN_IDS[1] and len(drawn) > 1


@pytest.mark.ros
def test_a_launch_runs_on_the_ros_domain_id_of_its_environment(tmp_path, ros_domain_id):
    # The session's domain (tests/conftest.py), given as a user gives theirs: ROS_DOMAIN_ID=N cq-ros launch ...
    # No greedy episodes: after 3 learning ones, indep's greedy policy runs to the step cap (40-60 s of a suite).
    out, namespace = tmp_path / "result", unique("envdomain")
    done = subprocess.run(launch_command(out, namespace, "grid_game_2", "indep", 3, ("eval_episodes=0",)),
                          capture_output=True, text=True, timeout=LAUNCH_TIMEOUT_S,
                          env={**os.environ, "ROS_DOMAIN_ID": str(ros_domain_id)})
    assert done.returncode == 0, done.stderr
    assert f"ROS_DOMAIN_ID={ros_domain_id}, namespace /{namespace}" in done.stderr
    assert json.loads((out / "manifest.json").read_text())["domain_id"] == ros_domain_id
    assert not alive_with(namespace)


def test_a_node_still_a_process_after_its_report_is_stopped_once_every_episode_is_heard(tmp_path, monkeypatch,
                                                                                          capsys):
    """Seen once beside two busy loops: a world that played every episode and printed its report was still a
    process 90 s later, and the launch waited for it. A node that has reported is stopped EXIT_HANG_S later and
    counts as done; one that has not reported is left to the launch's other rules."""
    from node_runtime.report import report_line
    from ros_tools import launch_watch
    from ros_tools.children import Child

    monkeypatch.setattr(launch_watch, "EXIT_HANG_S", 0.2)
    report = report_line({"node": "world", "counters": {}, "dropped_on": {}, "floods": {}})
    hung = Child("world", ["sh", "-c", f"echo '{report}'; exec sleep 60"], tmp_path / "world.log")
    busy = Child("agv1", ["sh", "-c", "echo working; exec sleep 60"], tmp_path / "agv1.log")
    for child in (hung, busy):
        child.start(dict(os.environ))
    try:
        wait_until(lambda: hung.reports() and busy.said_anything(), 30, "the children never wrote")
        wait_until(lambda: launch_watch._stop_hung_at_exit([c for c in (hung, busy) if c.running]) or not hung.running,
                   30, "the reported node was never stopped")
        assert hung.hung_at_exit and hung.exit_code == -signal.SIGKILL
        assert busy.running and not busy.hung_at_exit
        assert "world (pid" in capsys.readouterr().err
    finally:
        for child in (hung, busy):
            child.signal_group(signal.SIGKILL)
            child.process.wait(timeout=10)

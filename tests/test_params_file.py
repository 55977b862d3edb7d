"""A system in a file (ros_tools.params_file): every launch writes params.yaml with wildcard keys; it starts the
same system under another namespace, with `cq-ros launch --params-file` (the same episodes) and by hand with
`python -m ros_tools.compose`, whose results `cq-ros collect` writes (the same again); a key made by
`cq-ros key` is named there and kept; a file that cannot describe a system is one line naming it."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import uuid

import pytest
import yaml

from cq_ros.cli.main import main
from cq_ros.settings import run_settings
from cq_ros.gridmap import load_map
from helpers import alive_with, unique
from ros_tools.launch_nodes import node_specs
from ros_tools.params_file import SystemFileError, read_system, write_system

RUN_TIMEOUT_S = 120.0  # bound on one run by hand; it takes a few seconds


def test_the_file_has_wildcard_keys_and_reads_back_as_the_launch(tmp_path):
    settings = run_settings(load_map("warehouse_8"), ["alpha=0.2", "reward_step=0"])
    nodes = node_specs("warehouse_8", "cq", 7, 3, settings, tmp_path, 1.5, peer_linger_steps=2,
                       key_file=tmp_path / "k")
    path = write_system(tmp_path / "params.yaml", nodes)
    data = yaml.safe_load(path.read_text())
    assert list(data) == ["/**", "/**/world", *[f"/**/agv{k}" for k in range(1, 9)]]
    shared = data["/**"]["ros__parameters"]
    assert shared["map"] == "warehouse_8" and shared["alpha"] == 0.2 and shared["reward_step"] == 0.0
    assert data["/**/agv3"]["ros__parameters"]["agent_id"] == 3
    text = path.read_text()
    assert "checkpoint:" not in text and "min_stats_subscribers" not in text  # the launch's, not the system's
    system = read_system(path)
    assert (system.map, system.algo, system.episodes, system.seed) == ("warehouse_8", "cq", 7, 3)
    assert system.settings == {"alpha": 0.2, "reward_step": 0.0}
    assert system.node_parameters["step_timeout"] == 1.5 and system.node_parameters["peer_linger_steps"] == 2
    assert system.key_file == tmp_path / "k"


@pytest.mark.parametrize("edit, phrase", [
    (lambda d: d.update({"/cq_1/agv1": d.pop("/**/agv1")}), "section '/cq_1/agv1': expected `/**` or `/**/<node>`"),
    (lambda d: d["/**/agv1"]["ros__parameters"].update(checkpoint="/x.pkl"), "agv1: parameter checkpoint is set by"),
    (lambda d: d["/**"]["ros__parameters"].update(step_timout=1.0), "did you mean 'step_timeout'?"),
    (lambda d: d["/**/agv2"]["ros__parameters"].update(alpha=0.3), "agv2: setting alpha applies to every node"),
    (lambda d: d["/**/agv2"]["ros__parameters"].update(algo="js"), "parameter algo must be given once"),
    (lambda d: d["/**"]["ros__parameters"].pop("map"), "parameter map must be given once"),
    (lambda d: d["/**"]["ros__parameters"].update(step_timeout=3), "parameter step_timeout has ROS type double (like"),
    (lambda d: d["/**"]["ros__parameters"].update(alpha=1), "parameter alpha has ROS type double (like"),
    (lambda d: d["/**/agv1"]["ros__parameters"].update(peer_linger_steps=2.0),
     "agv1: parameter peer_linger_steps has ROS type integer"),
])
def test_a_file_that_describes_no_system_is_one_line(tmp_path, capsys, edit, phrase):
    nodes = node_specs("tunnel_to_goal", "cq", 5, 0, run_settings(load_map("tunnel_to_goal")), tmp_path, 2.0)
    path = write_system(tmp_path / "params.yaml", nodes)
    data = yaml.safe_load(path.read_text())
    edit(data)
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(SystemFileError, match=r"params\.yaml: .*" + phrase.replace("*", r"\*").replace("?", r"\?")
                       .replace("(", r"\(").replace(")", r"\)")):
        read_system(path)
    with pytest.raises(SystemExit) as stop:
        main(["launch", "--params-file", str(path), "--out", str(tmp_path / "never")])
    assert stop.value.code == 2 and phrase in capsys.readouterr().err
    assert not (tmp_path / "never").exists()


def test_params_file_and_the_options_it_replaces_do_not_mix(tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["launch", "--params-file", str(tmp_path / "p.yaml"), "--map", "grid_game_2", "--out",
              str(tmp_path / "o")])
    assert stop.value.code == 2 and "--params-file gives the system: drop --map" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["launch", "--out", str(tmp_path / "o")])
    assert "--map and --algo are required" in capsys.readouterr().err


@pytest.mark.ros
@pytest.mark.slow
def test_a_launch_s_params_yaml_starts_the_same_system_under_another_namespace(tmp_path, capsys, monkeypatch):
    key = tmp_path / "run.key"
    assert main(["key", "--out", str(key)]) == 0
    assert stat.S_IMODE(os.stat(key).st_mode) == 0o600
    with pytest.raises(SystemExit) as stop:  # a key file is never overwritten
        main(["key", "--out", str(key)])
    assert stop.value.code == 2

    first, second = tmp_path / "first", tmp_path / "second"
    base = ["launch", "--compose", "--no-figures"]
    assert main([*base, "--map", "grid_game_2", "--algo", "cq", "--episodes", "12", "--seed", "4", "--set", "window=5",
                 "--set", "eval_episodes=1", "--key", str(key), "--out", str(first),
                 "--namespace", f"one_{uuid.uuid4().hex[:6]}"]) == 0
    assert key.exists() and f"key_file: {key}" in (first / "params.yaml").read_text()  # named and kept
    assert main([*base, "--params-file", str(first / "params.yaml"), "--out", str(second),
                 "--namespace", f"two_{uuid.uuid4().hex[:6]}"]) == 0
    for table in ("episodes.csv", "greedy.csv", "observe.csv"):
        assert (first / table).read_text() == (second / table).read_text(), table
    assert (first / "params.yaml").read_text() == (second / "params.yaml").read_text()

    # By hand: the container alone under a third namespace, its statistics waiting for a listener, and
    # `cq-ros collect` finding it on the domain and writing what the launch wrote.
    namespace = f"three_{uuid.uuid4().hex[:6]}"
    by_hand = subprocess.Popen([sys.executable, "-m", "ros_tools.compose", "world", "agv1", "agv2", "--ros-args",
                                "-r", f"__ns:=/{namespace}", "--params-file", str(first / "params.yaml"),
                                "-p", "min_stats_subscribers:=1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    import ros_tools.collect

    found = ros_tools.collect.find_system

    def agv2_seen_first(*args, **kwargs):  # as when a process per node is discovered one at a time
        ns, _agents = found(*args, **kwargs)
        return ns, ["agv2"]

    monkeypatch.setattr(ros_tools.collect, "find_system", agv2_seen_first)
    try:
        collected = main(["collect", "--namespace", namespace, "--out", str(tmp_path / "third")])
        assert by_hand.wait(timeout=RUN_TIMEOUT_S) == 0, by_hand.stderr.read()
        assert collected == 0
    finally:
        by_hand.kill()
        by_hand.communicate()
    for table in ("episodes.csv", "greedy.csv", "observe.csv"):
        assert (first / table).read_text() == (tmp_path / "third" / table).read_text(), table
    manifest = json.loads((tmp_path / "third" / "manifest.json").read_text())
    assert manifest["namespace"] == f"/{namespace}" and manifest["collected"] and manifest["settings"]["window"] == 5
    launched = json.loads((first / "manifest.json").read_text())
    assert set(manifest["nodes"]) == {"world", "agv1", "agv2"}  # every node of the system, not those seen first
    assert {name: c["peer_messages"] for name, c in manifest["communication"].items()} == \
        {name: c["peer_messages"] for name, c in launched["communication"].items()}
    out = capsys.readouterr()
    assert "greedy policy, cq, 1 run x 1 episodes" in out.out and f"grid_game_2 cq in /{namespace}" in out.err
    assert not alive_with(namespace)


@pytest.mark.ros
def test_collect_without_a_system_is_one_line_and_writes_nothing(tmp_path, capsys):
    assert main(["collect", "--namespace", unique("none"), "--wait", "1", "--out", str(tmp_path / "r")]) == 1
    err = capsys.readouterr().err
    assert "cq-ros collect: error: no system" in err and len(err.strip().splitlines()) == 2  # after "looking for"
    assert not (tmp_path / "r").exists()

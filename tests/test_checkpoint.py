"""Checkpoints are data (agent_node.checkpoint): a crafted pickle runs nothing at any entry point and is refused
naming the command that converts an old checkpoint; every bad file is one line naming the file and the field."""

import io
import json
import os
import pickle
import re
import signal
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from agent_node.checkpoint import load_checkpoint, save_checkpoint
from cq_ros.engine import Team, make_learners
from cq_ros.gridmap import load_map
from cq_ros.learners.state import to_arrays
from cq_ros.settings import Settings, SettingsError, run_settings
from cq_ros.world import GridWorld
from helpers import Payload, crafted_pickle, wait_until
from ros_tools.restarts import Restarts, file_identity

MAP = "tunnel_to_goal"
CONVERT = "cq-ros checkpoint convert"


def _trained(settings=Settings(window=10, step_cap=100)):
    gridmap = load_map(MAP)
    team = Team(GridWorld(gridmap, settings), make_learners("cq", gridmap, settings, 0, 0))
    for _ in range(3):
        team.episode()
    return gridmap, settings, team.learners[0]


def same_state(a, b) -> bool:
    x, y = to_arrays(a), to_arrays(b)
    return x.keys() == y.keys() and all(np.array_equal(x[k], y[k], equal_nan=x[k].dtype.kind == "f") for k in x)


def _written(path, arrays):
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    path.write_bytes(buffer.getvalue())


def test_a_crafted_pickle_runs_nothing_and_names_the_command_that_converts(tmp_path):
    gridmap, settings, _ = _trained()
    path, marker = tmp_path / "agv1.npz", tmp_path / "ran"
    crafted_pickle(path, marker)
    with pytest.raises(SettingsError) as e:
        load_checkpoint(path, "cq", gridmap, 0, settings)
    assert not marker.exists()
    assert f"`{CONVERT} {path} NEW.npz`" in str(e.value) and "\n" not in str(e.value)


def _good_arrays(tmp_path):
    gridmap, settings, learner = _trained()
    path = tmp_path / "agv1.npz"
    save_checkpoint(path, learner, 7)
    return (gridmap, settings, path, _arrays_of(path))


def _arrays_of(path):
    with np.load(path) as npz:
        return {k: npz[k] for k in npz.files}


@pytest.mark.parametrize("change, field, message", [
    ({"algo": np.str_("str")}, "algo", "unknown algorithm 'str'"),
    ({"episode": np.int64(-5)}, "episode", "holds -5, below its least value 0"),
    ({"episode": np.str_("5")}, "episode", "holds <U1 where it must hold integers"),
    ({"agent": np.int64(7)}, "agent", "holds 7, above its greatest value 1"),
    ({"map": np.str_("cit")}, "map", "is cit; this node runs map tunnel_to_goal"),
    ({"q_local": np.zeros((4, 4))}, "q_local", "has shape (4, 4) where this map and these settings make it (25, 4)"),
    ({"q_local": np.full((25, 4), np.inf)}, "q_local", "holds a value that is not a finite number"),
    ({"rng": np.zeros(3, dtype=np.int64)}, "rng", "has shape (3,)"),
    ({"episode": np.int64(2**62)}, "episode", "holds 4611686018427387904, above its greatest value 2147483647"),
    ({"settings": np.str_("{")}, "settings", "not JSON"),
    ({"settings": np.str_("[" * 5000 + "]" * 5000)}, "settings", "nested too deeply"),  # a RecursionError once
    ({"settings": np.str_('{"alpha": ' + "[" * 9000 + "]" * 9000 + "}")}, "settings",
     "is 18,011 characters long, more than settings take (16,384)"),
    ({"settings": np.str_('{"alpha": [[0.1]]}')}, "settings", "alpha holds a list, where every setting is a number"),
    ({"checkpoint_format": np.int64(3)}, "checkpoint_format", "is 3; this version reads format 4"),
], ids=["learner-str", "episode-minus-5", "episode-string", "agent", "map", "shape", "inf", "rng", "episode-2**62",
        "settings", "settings-nested", "settings-long", "settings-list", "format"])
def test_every_bad_field_is_one_line_naming_the_file_and_the_field(tmp_path, change, field, message):
    gridmap, settings, path, arrays = _good_arrays(tmp_path)
    _written(path, {**arrays, **change})
    with pytest.raises(SettingsError) as e:
        load_checkpoint(path, "cq", gridmap, 0, settings)
    assert str(e.value).startswith(f"parameter checkpoint: {str(path)!r}: field {field}: {message}")
    assert "\n" not in str(e.value)


def test_another_runs_settings_are_refused(tmp_path):
    gridmap, settings, path, _ = _good_arrays(tmp_path)
    with pytest.raises(SettingsError, match=r"field settings: alpha is 0.1; this run's is 0.3$"):
        load_checkpoint(path, "cq", gridmap, 0, settings.with_overrides(["alpha=0.3"]))


@pytest.mark.parametrize("damage", ["truncated", "empty", "object-array", "text"])
def test_a_damaged_file_is_one_line(tmp_path, damage):
    gridmap, settings, path, arrays = _good_arrays(tmp_path)
    marker = tmp_path / "ran"
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[:len(path.read_bytes()) // 2])
    elif damage == "empty":
        path.write_bytes(b"")
    elif damage == "object-array":  # a pickle inside the .npz: never unpickled
        buffer = io.BytesIO()
        np.savez(buffer, **{**arrays, "q_local": np.array([Payload(marker)], dtype=object)})
        path.write_bytes(buffer.getvalue())
    else:
        path.write_text("episode: 5\n")
    with pytest.raises(SettingsError) as e:
        load_checkpoint(path, "cq", gridmap, 0, settings)
    assert str(e.value).startswith(f"parameter checkpoint: {str(path)!r}") and "\n" not in str(e.value)
    assert not marker.exists()


def test_a_file_that_unpacks_to_too_much_is_refused_before_it_is_read(tmp_path, monkeypatch):
    import agent_node.checkpoint as checkpoint

    gridmap, settings, path, _ = _good_arrays(tmp_path)
    monkeypatch.setattr(checkpoint, "_MAX_BYTES", 1000)
    with pytest.raises(SettingsError, match=r"agv1.npz' unpacks to [\d,]+ bytes, more than a checkpoint's 1,000$"):
        load_checkpoint(path, "cq", gridmap, 0, settings)


def test_a_good_checkpoint_loads_as_the_learner_it_was(tmp_path):
    gridmap, settings, learner = _trained()
    path = tmp_path / "agv1.npz"
    save_checkpoint(path, learner, 2)
    loaded, episode = load_checkpoint(path, "cq", gridmap, 0, settings)
    assert episode == 2
    assert same_state(loaded, learner)


@pytest.mark.ros
def test_an_old_checkpoint_converts_only_by_the_command_that_says_to_trust_it(tmp_path):
    gridmap, settings, learner = _trained(run_settings(load_map(MAP), ["window=10", "step_cap=100"]))
    old, new = tmp_path / "agv1.pkl", tmp_path / "agv1.npz"
    old.write_bytes(pickle.dumps({"format": 3, "algo": "cq", "map": MAP, "agent": 0, "episode": 2,
                                  "learner": learner}))
    cli = [sys.executable, "-m", "cq_ros.cli", "checkpoint", "convert"]
    done = subprocess.run([*cli, "--help"], capture_output=True, text=True, timeout=60)
    assert "only on a checkpoint you trust" in " ".join(done.stdout.split())
    done = subprocess.run([*cli, str(old), str(new)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    loaded, episode = load_checkpoint(new, "cq", gridmap, 0, settings)
    assert episode == 2
    assert same_state(loaded, learner)
    done = subprocess.run([*cli, str(old), str(new)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "exists" in done.stderr
    old.write_bytes(pickle.dumps({"format": 2, "learner": learner}))
    done = subprocess.run([*cli, str(old), str(tmp_path / "x.npz")], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "format 2" in done.stderr, done.stderr


@pytest.mark.ros
def test_a_crafted_pickle_given_to_an_agent_node_runs_nothing(tmp_path):
    path, marker = tmp_path / "agv1.npz", tmp_path / "ran"
    crafted_pickle(path, marker)
    done = subprocess.run([sys.executable, "-m", "agent_node", "--ros-args", "-p", "agent_id:=1", "-p",
                           f"checkpoint:={path}"], capture_output=True, text=True, timeout=180)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert CONVERT in done.stderr and str(path) in done.stderr
    assert not marker.exists()


@pytest.mark.ros
def test_a_crafted_pickle_to_start_a_launch_from_runs_nothing_and_starts_nothing(tmp_path):
    from ros_tools.launch import launch

    folder, marker = tmp_path / "from", tmp_path / "ran"
    folder.mkdir()
    crafted_pickle(folder / "agv1.npz", marker)
    crafted_pickle(folder / "agv2.npz", marker)
    with pytest.raises(ValueError, match=f"parameter checkpoint: .*agv1.npz.* is a pickle .*{CONVERT}"):
        launch(MAP, "cq", 5, 0, tmp_path / "out", start_from=folder, progress=False)
    assert not marker.exists() and not (tmp_path / "out").exists()


def test_an_episode_beyond_the_run_that_wrote_it_is_refused_where_the_run_is_known(tmp_path):
    gridmap, settings, path, _ = _good_arrays(tmp_path)  # episode 7
    assert load_checkpoint(path, "cq", gridmap, 0, settings, episodes=8)[1] == 7
    with pytest.raises(SettingsError, match=r"field episode: is 7, beyond this run's 7 learning episodes \(0..6\): "
                                            "not a checkpoint of this run$"):
        load_checkpoint(path, "cq", gridmap, 0, settings, episodes=7)


@pytest.mark.parametrize("kind", ["fifo", "folder", "device"])
@pytest.mark.timeout(20)  # open() of a FIFO used to wait for a writer for ever
def test_a_checkpoint_that_is_no_regular_file_is_refused_without_waiting_on_it(tmp_path, kind):
    gridmap, settings, _ = _trained()
    path = {"fifo": tmp_path / "agv1.npz", "folder": tmp_path, "device": "/dev/zero"}[kind]
    if kind == "fifo":
        os.mkfifo(path)
    with pytest.raises(SettingsError) as e:
        load_checkpoint(path, "cq", gridmap, 0, settings)
    what = {"fifo": "a FIFO", "folder": "a folder", "device": "a character device"}[kind]
    assert str(e.value) == (f"parameter checkpoint: {str(path)!r} is {what}, not a regular file: a checkpoint is a "
                            "file cq-ros wrote")


def _restarts(tmp_path, started_from=None, episodes=15):
    """ros_tools.restarts for agv1 of a CQ launch on MAP, its checkpoint path in tmp_path, without ROS."""
    gridmap, settings, _ = _trained()
    path = tmp_path / "agv1.npz"
    nodes = {"world": ("world_node", {}), "agv1": ("agent_node", {"agent_id": 1, "checkpoint": str(path)})}
    listener = SimpleNamespace(world=[0] * 9, episodes=episodes, newest={1: SimpleNamespace(episode=8)},
                               learning_lost={})
    child = SimpleNamespace(name="agv1", describe_exit=lambda: "agv1 (pid 1) exited with code -9")
    restarts = Restarts(nodes, "cq", gridmap, settings, episodes, [1, 2], listener, started_from or {}, RuntimeError)
    return restarts, child, path


def test_a_restart_goes_back_to_its_runs_checkpoint_or_before_the_run_from_the_one_it_started_from(tmp_path):
    restarts, child, path = _restarts(tmp_path)
    assert restarts.loss(child) == "it resumes from a fresh learner (no checkpoint yet): 9 learning episodes lost"
    save_checkpoint(path, _trained()[2], 4)
    assert restarts.loss(child) == "it resumes from its checkpoint of episode 4: 4 learning episodes lost"
    # an offline run's checkpoint of episode 59 that the launch started from: before this run's episode 0,
    # where it used to count as episode 59 of this run of 15, with no learning lost
    save_checkpoint(path, _trained()[2], 59)
    restarts, child, _ = _restarts(tmp_path, {"agv1": file_identity(path)})
    assert restarts.loss(child) == ("it resumes from the checkpoint it started from (none of this run yet): 9 "
                                    "learning episodes lost")
    assert restarts.listener.learning_lost == {"agv1": [{"learnt_to": 8, "resumed_from": -1, "episodes": 9}]}


@pytest.mark.parametrize("damage, reason", [
    ("beyond", r"field episode: is 59, beyond this run's 15 learning episodes"),
    ("fifo", "is a FIFO, not a regular file"),
])
@pytest.mark.timeout(20)
def test_a_restart_from_a_checkpoint_of_no_episode_of_the_run_or_no_file_is_refused_in_one_line(tmp_path, damage,
                                                                                                  reason):
    restarts, child, path = _restarts(tmp_path)
    if damage == "beyond":
        save_checkpoint(path, _trained()[2], 59)  # written by no node of this run: it names no episode of it
    else:
        os.mkfifo(path)
    with pytest.raises(RuntimeError) as e:
        restarts.loss(child)
    assert re.fullmatch(r"agv1 \(pid 1\) exited with code -9 after 9/15 episodes and cannot restart: parameter "
                        rf"checkpoint: '.*agv1.npz'.? {reason}.*", str(e.value)), str(e.value)
    assert restarts.listener.learning_lost == {}


@pytest.mark.ros
@pytest.mark.timeout(60)
def test_a_fifo_given_to_an_agent_node_as_its_checkpoint_is_one_line_not_a_hang(tmp_path):
    path = tmp_path / "agv1.npz"
    os.mkfifo(path)
    done = subprocess.run([sys.executable, "-m", "agent_node", "--ros-args", "-p", "agent_id:=1", "-p",
                           f"checkpoint:={path}"], capture_output=True, text=True, timeout=50)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "is a FIFO, not a regular file" in done.stderr


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize("damage, reason", [
    ("truncated", "cannot read it: BadZipFile"),
    ("pickle", r"is a pickle .* convert it with `cq-ros checkpoint convert .*agv1.npz NEW.npz`"),
    ("nested", "field settings: nested too deeply"),  # a RecursionError traceback once, and no manifest
    ("beyond", "field episode: is 1000000, beyond this run's 400 learning episodes"),  # once "0 episodes lost"
    ("fifo", "is a FIFO, not a regular file"),  # once a launcher blocked in open(), deaf to SIGINT and SIGTERM
])
def test_a_restart_from_a_bad_checkpoint_ends_the_launch_with_the_reason(tmp_path, damage, reason):
    """agv1 killed, its checkpoint cut in half, or replaced by a crafted pickle, a checkpoint of deeply nested
    settings or of an episode past the run's, or a FIFO, meanwhile: the launcher does not restart it into a node
    that would only say why in its log; the launch ends (exit 1) with one line giving the reason, and the pickle
    ran nothing."""
    from test_faults import LAUNCH_TIMEOUT_S, agv1_pid, failed_in_one_line, restarting_launch, stop_launcher, text_of

    out, err = tmp_path / "result", tmp_path / "stderr.txt"
    path = out / "checkpoints" / "agv1.npz"
    launcher = restarting_launch(out, err, 400, 5)
    try:
        pid = agv1_pid(launcher, err)
        wait_until(path.exists, LAUNCH_TIMEOUT_S, "no checkpoint of agv1", ended=lambda: launcher.poll() is not None,
                   detail=lambda: text_of(err))
        os.kill(pid, signal.SIGSTOP)  # no save while the file is cut, then killed
        if damage == "truncated":
            data = path.read_bytes()
            path.write_bytes(data[:len(data) // 2])
        elif damage == "pickle":
            crafted_pickle(path, tmp_path / "ran")
        elif damage == "fifo":
            path.unlink()
            os.mkfifo(path)
        else:
            change = {"nested": {"settings": np.str_("[" * 5000 + "]" * 5000)},
                      "beyond": {"episode": np.int64(10**6)}}[damage]
            _written(path, {**_arrays_of(path), **change})
        os.kill(pid, signal.SIGKILL)
        code = launcher.wait(LAUNCH_TIMEOUT_S)
    finally:
        stop_launcher(launcher)
    line = failed_in_one_line(code, err)
    assert re.search(r"agv1 \(pid \d+\) exited with code -9 .* and cannot restart: parameter checkpoint: "
                     r".*agv1.npz'.? " + reason, line), line
    assert not (tmp_path / "ran").exists()
    assert json.loads((out / "manifest.json").read_text())["ended"]["how"] == "node_failed"

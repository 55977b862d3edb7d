"""Checkpoints are data (agent_node.checkpoint): a crafted pickle runs nothing at any entry point and is refused
naming the command that converts an old checkpoint; every bad file is one line naming the file and the field."""

import io
import pickle
import subprocess
import sys

import numpy as np
import pytest

from agent_node.checkpoint import load_checkpoint, save_checkpoint
from cq_ros.engine import Team, make_learners
from cq_ros.gridmap import load_map
from cq_ros.learners.state import to_arrays
from cq_ros.settings import Settings, SettingsError, run_settings
from cq_ros.world import GridWorld
from helpers import Payload, crafted_pickle

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
    with np.load(path) as npz:
        return gridmap, settings, path, {k: npz[k] for k in npz.files}


@pytest.mark.parametrize("change, field, message", [
    ({"algo": np.str_("str")}, "algo", "unknown algorithm 'str'"),
    ({"episode": np.int64(-5)}, "episode", "holds -5, below its least value 0"),
    ({"episode": np.str_("5")}, "episode", "holds <U1 where it must hold integers"),
    ({"agent": np.int64(7)}, "agent", "holds 7, above its greatest value 1"),
    ({"map": np.str_("cit")}, "map", "is cit; this node runs map tunnel_to_goal"),
    ({"q_local": np.zeros((4, 4))}, "q_local", "has shape (4, 4) where this map and these settings make it (25, 4)"),
    ({"q_local": np.full((25, 4), np.inf)}, "q_local", "holds a value that is not a finite number"),
    ({"rng": np.zeros(3, dtype=np.int64)}, "rng", "has shape (3,)"),
    ({"settings": np.str_("{")}, "settings", "not JSON"),
    ({"checkpoint_format": np.int64(3)}, "checkpoint_format", "is 3; this version reads format 4"),
], ids=["learner-str", "episode-minus-5", "episode-string", "agent", "map", "shape", "inf", "rng", "settings",
        "format"])
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

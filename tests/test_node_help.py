"""`--help` on the node programs (python -m world_node, agent_node, ros_tools.compose): usage and every parameter
with its ROS type, default and description, exit 0, and nothing started (no rclpy context, no node)."""

import os
import re
import subprocess
import sys

import pytest
import rclpy

from node_runtime.parameters import PARAMETERS

PROGRAMS = {"world_node": ("world",), "agent_node": ("agent",), "ros_tools.compose": ("world", "agent")}


@pytest.mark.parametrize("program", PROGRAMS)
def test_help_prints_every_parameter_and_exits_0(program):
    # Bounded by the timeout; without --help each of these would start a node and wait for its peers.
    done = subprocess.run([sys.executable, "-m", program, "--help"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert f"python -m {program} " in done.stdout.split("\n\n")[0] + done.stdout.split("\n\n")[1]  # usage first
    for kind in PROGRAMS[program]:
        section = done.stdout.split(f"Parameters of the {kind} node")[1]
        for name, (default, description) in PARAMETERS[kind].items():
            ros_type = {bool: "bool", int: "integer", float: "double", str: "string"}[type(default)]
            entry = re.search(rf"^  {name} \({ros_type}, default {re.escape(repr(default))}\)\n((?:      .*\n?)+)",
                              section, re.M)
            assert entry, f"{program}: {name}"
            assert " ".join(entry.group(1).split()) == description


@pytest.mark.parametrize("program", PROGRAMS)
def test_help_starts_nothing(program, monkeypatch, capsys):
    """In process: with -h among the arguments (ROS arguments beside it), main returns 0 without rclpy.init."""
    module = __import__(program + ".__main__" if program != "ros_tools.compose" else program, fromlist=["main"])

    def no_init(*args, **kwargs):
        raise AssertionError("--help started ROS")

    monkeypatch.setattr(rclpy, "init", no_init)
    monkeypatch.setattr(sys, "argv", [program, "-h", "--ros-args", "-p", "agent_id:=1"])
    assert module.main() == 0
    assert "Parameters of the" in capsys.readouterr().out


@pytest.mark.parametrize("command", [[*map(str, ("-m", p, "--help"))] for p in PROGRAMS]
                         + [["-m", "cq_ros.cli", "--help"], ["-m", "cq_ros.cli", "launch", "--help"],
                            ["-m", "cq_ros.cli", "maps"]], ids=lambda c: " ".join(c[1:]))
def test_a_reader_that_leaves_early_gets_no_traceback_and_exit_0(command):
    # As `python -m world_node --help | head -1` once the reader has gone: the pipe's read end is closed before
    # the program starts, so its very first write fails (Python ignores SIGPIPE and raises BrokenPipeError).
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        done = subprocess.run([sys.executable, *command], stdout=write_end, stderr=subprocess.PIPE, text=True,
                              timeout=60)
    finally:
        os.close(write_end)
    assert (done.returncode, done.stderr) == (0, "")

"""The packages' layering, read from the source with `ast` (README, "Layout"), bottom-up:

    cq_ros -> msgs_spec -> node_runtime -> world_node, agent_node -> ros_tools

A module imports only packages below its own; world_node and agent_node never import each other; `cq_ros` (the
science) imports no ROS at all, and only its CLI reaches `ros_tools`, inside the functions of the ROS commands;
`msgs_spec`, the wire contract, imports no other package of ours and from rclpy only its QoS. Imports inside
functions count as much as those at the top.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
RANK = {"cq_ros": 0, "msgs_spec": 1, "node_runtime": 2, "world_node": 3, "agent_node": 3, "ros_tools": 4}
ROS = {"rclpy", "rcl_interfaces", "std_msgs", "diagnostic_msgs", "nav_msgs", "visualization_msgs",
       "geometry_msgs", "builtin_interfaces", "rosbags"}
CONTRACT_RCLPY = {"rclpy.qos", "rclpy.serialization"}  # all msgs_spec may take from rclpy: QoS and the wire bytes
CLI = "cq_ros/cli.py"
CLI_MODULES = {CLI, "cq_ros/ros_commands.py"}  # the CLI, its ROS commands in a module of their own


def imports(source: str, package: str) -> list[tuple[str, bool]]:
    """(absolute module name, imported at module level) of every import in `source`, a module of `package`;
    relative imports resolve into `package`."""
    found: list[tuple[str, bool]] = []

    def visit(node: ast.AST, top: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.Import):
                found.extend((alias.name, top) for alias in child.names)
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    found.append((package, top))
                else:
                    found.extend((f"{child.module}.{alias.name}", top) for alias in child.names)
            visit(child, top and not isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    visit(ast.parse(source), True)
    return found


def violations(path: str, source: str) -> list[str]:
    """What a module at `path` (relative to the repository) breaks of the layering, one line each."""
    package = path.split("/")[0]
    rank = RANK.get(package)
    out = []
    for name, top in imports(source, package):
        root = name.split(".")[0]
        where = f"{path} imports {name}"
        if root in RANK and root != package:
            if root == "ros_tools" and rank is not None and path not in CLI_MODULES:
                out.append(f"{where}: only {' and '.join(sorted(CLI_MODULES))}, the tests and the benchmarks import "
                           "ros_tools")
            elif root == "ros_tools" and path in CLI_MODULES and top:
                out.append(f"{where} at module level: the CLI reaches ros_tools only when a ROS command runs")
            elif package == "msgs_spec":
                out.append(f"{where}: the wire contract imports no other package of ours")
            elif rank is not None and root != "ros_tools" and RANK[root] >= rank:
                out.append(f"{where}: {package} may import only packages below it")
        if package == "cq_ros" and root in ROS:
            out.append(f"{where}: cq_ros runs without ROS")
        if package == "msgs_spec" and root == "rclpy" and not any(
                name == allowed or name.startswith(allowed + ".") for allowed in CONTRACT_RCLPY):
            out.append(f"{where}: the wire contract takes only {', '.join(sorted(CONTRACT_RCLPY))} from rclpy")
    return out


def modules() -> list[Path]:
    found = [p for d in [*RANK, "tests", "benchmarks"] for p in sorted((ROOT / d).rglob("*.py"))]
    assert len(found) > 40  # the packages are where this test looks
    return found


def test_every_module_keeps_to_the_layering():
    broken = [line for p in modules()
              for line in violations(p.relative_to(ROOT).as_posix(), p.read_text(encoding="utf-8"))]
    assert broken == []


def test_every_package_of_the_layering_exists_and_is_installed():
    text = (ROOT / "pyproject.toml").read_text()
    for package in RANK:
        assert (ROOT / package / "__init__.py").is_file()
        assert f'"{package}"' in text, f"{package} is not in pyproject.toml's packages"


@pytest.mark.parametrize("path, source, broken", [
    ("msgs_spec/codec.py", "from rclpy.executors import SingleThreadedExecutor", "only rclpy.qos"),
    ("msgs_spec/topics.py", "import cq_ros.settings", "no other package"),
    ("msgs_spec/topics.py", "from node_runtime.run import run_node", "no other package"),
    ("world_node/node.py", "from agent_node.config import agent_config", "only packages below"),
    ("agent_node/node.py", "def f():\n    from world_node import lockstep", "only packages below"),
    ("node_runtime/run.py", "from world_node import WorldNode", "only packages below"),
    ("world_node/node.py", "from ros_tools.launch import launch", "import ros_tools"),
    ("cq_ros/engine.py", "def f():\n    from ros_tools import commands", "import ros_tools"),
    ("cq_ros/cli.py", "from ros_tools.launch import launch", "at module level"),
    ("cq_ros/world.py", "def f():\n    import rclpy", "without ROS"),
    ("cq_ros/world.py", "from msgs_spec import Position", "only packages below"),
])
def test_the_check_catches_each_kind_of_break(path, source, broken):
    lines = violations(path, source)
    assert len(lines) == 1 and broken in lines[0], lines


@pytest.mark.parametrize("path, source", [
    ("cq_ros/cli.py", "def launch():\n    from ros_tools.launch import launch"),
    ("ros_tools/launch.py", "from world_node.lockstep import world_config\nfrom agent_node import AgentNode"),
    ("world_node/lockstep.py", "from .node import WorldNode\nfrom node_runtime.parameters import read_key_parameter"),
    ("msgs_spec/topics.py", "from rclpy.qos import QoSProfile\nfrom std_msgs.msg import Int32MultiArray"),
    ("tests/test_x.py", "from ros_tools.commands import echo"),
    ("benchmarks/bench_x.py", "from ros_tools.launch import launch"),
])
def test_what_the_layering_allows_passes(path, source):
    assert violations(path, source) == []


def test_the_cli_and_the_science_load_without_rclpy():
    probe = ("import sys, cq_ros.cli, cq_ros.engine, cq_ros.experiment, cq_ros.render; "
             "print(sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'ros_tools', 'msgs_spec')))")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"

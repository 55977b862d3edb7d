"""The packages' layering, read from the source with `ast` (README, "Layout"), bottom-up:

    cq_ros (the science) -> cq_ros.lab -> cq_ros.envs, cq_ros.cli;  cq_ros -> msgs_spec -> node_runtime
        -> world_node, agent_node -> ros_tools

A module imports only packages below its own; world_node and agent_node never import each other; the science
(cq_ros outside lab/, envs/ and cli/) imports no lab, envs, CLI, ROS, plotting, argument parsing or cluster code;
the lab imports no CLI and no envs; the envs (the PettingZoo interface) import no CLI and draw their
`rgb_array` frames with the lab's renderer, not with a plotting library of their own; only the CLI's ROS
commands reach `ros_tools`, inside their functions; `msgs_spec`, the wire contract, imports no other package
of ours and from rclpy only its serializer, inside the functions that read bytes; the cores of the two nodes
and the contract's payloads and codec load no rclpy at all. Imports inside functions count as much as those at
the top, and no module imports itself back through others (no import cycle, lazy imports included).
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
CONTRACT_RCLPY = {"rclpy.serialization"}  # all msgs_spec may take from rclpy: the wire bytes (its QoS is plain data)
CLI_MODULES = {"cq_ros/cli/main.py", "cq_ros/cli/ros.py", "cq_ros/cli/offline.py"}  # the CLI modules that may
# reach ros_tools, inside a ROS command: the dispatch, the ROS commands, and `render --bag`
# What the science leaves to the lab and the CLI: plots, argument parsing, clusters, progress bars.
NOT_SCIENCE = {"matplotlib", "argparse", "dask", "distributed", "tqdm", "foxglove"}


def layer(path: str) -> str | None:
    """'science', 'lab', 'envs' or 'cli' for a module of cq_ros, else None."""
    parts = path.split("/")
    if parts[0] != "cq_ros":
        return None
    return parts[1] if len(parts) > 2 and parts[1] in ("lab", "envs", "cli") else "science"


def module_name(path: str) -> str:
    """'cq_ros.lab.experiment' for 'cq_ros/lab/experiment.py', 'cq_ros.lab' for its __init__.py."""
    name = path.removesuffix(".py").replace("/", ".")
    return name.removesuffix(".__init__")


def imports(source: str, path: str) -> list[tuple[str, bool]]:
    """(absolute name, imported at module level) of every import in `source`, the module at `path`: a name as
    imported (`from a.b import c` gives a.b.c, which may be a module or a name in a.b); relative imports
    resolve against the module's own package. Imports under `if TYPE_CHECKING:` never run and do not count."""
    found: list[tuple[str, bool]] = []
    package = module_name(path).split(".")
    if not path.endswith("__init__.py"):
        package = package[:-1]

    def visit(node: ast.AST, top: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and ast.unparse(child.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING"):
                continue  # for annotations only: never imported at run time
            if isinstance(child, ast.Import):
                found.extend((alias.name, top) for alias in child.names)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    base = ".".join(package[:len(package) - child.level + 1] + ([base] if base else []))
                found.extend((f"{base}.{alias.name}", top) for alias in child.names)
            visit(child, top and not isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    visit(ast.parse(source), True)
    return found


def violations(path: str, source: str) -> list[str]:
    """What a module at `path` (relative to the repository) breaks of the layering, one line each."""
    package = path.split("/")[0]
    rank = RANK.get(package)
    out = []
    for name, top in imports(source, path):
        root = name.split(".")[0]
        where = f"{path} imports {name}"
        into = layer(name.replace(".", "/") + "/x.py") if root == "cq_ros" else None
        if layer(path) == "science" and (into in ("lab", "envs", "cli") or root in NOT_SCIENCE):
            out.append(f"{where}: the science imports no lab, envs, CLI, plotting, parsing or cluster code")
        elif layer(path) == "lab" and into in ("envs", "cli"):
            out.append(f"{where}: the lab imports no envs and no CLI")
        elif layer(path) == "envs" and (into == "cli" or root in NOT_SCIENCE):
            out.append(f"{where}: the envs import no CLI, and draw with the lab's renderer, not a plotting library")
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


def import_graph(sources: dict[str, str]) -> dict[str, set[str]]:
    """Module -> the project modules it imports (lazily or not), from {path: source}: an imported name resolves
    to the longest of its prefixes that is one of the modules."""
    names = {module_name(path) for path in sources}
    graph: dict[str, set[str]] = {}
    for path, source in sources.items():
        edges = graph.setdefault(module_name(path), set())
        for name, _top in imports(source, path):
            parts = name.split(".")
            found = next((".".join(parts[:k]) for k in range(len(parts), 0, -1) if ".".join(parts[:k]) in names), None)
            if found is not None and found != module_name(path):
                edges.add(found)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles of `graph`: each strongly connected component of more than one module, sorted (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_module_imports_itself_back():
    sources = {p.relative_to(ROOT).as_posix(): p.read_text(encoding="utf-8") for p in modules()
               if p.relative_to(ROOT).parts[0] in RANK}
    assert cycles(import_graph(sources)) == []


def test_the_cycle_check_sees_a_lazy_cycle():
    sources = {"cq_ros/lab/runner.py": "def f():\n    from .cluster import dask_backend",
               "cq_ros/lab/cluster.py": "from .runner import Backend",
               "cq_ros/lab/summary.py": "from .runner import Backend"}
    assert cycles(import_graph(sources)) == [["cq_ros.lab.cluster", "cq_ros.lab.runner"]]


def test_every_package_of_the_layering_exists_and_is_installed():
    import tomllib

    from setuptools import find_packages

    include = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]["include"]
    found = set(find_packages(str(ROOT), include=include))
    for package in RANK:
        assert (ROOT / package / "__init__.py").is_file()
        assert package in found, f"{package} is not among the packages pyproject.toml's find includes"


@pytest.mark.parametrize("path, source, broken", [
    ("msgs_spec/codec.py", "from rclpy.executors import SingleThreadedExecutor", "only rclpy.serialization"),
    ("msgs_spec/topics.py", "from rclpy.qos import QoSProfile", "only rclpy.serialization"),
    ("msgs_spec/topics.py", "import cq_ros.settings", "no other package"),
    ("msgs_spec/topics.py", "from node_runtime.run import run_node", "no other package"),
    ("world_node/node.py", "from agent_node.config import agent_config", "only packages below"),
    ("agent_node/node.py", "def f():\n    from world_node import lockstep", "only packages below"),
    ("node_runtime/run.py", "from world_node import WorldNode", "only packages below"),
    ("world_node/node.py", "from ros_tools.launch import launch", "import ros_tools"),
    ("cq_ros/engine.py", "def f():\n    from ros_tools import commands", "import ros_tools"),
    ("cq_ros/cli/main.py", "from ros_tools.launch import launch", "at module level"),
    ("cq_ros/world.py", "def f():\n    import rclpy", "without ROS"),
    ("cq_ros/world.py", "from msgs_spec import Position", "only packages below"),
    ("cq_ros/engine.py", "def f():\n    from .lab.plots import write_figures", "the science imports no lab"),
    ("cq_ros/stats.py", "import matplotlib.pyplot as plt", "the science imports no lab"),
    ("cq_ros/learners/cq.py", "from ..cli.main import main", "the science imports no lab"),
    ("cq_ros/lab/summary.py", "from ..cli.offline import print_summary", "the lab imports no envs and no CLI"),
    ("cq_ros/lab/render.py", "from ..envs.pettingzoo_env import GridWorldEnv", "the lab imports no envs"),
    ("cq_ros/world.py", "def f():\n    from .envs import pettingzoo_env", "the science imports no lab, envs"),
    ("cq_ros/envs/pettingzoo_env.py", "def f():\n    import matplotlib", "draw with the lab's renderer"),
    ("cq_ros/envs/pettingzoo_env.py", "from ..cli.main import main", "the envs import no CLI"),
])
def test_the_check_catches_each_kind_of_break(path, source, broken):
    lines = violations(path, source)
    assert len(lines) == 1 and broken in lines[0], lines


@pytest.mark.parametrize("path, source", [
    ("cq_ros/cli/main.py", "def launch():\n    from ros_tools.launch import launch"),
    ("ros_tools/launch.py", "from world_node.lockstep import world_config\nfrom agent_node import AgentNode"),
    ("world_node/lockstep.py", "from .node import WorldNode\nfrom node_runtime.parameters import read_key_parameter"),
    ("msgs_spec/stats.py", "from std_msgs.msg import Int32MultiArray\ndef f():\n    import rclpy.serialization"),
    ("tests/test_x.py", "from ros_tools.commands import echo"),
    ("cq_ros/lab/plots.py", "import matplotlib\nfrom ..gridmap import load_map"),
    ("cq_ros/cli/offline.py", "from ..lab.experiment import experiment\nfrom ..settings import Settings"),
    ("cq_ros/envs/pettingzoo_env.py", "from ..world import GridWorld\ndef f():\n    from ..lab.render import Picture"),
    ("benchmarks/bench_x.py", "from ros_tools.launch import launch"),
])
def test_what_the_layering_allows_passes(path, source):
    assert violations(path, source) == []


def test_the_cli_and_the_science_load_without_rclpy():
    probe = ("import sys, cq_ros.cli.main, cq_ros.engine, cq_ros.lab.experiment, cq_ros.lab.render; "
             "print(sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'ros_tools', 'msgs_spec')))")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


# The cores, the nodes' decoding into their payloads, and the contract's payloads and codec: pure Python over the
# messages' types, run and tested without a ROS context; the nodes and node_runtime.qos are where rclpy comes in.
ROS_FREE = ("world_node.lockstep", "agent_node.driver", "world_node.wire_reading", "agent_node.wire_reading",
            "msgs_spec", "msgs_spec.payloads", "msgs_spec.codec", "msgs_spec.arrays", "msgs_spec.stats",
            "msgs_spec.checks", "msgs_spec.errors", "msgs_spec.auth", "msgs_spec.topics")


def test_the_cores_and_the_contracts_codec_load_no_rclpy():
    probe = f"import sys, {', '.join(ROS_FREE)}; print('rclpy' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False"
    # the probe can see rclpy come in: a node does load it
    done = subprocess.run([sys.executable, "-c", probe.replace("import sys,", "import sys, world_node.node,")],
                          capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert done.stdout.strip() == "True", done.stderr


# rclpy's handles are its C objects behind a publisher, a subscription or a node: what reaches them works
# around rclpy from pip and says why, in one module.
HANDLE_HOME = "node_runtime/rclpy_workarounds.py"


def handle_uses(source: str) -> list[int]:
    """The lines of `source` that read a `.handle` attribute."""
    return [node.lineno for node in ast.walk(ast.parse(source)) if isinstance(node, ast.Attribute)
            and node.attr == "handle"]


def test_only_the_rclpy_workarounds_touch_an_rclpy_handle():
    touching = [f"{p.relative_to(ROOT).as_posix()}:{line}" for p in modules()
                if p.relative_to(ROOT).as_posix() != HANDLE_HOME for line in handle_uses(p.read_text(encoding="utf-8"))]
    assert touching == []
    assert handle_uses((ROOT / HANDLE_HOME).read_text(encoding="utf-8"))  # where handles are touched, it sees them
    assert handle_uses("with sub.handle:\n    pass") == [1]


HEAVY = ("scipy", "matplotlib", "dask", "distributed", "rclpy", "foxglove")


@pytest.mark.parametrize("argv", [["--help"], ["maps"], ["settings"]])
def test_a_quick_command_loads_no_heavy_library(argv):
    """`cq-ros --help` and the listing commands start in a fraction of a second: nothing they do needs the t
    quantiles, the plots, a cluster, ROS or a viewer."""
    probe = (f"import sys\nfrom cq_ros.cli.main import main\ntry:\n    main({argv!r})\nexcept SystemExit:\n    pass\n"
             f"print(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r})), file=sys.stderr)")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert done.stderr.strip().splitlines()[-1] == "[]"

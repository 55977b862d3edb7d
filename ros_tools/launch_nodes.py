"""The nodes of one launch and their command lines: `--set` split into Settings and node parameters (checked by
the nodes' own rules before anything starts), each node's parameters (node name -> (module, parameters)), and a
process per node or one container (ros_tools.compose) reading the system's params.yaml.
"""

from __future__ import annotations

import os
import sys
from dataclasses import fields
from pathlib import Path
from typing import Any

import yaml

from agent_node.checkpoint import SUFFIX as CHECKPOINT_SUFFIX
from agent_node.config import agent_config
from cq_ros.gridmap import GridMap, load_map
from cq_ros.learners import LEARNERS
from cq_ros.settings import Settings, SettingsError, coerce, run_settings, split_pair
from msgs_spec import agent_namespace
from msgs_spec.auth import new_run
from node_runtime.parameters import AGENT_PARAMETERS, WORLD_PARAMETERS, check_names
from world_node.lockstep import world_config

from .children import Child
from .params_file import LAUNCH_ONLY, SYSTEM_FILE, write_system

__all__ = ["STARTUP_TIMEOUT_S", "SETTABLE", "split_sets", "check_node_parameters", "agent_nodes", "startup_wait",
           "node_specs", "node_commands", "compose_command"]

STARTUP_TIMEOUT_S = 30.0  # the world's startup_timeout: every child discovered by then, or the world exits 1
STARTUP_PER_NODE_S = 4.0  # ... or this many seconds per node where that is longer (`startup_wait`)
CHECKPOINT_EVERY = 50
# Node parameters the launcher fixes itself (from its own options, or as its children need them).
LAUNCHER_OWNS = {"map", "episodes", "seed", "run", "algo", "agent_id", "checkpoint", "min_stats_subscribers",
                 "key_file", "run_nonce"}
_SETTINGS = {f.name for f in fields(Settings)}
# name -> default: the node parameters `--set` may change, beside the Settings fields.
SETTABLE = {name: default for params in (WORLD_PARAMETERS, AGENT_PARAMETERS)
            for name, (default, _) in params.items() if name not in LAUNCHER_OWNS | _SETTINGS}


def split_sets(pairs: list[str], gridmap: GridMap) -> tuple[Settings, dict[str, Any]]:
    """`--set key=value` pairs -> (the run's Settings on `gridmap`, node parameter -> typed value); SettingsError
    names a bad one (an unknown key with the closest known one)."""
    settings, node = [], {}
    for pair in pairs:
        key, value = split_pair(pair)
        if key in _SETTINGS:
            settings.append(pair)
        elif key in SETTABLE:
            default = SETTABLE[key]
            if isinstance(default, bool):  # markers=false
                if value.lower() not in ("true", "false"):
                    raise SettingsError(f"setting {key} takes true or false, got {value!r}")
                node[key] = value.lower() == "true"
            else:
                node[key] = value if isinstance(default, str) else coerce(key, value, type(default))
        elif key in LAUNCHER_OWNS:
            raise SettingsError(f"setting {key} is fixed by cq-ros launch (see cq-ros launch --help)")
        else:
            check_names([key], _SETTINGS | SETTABLE.keys(), what="setting")
    return run_settings(gridmap, settings), node


def check_node_parameters(map_name: str, algo: str, settings: Settings, node: dict[str, Any]) -> None:
    """The nodes' own checks on what a launch hands them, before any process starts."""
    common = {"map": str(map_name), **settings.as_dict(), **node}
    world_config({**{k: d for k, (d, _) in WORLD_PARAMETERS.items()},
                  **{k: v for k, v in common.items() if k in WORLD_PARAMETERS}})
    agent_config({**{k: d for k, (d, _) in AGENT_PARAMETERS.items()}, "algo": algo,
                  "agent_id": 0 if LEARNERS[algo].central else 1,
                  **{k: v for k, v in common.items() if k in AGENT_PARAMETERS}})


def _param(value: Any) -> str:
    """A parameter value as ROS parses it back into the declared type: floats always with a point or exponent."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(float(value)) if isinstance(value, float) else str(value)


def agent_nodes(gridmap: GridMap, algo: str) -> list[tuple[str, dict[str, int]]]:
    """The agent nodes of a launch: (node name, its agent_id parameter, if any)."""
    if LEARNERS[algo].central:
        return [("jsa", {})]  # one node moves every AGV; agent_id stays 0
    return [(agent_namespace(k), {"agent_id": k}) for k in range(1, gridmap.n_agents + 1)]


def startup_wait(nodes: int) -> float:
    """The world's startup_timeout for a launch of `nodes` nodes, and the least feedback_timeout of its agents:
    STARTUP_TIMEOUT_S, or STARTUP_PER_NODE_S per node where that is longer. Every node must be up and matched
    before the first step, and on a busy 2-core machine a node process takes seconds of CPU to start (Python,
    rclpy, numpy) and discovery grows with the graph: warehouse_32's 33 processes did not all match within 30 s
    (benchmarks/bench_startup.py). An agent started early hears nothing of the world meanwhile, so its
    patience grows alike."""
    return max(STARTUP_TIMEOUT_S, STARTUP_PER_NODE_S * nodes)


def node_specs(map_name: str, algo: str, episodes: int, seed: int, settings: Settings, out: Path,
               step_timeout: float, peer_linger_steps: int | None = None,
               node_parameters: dict[str, Any] | None = None,
               key_file: Path | None = None) -> dict[str, tuple[str, dict[str, Any]]]:
    """The nodes of one launch: node name -> (its module, its parameters), the world first, then the agent
    node(s). Every setting that differs from its default on this map (Settings' or the map's own) goes to
    both, every node parameter (`node_parameters`, from `--set`) to the nodes that take it. The world and every
    agent wait for the launcher's statistics subscription (min_stats_subscribers 1): a statistics writer keeps
    only its last 1000 for a listener that matches late."""
    gridmap = load_map(map_name)
    defaults = run_settings(gridmap)
    changed = {f.name: getattr(settings, f.name) for f in fields(Settings)
               if getattr(settings, f.name) != getattr(defaults, f.name)}
    # A map file by its absolute path, so that the system file (params.yaml) starts it from anywhere.
    where = Path(map_name)
    map_ref = str(where.resolve()) if isinstance(map_name, os.PathLike) or where.suffix == ".txt" or \
        len(where.parts) > 1 else str(map_name)
    common = {"map": map_ref, "episodes": episodes, "seed": seed, "run": 0,
              **({"key_file": str(key_file), "run_nonce": new_run()} if key_file else {})}
    node_parameters = node_parameters or {}
    to_world = {k: v for k, v in node_parameters.items() if k in WORLD_PARAMETERS}
    to_agents = {k: v for k, v in node_parameters.items() if k in AGENT_PARAMETERS}
    agents = agent_nodes(gridmap, algo)
    wait = startup_wait(1 + len(agents))
    nodes = {"world": ("world_node", {**common, "step_timeout": float(step_timeout), "startup_timeout": wait,
                                      "min_stats_subscribers": 1, **to_world, **changed})}
    linger = {} if peer_linger_steps is None else {"peer_linger_steps": peer_linger_steps}
    patience = {"feedback_timeout": wait} if wait > AGENT_PARAMETERS["feedback_timeout"][0] else {}
    for name, ident in agents:
        nodes[name] = ("agent_node", {
            **ident, "algo": algo, **common,
            "checkpoint": str(out.resolve() / "checkpoints" / (name + CHECKPOINT_SUFFIX)),
            "checkpoint_every": CHECKPOINT_EVERY, "min_stats_subscribers": 1, **linger, **patience, **to_agents,
            **changed})
    return nodes


# File logging off: each child's console output is its log (DIR/logs/<node>.log), in one place.
def _ros_args(namespace: str) -> list[str]:
    return ["--ros-args", "--disable-external-lib-logs", "-r", f"__ns:=/{namespace}"]


def node_commands(nodes: dict[str, tuple[str, dict[str, Any]]], namespace: str, out: Path) -> list[Child]:
    """A process per node (`python -m world_node|agent_node`), the world first, with the command lines fixed
    by world_node and agent_node (__main__)."""
    children = []
    for name, (module, params) in nodes.items():
        rename = [] if module == "world_node" else ["-r", f"__node:={name}"]
        values = [arg for k, v in params.items() for arg in ("-p", f"{k}:={_param(v)}")]
        children.append(Child(name, [sys.executable, "-m", module, *_ros_args(namespace), *rename, *values],
                              out / "logs" / f"{name}.log"))
    return children


def compose_command(nodes: dict[str, tuple[str, dict[str, Any]]], namespace: str, out: Path,
                    launch_only: frozenset[str] = LAUNCH_ONLY) -> Child:
    """Every node in one process (`python -m ros_tools.compose`), reading the system's DIR/params.yaml
    (ros_tools.params_file) and then what is this launch's alone (`launch_only`: checkpoints, listeners, a
    temporary key) from DIR/logs/launch_params.yaml, both written here."""
    system = write_system(out / SYSTEM_FILE, nodes, launch_only)
    own = {f"/**/{name}": {"ros__parameters": {k: v for k, v in values.items() if k in launch_only}}
           for name, (_, values) in nodes.items()}
    (out / "logs").mkdir(parents=True, exist_ok=True)
    launch_file = out / "logs" / "launch_params.yaml"
    launch_file.write_text(yaml.safe_dump(own, sort_keys=False))
    return Child("container", [sys.executable, "-m", "ros_tools.compose", *nodes, *_ros_args(namespace),
                               "--params-file", str(system), "--params-file", str(launch_file)],
                 out / "logs" / "container.log")

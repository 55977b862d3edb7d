"""A system in a file: the `params.yaml` every `cq-ros launch` writes into its result directory, in ROS 2's own
parameters-file layout, and its reading back by `cq-ros launch --params-file FILE`.

Its keys are wildcards, so it starts the same system under any namespace: `/**` holds what every node of the
system is given alike (the map, episodes, seed, the settings that differ from the map's, ...), and one `/**/<node>`
section per node (`/**/world`, `/**/agv1`, ... or `/**/jsa`) what is that node's own. (A bare `agv1:` key would
name the node /agv1 only: rcl matches keys against the fully qualified name.) What belongs to one launch, not to
the system (the checkpoint paths inside its result directory, how many statistics listeners to wait for, the
launch's own temporary key), is left out; the launcher hands it to its nodes beside the file. A key that must
outlive a launch is made with `cq-ros key --out FILE`; a file that names it (key_file) keeps it.

    python -m ros_tools.compose world agv1 agv2 --ros-args -r __ns:=/any --params-file DIR/params.yaml
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from cq_ros.learners import LEARNERS
from cq_ros.settings import SettingsError
from msgs_spec import KeyFileError, write_key_file
from node_runtime.parameters import PARAMETERS, SETTING_NAMES, check_names, ros_type

__all__ = ["ALL_NODES", "SYSTEM_FILE", "SystemFile", "SystemFileError", "system_params", "write_system",
           "read_system", "make_key"]

SYSTEM_FILE = "params.yaml"
ALL_NODES = "/**"
_NODE = "/**/"
# Parameters of one launch rather than of the system (see the module docstring).
# run_nonce: fresh for every launch (a kept one would let a run's messages be replayed into the next)
LAUNCH_ONLY = frozenset({"checkpoint", "min_stats_subscribers", "run_nonce"})
_HEADER = ("# A cq_ros system in ROS 2's parameters-file layout (ros_tools/params_file.py): start it again under\n"
           "# any namespace with `cq-ros launch --params-file {name}` or by hand, e.g.\n"
           "# python -m ros_tools.compose {nodes} --ros-args -r __ns:=/NAME --params-file {name}\n")


class SystemFileError(ValueError):
    """A parameters file that does not describe a system cq-ros launch can start; one line naming file and key."""


def system_params(nodes: dict[str, tuple[str, dict[str, Any]]], launch_only: frozenset[str] = LAUNCH_ONLY) -> dict:
    """The ROS parameters-file dict of `nodes` (name -> (module, parameters), as ros_tools.launch_nodes.node_specs
    makes them) without the parameters in `launch_only`: what all nodes share under `/**`, the rest under
    `/**/<name>`."""
    own = {name: {k: v for k, v in params.items() if k not in launch_only} for name, (_, params) in nodes.items()}
    first, *others = own.values()
    shared = {k: v for k, v in first.items() if all(k in o and o[k] == v for o in others)}
    sections = {ALL_NODES: {"ros__parameters": shared}}
    for name, params in own.items():
        rest = {k: v for k, v in params.items() if k not in shared}
        sections[_NODE + name] = {"ros__parameters": rest}
    return sections


def write_system(path: Path, nodes: dict[str, tuple[str, dict[str, Any]]],
                 launch_only: frozenset[str] = LAUNCH_ONLY) -> Path:
    """`path` holding system_params(nodes, launch_only), headed by how to start it."""
    header = _HEADER.format(name=path.name, nodes=" ".join(nodes))
    path.write_text(header + yaml.safe_dump(system_params(nodes, launch_only), sort_keys=False))
    return path


@dataclass(frozen=True)
class SystemFile:
    """What a system file says, as the arguments of ros_tools.launch.launch."""

    map: str
    algo: str
    episodes: int
    seed: int
    settings: dict[str, Any]  # Settings fields the file gives (over the map's own defaults)
    node_parameters: dict[str, Any]  # the other node parameters it gives
    key_file: Path | None
    nodes: tuple[str, ...]


def read_system(path: str | os.PathLike) -> SystemFile:
    """The system `path` describes; SystemFileError naming the file and the key at fault."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as e:
        raise SystemFileError(f"{path}: cannot read: {e.strerror or e}") from None
    except yaml.YAMLError as e:
        raise SystemFileError(f"{path}: not YAML: {str(e).splitlines()[0]}") from None
    if not isinstance(data, dict) or ALL_NODES not in data:
        raise SystemFileError(f"{path}: expected a ROS parameters file with a `{ALL_NODES}:` section "
                              "(as cq-ros launch writes params.yaml)")
    sections: dict[str, dict[str, Any]] = {}
    for key, section in data.items():
        params = section.get("ros__parameters") if isinstance(section, dict) else None
        if not isinstance(params, dict):
            raise SystemFileError(f"{path}: section {key!r} has no `ros__parameters:` mapping")
        if key != ALL_NODES and not key.startswith(_NODE):
            raise SystemFileError(f"{path}: section {key!r}: expected `{ALL_NODES}` or `{_NODE}<node>` (a key "
                                  "without the wildcard ties the file to one namespace)")
        sections[key.removeprefix(_NODE) if key != ALL_NODES else key] = params
    shared = sections.pop(ALL_NODES)
    nodes = tuple(sections)
    if "world" not in nodes or len(nodes) < 2:
        raise SystemFileError(f"{path}: expected sections `{_NODE}world` and one per agent node, got {list(nodes)}")
    merged = {name: {**shared, **params} for name, params in sections.items()}
    for name, params in merged.items():
        for key in sorted(LAUNCH_ONLY & params.keys()):
            raise SystemFileError(f"{path}: {name}: parameter {key} is set by the launcher for each launch; "
                                  "remove it")

    def one(key: str, kind: type, among: tuple[str, ...] = nodes) -> Any:
        values = [merged[name].get(key) for name in among]
        if any(v != values[0] for v in values) or values[0] is None:
            raise SystemFileError(f"{path}: parameter {key} must be given once, the same for every node "
                                  f"(under `{ALL_NODES}`), got {values}")
        if type(values[0]) is not kind:
            raise SystemFileError(f"{path}: parameter {key} must be a {kind.__name__}, got {values[0]!r}")
        return values[0]

    try:
        check_names({k for params in merged.values() for k in params}, {k for t in PARAMETERS.values() for k in t})
    except SettingsError as e:
        raise SystemFileError(f"{path}: {e}") from None
    # ROS types parameters strictly (an integer is no double): a wrong type would start every node and stop
    # them seconds later with the reason in one node's log, so it is refused here, before anything starts.
    declared = {key: default for table in PARAMETERS.values() for key, (default, _) in table.items()}
    for name, params in merged.items():
        for key in sorted(declared.keys() & params.keys()):
            if type(params[key]) is not type(declared[key]):
                raise SystemFileError(f"{path}: {name}: parameter {key} has ROS type {ros_type(declared[key])} "
                                      f"(like {declared[key]!r}): got {params[key]!r}")
    for name, params in sections.items():
        for key in sorted(SETTING_NAMES & params.keys()):
            raise SystemFileError(f"{path}: {name}: setting {key} applies to every node: give it under `{ALL_NODES}`")
    algo = one("algo", str, tuple(n for n in nodes if n != "world"))
    if algo not in LEARNERS:
        raise SystemFileError(f"{path}: parameter algo: unknown algorithm {algo!r}; choose from {', '.join(LEARNERS)}")
    if merged["world"].get("run", 0) != 0:
        raise SystemFileError(f"{path}: parameter run must be 0 for cq-ros launch, got {merged['world']['run']!r}")
    key_file = shared.get("key_file") or None
    fixed = {"map", "episodes", "seed", "run", "algo", "agent_id", "key_file"}
    settings = {k: v for k, v in shared.items() if k in SETTING_NAMES}
    node_parameters = {k: v for params in sections.values() for k, v in params.items() if k not in fixed}
    node_parameters.update({k: v for k, v in shared.items() if k not in fixed | SETTING_NAMES})
    return SystemFile(one("map", str), algo, one("episodes", int), one("seed", int), settings, node_parameters,
                      Path(key_file) if key_file else None, nodes)


def make_key(path: str | os.PathLike) -> Path:
    """`cq-ros key --out FILE`: a new key file for a system kept in a parameters file (msgs_spec.auth; mode
    0600, never overwritten); SystemFileError naming the file otherwise."""
    try:
        return write_key_file(path)
    except KeyFileError as e:
        raise SystemFileError(str(e)) from None

"""`cq-ros collect`: the results of a system started by hand (python -m world_node / agent_node, or
ros_tools.compose), written as a launch writes them (episodes.csv, greedy.csv, observe.csv, manifest.json).

It finds the system on the domain (the namespace of its one `world` node, unless given), asks the world and an
agent node for their parameters over ROS's parameter services (map, episodes, seed, the settings given, the
algorithm), then listens to world/stats and every agv<k>/stats with the launcher's own StatsListener until
every episode is in (the world's `run_nonce`, when it was given one, is the only run whose statistics count:
a recording of an earlier run is `dropped.other_run`; conflicting ones are named, as a launch names them),
and writes through the launcher's writer (ros_tools.launch_results.write_heard). A statistics
writer keeps its last 1000 for a reader that comes late; to be sure of every episode, start collect before
the run's first step, e.g. with -p min_stats_subscribers:=1 on the nodes, which then wait for it (the world
before its first step, an agent before it sends its statistics).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any

import rclpy

from cq_ros.lab.results import prepare_output
from cq_ros.gridmap import load_map
from cq_ros.learners import LEARNERS
from node_runtime.parameters import SETTING_NAMES
from cq_ros.settings import run_settings

from .session import FIND_S, WORLD, StopSignals, ToolError, environment_domain, find_system, ros_session, spin_until
from .launch_end import Interrupted, LaunchError
from .launch_nodes import agent_nodes
from .launch_results import StatsListener, write_heard
from .progress import Progress

__all__ = ["CollectError", "collect"]

PARAMETERS_S = 10.0  # how long to wait for a node's parameter service
GONE_S = 2.0  # how long the world node may be missing from the graph before its statistics are given up


class CollectError(LaunchError):
    """The system was not found, or its statistics did not all come; one line."""


def node_parameters(node: Any, executor: Any, fqn: str, names: list[str], stop: StopSignals) -> dict[str, Any]:
    """The values of parameters `names` of node `fqn`, those declared without a value (settings left to the
    map) left out: their types first, since rclpy answers a request naming one of those with no value at all."""
    from rcl_interfaces.msg import ParameterType
    from rclpy.parameter import parameter_value_to_python
    from rclpy.parameter_client import AsyncParameterClient

    client = AsyncParameterClient(node, fqn)
    if not spin_until(executor, client.services_are_ready, PARAMETERS_S, stop):
        raise CollectError(f"{fqn} answers no parameter request after {PARAMETERS_S:g} s")

    def ask(request: Any) -> Any:
        if not spin_until(executor, request.done, PARAMETERS_S, stop) or request.result() is None:
            raise CollectError(f"{fqn} did not give its parameters within {PARAMETERS_S:g} s")
        return request.result()

    types = ask(client.get_parameter_types(names)).types
    given = [name for name, kind in zip(names, types) if kind != ParameterType.PARAMETER_NOT_SET]
    values = ask(client.get_parameters(given)).values
    if len(values) != len(given):
        raise CollectError(f"{fqn} did not give parameters {', '.join(given)}")
    return {name: parameter_value_to_python(v) for name, v in zip(given, values)}


def collect(out: str | Path, *, domain_id: int | None = None, namespace: str | None = None, force: bool = False,
            progress: bool = True, wait_s: float = FIND_S, episodes_timeout: float | None = None) -> Path:
    """Listen to the system on the domain and write its results to `out` (see the module docstring);
    CollectError (or Interrupted, a LaunchError, on Ctrl-C) before anything is written otherwise.
    `wait_s`: how long to look for the system; `episodes_timeout`: give up when no new episode came for that long
    (None: wait for every one)."""
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not force:
        prepare_output(out, force)  # the same one-line refusal as a launch, before any waiting
    namespace = None if namespace is None else "/" + namespace.strip("/")
    with StopSignals() as stop, ros_session("collect", domain_id=domain_id) as (node, executor):
        if progress:
            print(f"cq-ros collect: looking for a system on {f'namespace {namespace}' if namespace else 'the domain'}"
                  f" (at most {wait_s:g} s)", file=sys.stderr, flush=True)
        try:
            ns, agents = find_system(node, executor, namespace, stop, wait_s)
        except ToolError as e:
            raise CollectError(str(e)) from None
        world = node_parameters(node, executor, f"{ns.rstrip('/')}/{WORLD}",
                                ["map", "episodes", "seed", "run_nonce", *sorted(SETTING_NAMES)], stop)
        agent = node_parameters(node, executor, f"{ns.rstrip('/')}/{agents[0]}", ["algo"], stop)
        gridmap = load_map(world["map"])
        settings = run_settings(gridmap, {k: v for k, v in world.items() if k in SETTING_NAMES})
        algo, episodes = agent["algo"], world["episodes"]
        # The system's agent nodes are the map's (agv1..agvN, or jsa), not those discovered so far: a process
        # per node is often seen one at a time, and the manifest names each learner's statistics by its node.
        agents = [name for name, _ in agent_nodes(gridmap, algo)]
        # The statistics topics are relative to the system's namespace: the listener's node lives there.
        here = rclpy.create_node(f"_collect_{os.getpid()}", namespace=ns, context=node.context, enable_rosout=False,
                                 start_parameter_services=False)
        executor.add_node(here)
        try:
            return _listen(here, executor, stop, out, force, progress, episodes_timeout, ns, agents, gridmap, algo,
                           episodes, world["seed"], settings, domain_id, world.get("run_nonce") or None)
        finally:
            executor.remove_node(here)
            here.destroy_node()


def _listen(node: Any, executor: Any, stop: StopSignals, out: Path, force: bool, progress: bool,
            episodes_timeout: float | None, ns: str, agents: list[str], gridmap: Any, algo: str, episodes: int,
            seed: int, settings: Any, domain_id: int | None, run: int | None) -> Path:
    """Every episode's statistics of the system in `ns` heard through `node`, then the result files; given the
    world's `run` nonce, only statistics sealed to that run count."""
    total = episodes + settings.eval_episodes
    learners = [1] if LEARNERS[algo].central else list(range(1, gridmap.n_agents + 1))
    listener = StatsListener(node, gridmap, total, run=run)
    label = f"{gridmap.name} {algo}"
    if progress:
        print(f"cq-ros collect: {label} in {ns}, {len(agents)} agent node(s), {total} episodes", file=sys.stderr,
              flush=True)
    bar = Progress(label, total, episodes, progress)
    started = last = look_at = time.monotonic()
    gone = None
    try:
        while not listener.complete:
            if stop:
                raise Interrupted(f"interrupted by {stop.received} after {len(listener.world)}/{total} episodes; "
                                  "nothing written")
            executor.spin_once(timeout_sec=0.05)
            if len(listener.world) != bar.shown:
                last = time.monotonic()
                latest = [listener.newest[k] for k in learners if k in listener.newest]
                bar.update(len(listener.world), listener.collisions, sum(s.joint_states for s in latest),
                           sum(listener.heard[k] for k in learners))
                if 0 not in listener.world:
                    raise CollectError(f"the first statistics heard are of episode {min(listener.world)}: the "
                                       "run started before collect; give its nodes -p min_stats_subscribers:=1 "
                                       "to make them wait for it")
            if time.monotonic() >= look_at:  # the system gone before its last statistics: they never come
                look_at = time.monotonic() + GONE_S
                if (WORLD, ns) not in node.get_node_names_and_namespaces() and not listener.complete:
                    gone = gone or time.monotonic()
                    if time.monotonic() - gone > GONE_S:
                        raise CollectError(f"the world node {ns}/{WORLD} is gone; missing "
                                           f"{'; '.join(listener.missing())}")
            if episodes_timeout is not None and time.monotonic() - last > episodes_timeout:
                raise CollectError(f"no new episode for {episodes_timeout:g} s; missing "
                                   f"{'; '.join(listener.missing())}")
    finally:
        bar.close()
    out = prepare_output(out, force)
    nodes = {name: {"namespace": ns} for name in [WORLD, *agents]}
    heard_on = domain_id if domain_id is not None else environment_domain() or 0
    run_info = dict(mode="ros", collected=True, domain_id=heard_on, namespace=ns)
    write_heard(out, gridmap, algo, episodes, seed, settings, time.monotonic() - started, listener,
                learners, agents, nodes, run_info)
    return out

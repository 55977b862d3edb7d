"""`cq-ros launch`: a world node and its agent nodes as child processes, watched to the end, and the run written
as the same result files as `cq-ros experiment` (docs/ros.md, "Launch", is what a user sees of it).

One launch is one ROS 2 system of its own: a ROS_DOMAIN_ID (`run_domain`), discovery kept on this host unless
on `hosts`, and a namespace (/cq_<hex> unless given), so launches side by side never hear each other's nodes.
The launcher's own node (`/<namespace>/launch`, the listener of ros_tools.launch_results) subscribes to every
statistics topic, then every child starts at once, which overlaps the interpreters' start-up: the nodes send no
statistics before the listener has matched (ros_tools.launch_nodes.node_specs). Where the rest lives:
ros_tools.launch_nodes (the nodes and their command lines), ros_tools.run_key (the key of a launch given none),
ros_tools.children (the processes), ros_tools.launch_watch (the watch loop), ros_tools.restarts (agents started
again) and ros_tools.launch_end (the exit status, the errors, and what each end leaves in the folder).
"""

from __future__ import annotations

import os
import random
import re
import secrets
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from tqdm import tqdm

from agent_node.checkpoint import SUFFIX as CHECKPOINT_SUFFIX, load_checkpoint
from cq_ros.engine import make_learner
from cq_ros.gridmap import GridMap, load_map
from cq_ros.lab.output import made_by, removed_if_failing
from cq_ros.lab.results import prepare_output
from cq_ros.learners import LEARNERS
from cq_ros.settings import Settings, run_settings
from node_runtime.parameters import AGENT_PARAMETERS, read_key_parameter
from node_runtime.run import EXECUTOR_ENV, executor_kind

from .children import stop_children
from .hosts import Hosts
from .launch_end import Ending, Interrupted, LaunchError, NamespaceTaken, remove, rows_failed
from .launch_nodes import agent_nodes, check_node_parameters, compose_command, node_commands, node_specs
from .launch_results import EpisodeRows, LaunchResult, StatsListener
from .launch_watch import watch
from .params_file import LAUNCH_ONLY, SYSTEM_FILE, write_system
from .progress import Progress
from .restarts import Restarts, file_identity
from .run_key import RunKeyFile
from .session import StopSignals, ToolError, environment, environment_domain, others_in, ros_session, spin_until

__all__ = ["DOMAIN_IDS", "BENCH_DOMAINS", "check_hosts", "run_domain", "launch"]

DOMAIN_IDS = (100, 200)  # a launch given no domain (--domain-id, ROS_DOMAIN_ID) draws one from this range
BENCH_DOMAINS = (40, 99)  # ... and a ROS benchmark (benchmarks/) from this one, off the launches' range
DRAIN_S = 5.0  # after the last child exits, how long to wait for statistics still in the listener's queue
NAMESPACE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _checkpoints(folder: Path, gridmap: GridMap, algo: str, settings: Settings) -> list[Path]:
    """The checkpoint of every agent node of this launch in `folder`, each loaded and checked as its node will
    (agent_node.checkpoint); ValueError naming the first missing or bad one."""
    paths = []
    for name, ident in agent_nodes(gridmap, algo):
        path = folder / (name + CHECKPOINT_SUFFIX)
        if not path.exists():  # a FIFO or a device is there, and refused as such by load_checkpoint
            raise ValueError(f"start_from {os.fspath(folder)!r}: no checkpoint {path.name} for node {name}")
        load_checkpoint(path, algo, gridmap, max(ident.get("agent_id", 0) - 1, 0), settings)
        paths.append(path)
    return paths


def check_hosts(hosts: Hosts, gridmap: GridMap, algo: str, discovery: str) -> None:
    """ValueError unless a launch of `algo` on `gridmap` can run on these hosts: one per agent node."""
    if LEARNERS[algo].central:
        raise ValueError(f"{algo} is one central node: hosts run one agent node per AGV")
    if hosts.agents != gridmap.n_agents:
        raise ValueError(f"hosts {hosts.prefix} have {hosts.agents} AGV hosts, map {gridmap.name} has "
                         f"{gridmap.n_agents} agents")
    hosts.discovery_env("world", discovery)  # a bad discovery fails here


def run_domain(given: int | None, drawn_from: tuple[int, int] = DOMAIN_IDS) -> int:
    """The launch's ROS_DOMAIN_ID: `given` (--domain-id), else the environment's, as every ROS tool takes it;
    drawn from `drawn_from` only when neither says one (so two launches side by side do not hear each other;
    the ROS benchmarks draw theirs from 40..99, off the launches' range)."""
    if given is not None:
        return given
    chosen = environment_domain()
    return random.SystemRandom().randint(*drawn_from) if chosen is None else chosen


def launch(map_name: str, algo: str, episodes: int, seed: int, out: str | os.PathLike,
           settings: Settings | None = None, *, domain_id: int | None = None, namespace: str | None = None,
           step_timeout: float = 2.0, peer_linger_steps: int | None = None, compose: bool = False,
           executor: str | None = None, markers: bool = True, force: bool = False, figures: bool = True,
           progress: bool = True, node_parameters: dict[str, Any] | None = None, hosts: Hosts | None = None,
           discovery: str = "subnet", key_file: str | os.PathLike | None = None,
           view_port: int | None = None, start_from: str | os.PathLike | None = None,
           restart_agents: int = 0) -> LaunchResult:
    """Run one (map, algorithm, seed) over ROS and write the result directory `out`: a process per node, or
    with `compose` every node in one process (ros_tools.compose), spinning on `executor` (EXECUTORS; None:
    the environment's $CQ_ROS_EXECUTOR, else the EventsExecutor); `markers` False: no publishers for viewers.
    Without `settings`, the run's are the map's (`cq_ros.settings.run_settings`).

    With `hosts` (ros_tools.hosts, one per AGV of the map), each node runs on its own host, found by
    `discovery` ("subnet" or "static", see ros_tools.hosts.DISCOVERY); the launcher must run on the world's.

    Every launch writes the system it ran to DIR/params.yaml (ros_tools.params_file). `key_file` (made by `cq-ros
    key`) keys the run and is named there and kept; without it the launch makes a key of its own and removes
    it at the end. `view_port`: also serve the run to Foxglove there (ros_tools.view, the extra `view`).

    `start_from`: a folder holding a checkpoint (agent_node.checkpoint) per agent node, `<node>.npz` (agv1.npz
    ..., or jsa.npz): the agents start from those learners (as nodes restarted from them) instead of fresh ones;
    each is loaded and checked here first, so a bad one is one line before any process starts.
    `restart_agents`: how many times in all an agent node that dies is started again (ros_tools.restarts).

    Bad input (map, algorithm, setting, namespace, an output that is not ours to write, a missing checkpoint)
    raises ValueError or a subclass before any process starts; LaunchError/Interrupted after every child has
    been stopped."""
    gridmap = load_map(map_name)
    settings = run_settings(gridmap) if settings is None else settings
    make_learner(algo, gridmap, settings, seed, 0, 0)  # an unknown algorithm, or jsa on 8 agents, fails here
    executor_name = executor_kind(executor)
    start_with = [] if start_from is None else _checkpoints(Path(start_from), gridmap, algo, settings)
    node_parameters = {"step_timeout": float(step_timeout),
                       **({} if peer_linger_steps is None else {"peer_linger_steps": peer_linger_steps}),
                       **({} if markers else {"markers": False}), **(node_parameters or {})}
    check_node_parameters(map_name, algo, settings, node_parameters)
    drawn = namespace is None  # then the launch's own: no system can be in it yet
    given = namespace if namespace is not None else f"cq_{secrets.token_hex(4)}"
    namespace = given.removeprefix("/")  # "/demo" and "demo" name one namespace, as they do for ROS
    if not NAMESPACE.fullmatch(namespace):
        raise ValueError(f"namespace {given!r} is not a ROS name (letters, digits, _; not starting with a digit)")
    if hosts is not None:
        if compose:
            raise ValueError("--compose runs every node in one process, --hosts each on its own host: choose one")
        check_hosts(hosts, gridmap, algo, discovery)
        if hosts.current_host() != "world":
            raise ValueError(f"the launcher must run on the world's host: ip netns exec {hosts.namespace('world')} ...")
    if key_file is not None:
        read_key_parameter(os.fspath(key_file))  # a missing or readable-by-others key fails before any work
    domain_id = run_domain(domain_id)
    made = made_by(out)  # what this launch makes, removed if it ends before a row of its own is written
    with removed_if_failing(out):
        out = prepare_output(Path(out), force)
        for sub in ("logs", "checkpoints"):
            (out / sub).mkdir(exist_ok=True)
        kept_key = key_file is not None  # the system's own key (cq-ros key), named in params.yaml and kept
        own_key = None if kept_key else RunKeyFile()
        key_file = Path(key_file).resolve() if kept_key else own_key.path
        run_key = read_key_parameter(os.fspath(key_file))
        nodes = node_specs(map_name, algo, episodes, seed, settings, out, step_timeout, peer_linger_steps,
                           node_parameters, key_file)
        launch_only = LAUNCH_ONLY if kept_key else LAUNCH_ONLY | {"key_file"}
        if compose:
            children = [compose_command(nodes, namespace, out, launch_only)]
        else:
            write_system(out / SYSTEM_FILE, nodes, launch_only)
            children = node_commands(nodes, namespace, out)
        for name in nodes:  # a fresh run: a checkpoint left by an earlier result would be resumed from
            (out / "checkpoints" / (name + CHECKPOINT_SUFFIX)).unlink(missing_ok=True)
        started_from = {}  # node name -> the file start_from gave it (ros_tools.restarts)
        for given in start_with:
            shutil.copyfile(given, out / "checkpoints" / given.name)
            started_from[given.stem] = file_identity(out / "checkpoints" / given.name)
        env = {**os.environ, "ROS_DOMAIN_ID": str(domain_id), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
               "PYTHONUNBUFFERED": "1", EXECUTOR_ENV: executor_name}
        listener_env: dict[str, str] = {}
        if hosts is not None:
            for child in children:
                child.command = [*hosts.exec_on(child.name), *child.command]
                child.env = hosts.discovery_env(child.name, discovery)
            listener_env = hosts.discovery_env("world", discovery)
        learners = [1] if LEARNERS[algo].central else list(range(1, gridmap.n_agents + 1))
        rows = EpisodeRows(out, gridmap.name, algo, learners, episodes)  # OutputError if the disk is full already
    on_hosts = {} if hosts is None else {"hosts": {"prefix": hosts.prefix, "discovery": discovery,
                                                   "addresses": {h: hosts.address(h) for h in hosts.names}}}
    run_info = dict(mode="ros", composed=compose, executor=executor_name, markers=node_parameters.get("markers", True),
                    domain_id=domain_id, namespace=f"/{namespace}",
                    step_timeout_s=node_parameters["step_timeout"], **on_hosts,
                    checkpoint_every=list(nodes.values())[1][1]["checkpoint_every"],
                    peer_linger_steps=node_parameters.get("peer_linger_steps",
                                                          AGENT_PARAMETERS["peer_linger_steps"][0]),
                    node_parameters=node_parameters, authenticated=True)
    started = time.perf_counter()
    with StopSignals() as stop, environment(**listener_env), ros_session(
            "launch", domain_id=domain_id, namespace=f"/{namespace}", localhost_only=hosts is None,
            hidden=False) as (node, executor):
        listener = StatsListener(node, gridmap, episodes + settings.eval_episodes, key=run_key,
                                 run=nodes["world"][1]["run_nonce"])
        end = Ending(out, gridmap, algo, episodes, seed, settings, run_info, children, rows, listener, learners,
                     list(nodes)[1:], made, started)
        restarts = Restarts(nodes, algo, gridmap, settings, episodes, learners, listener, started_from, LaunchError)
        server = None
        if view_port is not None:  # a live view in Foxglove (ros_tools.view), relayed by the listener's node
            from .view import serve

            try:
                server, _ = serve(node, f"/{namespace}", port=view_port, n_agents=gridmap.n_agents)
            except ToolError as e:
                rows.close()
                if own_key is not None:
                    own_key.close()
                remove(made)
                raise LaunchError(str(e)) from None
            tqdm.write(f"cq-ros launch: Foxglove view on ws://127.0.0.1:{server.port}", file=sys.stderr)
        bar = Progress(f"{gridmap.name} {algo}", listener.episodes, episodes, progress)
        try:
            # A world started in a running system's namespace began stepping that system's agents before it
            # heard the other world, and yielded episodes later ("a second system started together with this
            # one"): the launch looks first, once discovery has settled there.
            running = [] if drawn else others_in(node, executor, f"/{namespace}", stop)
            if running:
                raise NamespaceTaken(f"namespace /{namespace} on ROS_DOMAIN_ID {domain_id} already holds a running "
                                     f"system (nodes {', '.join(running)}): refusing to start; give this launch "
                                     "another --namespace or --domain-id")
            for child in children:
                child.start(env)
            if progress:
                tqdm.write(f"cq-ros launch: ROS_DOMAIN_ID={domain_id}, namespace /{namespace}, "  # above the bar
                           + ", ".join(f"{c.name} pid {c.process.pid}" for c in children)
                           + f"; logs in {out / 'logs'}", file=sys.stderr)
            watch(children, listener, executor, stop, bar, learners, rows, restart_agents, env, compose, restarts,
                  list(nodes))
            if not spin_until(executor, lambda: listener.complete, DRAIN_S, stop):
                if stop:
                    raise Interrupted(f"interrupted by {stop.received}")
                raise LaunchError(f"every node finished, but the launcher never got {'; '.join(listener.missing())}")
            rows.take(listener)
            rows_failed(rows)
        except LaunchError as e:
            raise end.failed(e) from None
        finally:
            stop_children(children)
            if own_key is not None:
                own_key.close()
            if server is not None:
                server.stop()
            bar.close()

    return end.finished(nodes, figures)



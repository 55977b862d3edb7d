"""`cq-ros launch`: a world node and its agent nodes as child processes, watched to the end, and the run
written as the same result files as `cq-ros experiment` (episodes.csv, observe.csv, greedy.csv,
manifest.json and the figures).

One launch is one ROS 2 system of its own: a ROS_DOMAIN_ID (--domain-id, else the environment's as every ROS
tool takes it, else drawn in 100..200: `run_domain`), discovery kept on this host
(ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) and a namespace (/cq_<hex> unless given), so launches side by side
never hear each other's nodes; `cq-ros echo /<namespace>/world/stats --domain-id N` watches one.

Start-up. The launcher's own node (the listener, `/<namespace>/launch`) subscribes to every agv<k>/stats, then
every child starts at once: the world, and one agent process per AGV (`agv<k>`) or the one central JSA node
(`jsa`). A statistics writer keeps only its last 1000 for a listener that matches late (transient local),
so none is sent before the match: the world runs with min_stats_subscribers:=1 (its first step waits for the
listener's world/stats subscription) and so does every agent (it holds its statistics until its own
publisher has matched the listener, and waits for that before it exits; only the publisher's side of a match
says that a message will arrive). Starting everything at once (instead of the agents first) overlaps the
interpreters' start-up.
With `--compose` the one child is a container (ros_tools.compose) holding every node, each reading its
system's DIR/params.yaml (which every launch writes: ros_tools.params_file) and its own launch_params.yaml;
the nodes and the protocol are the same.

Parameters and key. `--set name=value` takes every Settings field and every node parameter that matters
for a run (timeouts, heartbeat, linger, checkpoints: `SETTABLE`), checked by the nodes' own rules before
anything starts. Each launch makes a fresh key (msgs_spec.auth) in a file that has no name, only the user can
read, and exists while the launcher has it open (O_TMPFILE), and hands every node its path through the
launcher's descriptor (`key_file` /proc/<launcher pid>/fd/<n>): a writer outside the launch cannot steer the
run, and no end of the launch, kill -9 of the launcher included, leaves the key behind in a file.

Restarts. With `restart_agents` N (off by default), an agent node that dies while the world runs is started
again, up to N times in all, with the same command: it resumes from its checkpoint (agent_node.checkpoint,
every CHECKPOINT_EVERY episodes unless `--set checkpoint_every`) or, before the first, joins as a fresh learner.
The launcher loads that checkpoint first: one it cannot load ends the launch with the reason (which the node
would only say in its log), and the episodes learnt past it are lost learning. Each restart is a line saying
how many, and counted (manifest `restarts`, `restarts.learning_lost`); the episodes it was away for have no
statistics of it, and their rows sum the other learners' (manifest `restarts.episodes_without`); the world
missed its actions meanwhile, so such a run ends degraded (exit status 3).

Watching. A child that exits non-zero (or is killed) ends the launch with `LaunchError` naming it and its exit
code (the world's 3: a twin of a node, `WORLD_TWIN`); Ctrl-C or SIGTERM to the launcher ends it with
`Interrupted`. Either way every child still running gets
SIGINT, then SIGTERM after 3 s, then SIGKILL after 2 more. Children run in sessions of their own, so a
terminal's Ctrl-C reaches the launcher only and it stops them in that order, and the kernel sends them SIGTERM
if the launcher itself dies (PR_SET_PDEATHSIG on Linux): none outlives it. Each child's output goes to
DIR/logs/<node>.log (ROS file logging is off: the console output is the log).

Hosts. With `hosts` (ros_tools.hosts: network namespaces joined by a bridge), the launcher runs on the world's
host and starts each node on its own (`ip netns exec`), all over UDP, discovering each other on the subnet or
through ROS_STATIC_PEERS only; `cq-ros launch --hosts PREFIX` enters the world's host itself.

Results. The nodes play `episodes` learning episodes, then `eval_episodes` greedy ones (the agents on a copy
of their learner at epsilon 0, as `cq_ros.engine.greedy_episodes`). Per episode, steps, collisions,
truncation and return (summed over agents) come from WorldStats; joint plays and states (local + joint) are
summed over the learners' AgentStats, where the central JSA node, which repeats its one learner's counts on
every agv<k>/stats, counts once. The learning episodes' rows make episodes.csv, the greedy ones' greedy.csv
(RunResult.greedy, as `cq_ros.engine.run` gives it), and the marked joint states of the last learning
episode's AgentStats make observe.csv (the engine takes them before its greedy episodes too). episodes.csv
is written row by row as the episodes are heard (ros_tools.launch_results: a disk that fills keeps every row
it took, the launch ends early with one line naming the file and the OS's reason, and the manifest says so; a
results folder removed or moved mid-run ends it at the next episode with one line, `ResultsGone`);
a checkpoint an agent could not write is a warning line at the end, naming the node, the file and the reason.
The manifest adds the communication cost over the whole launch (per agent node: peer subscriptions created, peer
messages; the world's missed actions and dropped-message counters, by kind and by topic).

Ends. Every end writes manifest.json: `ended` says how (finished, degraded, node_failed, twin, interrupted,
disk, incomplete: a node hung or statistics never came), the one-line reason and the exit status, beside each
node's counters: those of the report it printed at its exit (node_runtime.report: what it counted after its
last statistics too, by topic), else, for a node killed by SIGKILL, its last statistics' (`counters_as_of`;
ros_tools.launch_results); only a launch that refused at its start (a second system here: one its launcher
found in the namespace it was given, once discovery had settled there, or its world's twin) leaves nothing but
its line. The exit
status tells a clean run (`EXIT_CLEAN`, 0) from one that played every episode but left the offline engine's
behaviour somewhere (`EXIT_DEGRADED`, 3: a missed or unapplied action, a feedback never heard; the summary
says how many episodes that touched), a launch that failed or ended early (1) and one interrupted (130).
"""

from __future__ import annotations

import ctypes
import os
import random
import re
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Callable

import yaml
from tqdm import tqdm

from agent_node.checkpoint import SUFFIX as CHECKPOINT_SUFFIX, load_checkpoint
from agent_node.config import agent_config
from cq_ros.engine import make_learner
from cq_ros.lab.results import prepare_output
from cq_ros.gridmap import GridMap, load_map
from cq_ros.learners import LEARNERS
from cq_ros.lab.output import made_by, os_reason, removed_if_failing
from node_runtime.parameters import check_names
from cq_ros.settings import Settings, SettingsError, coerce, run_settings, split_pair
from msgs_spec import agent_namespace, new_key_file
from msgs_spec.auth import KEY_BYTES, new_run
from node_runtime.parameters import AGENT_PARAMETERS, WORLD_PARAMETERS, read_key_parameter
from node_runtime.report import read_reports
from node_runtime.run import EXECUTOR_ENV, executor_kind
from world_node.lockstep import TWIN_EXIT as WORLD_TWIN, world_config

from .session import StopSignals, ToolError, environment, environment_domain, others_in, ros_session, spin_until
from .hosts import Hosts
from .launch_results import (
    EpisodeRows, LaunchResult, StatsListener, checkpoint_failures, departures, describe_departures, write_ended_early,
    write_heard,
)
from .params_file import LAUNCH_ONLY, SYSTEM_FILE, write_system
from .restarts import Restarts, file_identity

__all__ = ["EXIT_CLEAN", "EXIT_FAILED", "EXIT_DEGRADED", "EXIT_INTERRUPTED", "WORLD_TWIN", "DOMAIN_IDS",
           "BENCH_DOMAINS", "SETTABLE", "LaunchError", "Interrupted", "NamespaceTaken", "EndedEarly", "ResultsGone",
           "LaunchResult", "Child", "split_sets", "agent_nodes", "node_specs", "node_commands", "compose_command",
           "check_hosts", "run_domain", "launch", "StatsListener", "Progress", "write_heard"]

# The launch's exit status (`cq-ros launch`): every episode played as the offline engine plays it; a launch that
# failed or ended early; every episode played, but some step not as offline (a missed or unapplied action, a
# feedback never heard: the summary says where); Ctrl-C or SIGTERM.
EXIT_CLEAN, EXIT_FAILED, EXIT_DEGRADED, EXIT_INTERRUPTED = 0, 1, 3, 130
DOMAIN_IDS = (100, 200)  # a launch given no domain (--domain-id, ROS_DOMAIN_ID) draws one from this range
BENCH_DOMAINS = (40, 99)  # ... and a ROS benchmark (benchmarks/) from this one, off the launches' range
STARTUP_TIMEOUT_S = 30.0  # the world's startup_timeout: every child discovered by then, or the world exits 1
# ... or this many seconds per node where that is longer (`startup_wait`)
STARTUP_PER_NODE_S = 4.0
NODE_UP_S, STUCK_TRIES = 60.0, 2  # a node process that logs nothing this long after its start is started again
CHECKPOINT_EVERY = 50
AGENT_EXIT_GRACE_S = 10.0  # an agent still running this long after the world finished is stuck
# A node still a process this long after its report (its last word) hangs in its teardown, every episode heard:
# it is stopped (`_stop_hung_at_exit`).
EXIT_HANG_S = 5.0
DRAIN_S = 5.0  # after the last child exits, how long to wait for statistics still in the listener's queue
# after a child fails, how long to wait for the rows of the episodes the world has said it played: the agents'
# statistics of its last episode are sent at the same moment as its own and may still be on their way
LAST_ROWS_S = 2.0
STATUS_S = 5.0  # between two episodes, how often the progress says where the run is
STOP_GRACE_S = ((signal.SIGINT, 3.0), (signal.SIGTERM, 2.0), (signal.SIGKILL, 5.0))
NAMESPACE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
# Node parameters the launcher fixes itself (from its own options, or as its children need them).
LAUNCHER_OWNS = {"map", "episodes", "seed", "run", "algo", "agent_id", "checkpoint", "min_stats_subscribers",
                 "key_file", "run_nonce"}
_SETTINGS = {f.name for f in fields(Settings)}
# name -> default: the node parameters `--set` may change, beside the Settings fields.
SETTABLE = {name: default for params in (WORLD_PARAMETERS, AGENT_PARAMETERS)
            for name, (default, _) in params.items() if name not in LAUNCHER_OWNS | _SETTINGS}


class LaunchError(RuntimeError):
    """The launch failed (a child died or hung, statistics went missing); the message is one line."""

    exit_status = EXIT_FAILED


class Interrupted(LaunchError):
    """Ctrl-C or SIGTERM to the launcher; every child was stopped."""

    exit_status = EXIT_INTERRUPTED


class NamespaceTaken(LaunchError):
    """A system already runs in the namespace given: the launch refuses before any process starts."""


class EndedEarly(LaunchError):
    """The launcher could not write a result file (a full or failing disk): every child was stopped, the rows
    written are kept, and the manifest says why."""


class ResultsGone(LaunchError):
    """The result folder was removed or moved mid-run (ros_tools.launch_results.EpisodeRows looks every
    episode): every child was stopped, since whatever followed would be played into files nobody can read."""


def _rows_failed(rows: EpisodeRows) -> None:
    """Raise what a failure of episodes.csv ends the launch with, if there was one."""
    if rows.failure:
        raise (ResultsGone if rows.gone else EndedEarly)(rows.failure)


# -- children ----------------------------------------------------------------------------------------------

if sys.platform.startswith("linux"):
    _PR_SET_PDEATHSIG = 1
    _prctl = ctypes.CDLL(None, use_errno=True).prctl  # looked up here: the child only calls it

    def _die_with_launcher() -> None:
        """Run in the child between fork and exec: the kernel sends it SIGTERM when the launcher dies."""
        _prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
else:
    _die_with_launcher = None


@dataclass
class Child:
    """One node process: its name (also its log file's), command line, log and, once started, its process."""

    name: str
    command: list[str]
    log: Path
    process: subprocess.Popen | None = None
    env: dict[str, str] = field(default_factory=dict)  # its own, over the launch's
    restarts: int = 0  # times the launch started it again after it died (`restart_agents`)
    stuck_starts: int = 0  # times the launch started it again because it never came up (`_unstick`)
    started_at: float = 0.0  # time.monotonic() of its latest start
    logged_at_start: int = 0  # its log's size then
    reported_at: float | None = None  # time.monotonic() its report was first seen in its log (`_stop_hung_at_exit`)
    looked_at: float = 0.0  # ... when its log was last looked at for it
    hung_at_exit: bool = False  # stopped by the launch after its report: its work was done

    def start(self, env: dict[str, str]) -> None:
        # the child keeps its own copy of the descriptor; a restarted one's log goes on after its first life's
        with open(self.log, "ab" if self.restarts or self.stuck_starts else "wb") as log:
            self.logged_at_start = log.tell()
            self.process = subprocess.Popen(self.command, stdin=subprocess.DEVNULL, stdout=log,
                                            stderr=subprocess.STDOUT, env={**env, **self.env},
                                            start_new_session=True, preexec_fn=_die_with_launcher)
        self.started_at = time.monotonic()

    def said_anything(self) -> bool:
        """Whether its log has grown since its latest start: a node's first line comes once it is made."""
        try:
            return self.log.stat().st_size > self.logged_at_start
        except OSError:
            return False

    @property
    def exit_code(self) -> int | None:
        return None if self.process is None else self.process.poll()

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def signal_group(self, sig: int) -> None:
        try:
            os.killpg(self.process.pid, sig)  # its own session: the group is the child and anything it started
        except ProcessLookupError:
            pass

    def describe_exit(self) -> str:
        code = self.exit_code
        how = f" (killed by {signal.Signals(-code).name})" if code is not None and code < 0 else ""
        said = self.last_error()
        return f"{self.name} (pid {self.process.pid}) exited with code {code}{how}" + (f" ({said})" if said else "")

    def reports(self) -> dict[str, dict]:
        """The reports its nodes printed at their end since its latest start (node_runtime.report; none if it was
        killed, or still runs), by node name."""
        try:
            with open(self.log, "rb") as f:
                f.seek(self.logged_at_start)
                return read_reports(f.read().decode(errors="replace"))
        except OSError:
            return {}

    def last_error(self) -> str | None:
        """The node's last ERROR line, without rclpy's prefix (a refusal says why there), if its log has one."""
        try:
            with open(self.log, "rb") as f:
                f.seek(max(0, f.seek(0, os.SEEK_END) - 8192))
                lines = f.read().decode(errors="replace").splitlines()
        except OSError:
            return None
        errors = [line for line in lines if line.startswith("[ERROR]")]
        return errors[-1].split("]: ", 1)[-1] if errors else None


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


def _check_node_parameters(map_name: str, algo: str, settings: Settings, node: dict[str, Any]) -> None:
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


def _params(values: dict[str, Any]) -> list[str]:
    return [arg for k, v in values.items() for arg in ("-p", f"{k}:={_param(v)}")]


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
    both, every node parameter (`node_parameters`, from `--set`) to the nodes that take it."""
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
        children.append(Child(name, [sys.executable, "-m", module, *_ros_args(namespace), *rename, *_params(params)],
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


class _RunKeyFile:
    """The launch's own key in a file without a name (O_TMPFILE where the kernel has it, else unlinked at once),
    mode 0600, which the nodes open through the launcher's descriptor (`path`, /proc/<pid>/fd/<n>) while the
    launcher lives: they read it once, at their start, and a node outlives the launcher by nothing (its
    PR_SET_PDEATHSIG). So whatever ends the launch, kill -9 included, no key stays behind in a file. Without
    /proc, a named file (msgs_spec.auth.new_key_file) removed by `close`."""

    def __init__(self) -> None:
        self.named: Path | None = None
        self.file = tempfile.TemporaryFile("w+")
        self.file.write(secrets.token_hex(KEY_BYTES) + "\n")
        self.file.flush()
        self.path = Path(f"/proc/{os.getpid()}/fd/{self.file.fileno()}")
        if not self.path.exists():
            self.file.close()
            self.named = self.path = new_key_file()

    def close(self) -> None:
        self.file.close()
        if self.named is not None:
            self.named.unlink(missing_ok=True)


def _stop(children: list[Child]) -> None:
    """SIGINT to every child still running, then SIGTERM, then SIGKILL, each with a bounded wait; reaps them."""
    running = [c for c in children if c.running]
    for sig, grace in STOP_GRACE_S:
        if not running:
            return
        for child in running:
            child.signal_group(sig)
        deadline = time.monotonic() + grace
        while running and time.monotonic() < deadline:
            time.sleep(0.02)
            running = [c for c in running if c.running]


# -- progress ----------------------------------------------------------------------------------------------


class Progress:
    """A tqdm bar on a terminal; otherwise a plain line every 5% of the episodes (and at the last). It counts
    every episode; the label says "greedy" once the learning episodes (the first `learning`) are over. Between
    them, every STATUS_S at most, where the run is (`within`): how many nodes are up, then the episode and step,
    so a big map shows progress from its first step."""

    def __init__(self, label: str, episodes: int, learning: int, enabled: bool):
        self.label, self.episodes, self.learning, self.enabled = label, episodes, learning, enabled
        self.tty = enabled and sys.stderr.isatty()
        self.bar = tqdm(total=episodes, desc=label, unit="episode", disable=not self.tty)
        self.every = max(1, episodes // 20)
        self.shown = 0
        self.said = time.monotonic()  # when a line (or the bar) last said something

    def within(self, where: Callable[[], str]) -> None:
        """Say where() ('starting: 12/33 nodes up', 'episode 0, step 1200') if nothing was said for STATUS_S."""
        if not self.enabled or time.monotonic() - self.said < STATUS_S:
            return
        self.said = time.monotonic()
        if self.tty:
            self.bar.set_postfix_str(where())
        else:
            print(f"{self.label}: {where()}", file=sys.stderr, flush=True)

    def update(self, done: int, collisions: int, joint_states: int, peer_messages: int) -> None:
        self.said = time.monotonic()
        label = f"{self.label} greedy" if done > self.learning else self.label
        if self.tty:
            self.bar.set_description(label, refresh=False)
            self.bar.set_postfix(collisions=collisions, joint_states=joint_states, peer_msgs=peer_messages,
                                 refresh=False)
            self.bar.update(done - self.shown)
        elif self.enabled and (done // self.every > self.shown // self.every or done == self.episodes):
            print(f"{label}: episodes {done}/{self.episodes}, {collisions} collisions, {joint_states} joint "
                  f"states, {peer_messages} peer messages", file=sys.stderr, flush=True)
        self.shown = done

    def close(self) -> None:
        self.bar.close()


# -- one launch --------------------------------------------------------------------------------------------


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
    `restart_agents`: how many times in all an agent node that dies is started again (the module's "Restarts").

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
    _check_node_parameters(map_name, algo, settings, node_parameters)
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
        own_key = None if kept_key else _RunKeyFile()
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

    def node_info() -> dict:
        return {c.name: {"command": c.command, "exit_code": c.exit_code, "log": str(c.log.relative_to(out)),
                         **({"restarts": c.restarts} if c.restarts else {}),
                         **({"stuck_starts": c.stuck_starts} if c.stuck_starts else {})} for c in children}

    learner_nodes = list(nodes)[1:]

    def reports() -> dict[str, dict]:
        """Every node's report at its end (each child's log, since its latest start): its final counters."""
        return {name: report for c in children for name, report in c.reports().items()}

    def write_ended(reason: str, how: str, status: int) -> str:
        """The manifest of a launch that ended before its results (`reason`): what became of it, for the line."""
        return write_ended_early(out, gridmap, algo, episodes, seed, settings, time.perf_counter() - started, rows,
                                 node_info(), run_info, reason, listener, learners, learner_nodes,
                                 ended={"how": how, "reason": reason, "exit_status": status}, reports=reports())

    def ended_early(reason: str) -> EndedEarly:
        kept = write_ended(f"the launcher {reason}", "disk", EndedEarly.exit_status)
        return EndedEarly(f"the launcher {reason}: the run ended early after {rows.written}/{episodes} "
                          f"episodes; those rows are in {rows.path}, and {kept}")

    started = time.perf_counter()

    with StopSignals() as stop, environment(**listener_env), ros_session(
            "launch", domain_id=domain_id, namespace=f"/{namespace}", localhost_only=hosts is None,
            hidden=False) as (node, executor):
        listener = StatsListener(node, gridmap, episodes + settings.eval_episodes, key=run_key,
                                 run=nodes["world"][1]["run_nonce"])
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
                _remove(made)
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
            _watch(children, listener, executor, stop, bar, learners, rows, restart_agents, env, compose,
                   restarts, list(nodes))
            if not spin_until(executor, lambda: listener.complete, DRAIN_S, stop):
                if stop:
                    raise Interrupted(f"interrupted by {stop.received}")
                raise LaunchError(f"every node finished, but the launcher never got {'; '.join(listener.missing())}")
            rows.take(listener)
            _rows_failed(rows)
        except LaunchError as e:
            stopping = [c.name for c in children if c.running]
            _stop(children)
            rows.close()
            if isinstance(e, EndedEarly):
                raise ended_early(str(e)) from None
            if isinstance(e, ResultsGone):  # nowhere left to write a manifest or read a log
                raise ResultsGone(f"{e}: the run stopped after {rows.written}/{episodes} episodes; stopped "
                                  f"{', '.join(stopping) or 'nothing'}") from None
            stopped = f"; stopped {', '.join(stopping)}" if stopping else ""
            # A launch or node that refused (a second system here) before any row of this run leaves nothing
            # worth keeping, and the line says why; a node that crashed or was stopped leaves its log to read, and the
            # manifest says how the run ended, with the counters of each node.
            refused = isinstance(e, NamespaceTaken) or any(c.exit_code == 2 for c in children)
            if rows.written == 0 and refused and made is not None:
                rows.free()
                _remove(made)
                raise type(e)(f"{e}{stopped}; {made} removed") from None
            if not refused:
                listener.show_held()
            failed = any(c.exit_code not in (None, 0) for c in children)
            how = "interrupted" if isinstance(e, Interrupted) else "twin" if children[0].exit_code == WORLD_TWIN \
                else "node_failed" if failed else "incomplete"  # incomplete: a node hung, or statistics never came
            kept = write_ended(f"{e}{stopped}", how, e.exit_status)
            raise type(e)(f"{e}{stopped} (logs in {out / 'logs'}; {kept})") from None
        finally:
            _stop(children)
            if own_key is not None:
                own_key.close()
            if server is not None:
                server.stop()
            bar.close()

    rows.close()
    try:
        # Degraded or clean: known from the statistics only, so the manifest is written with both and then told.
        result = write_heard(out, gridmap, algo, episodes, seed, settings, time.perf_counter() - started,
                             listener, learners, learner_nodes, node_info(), run_info, episodes_written=True,
                             ended=_ended_as(listener, learners), reports=reports())
        rows.free()
        if figures:
            from cq_ros.lab.plots import write_figures  # matplotlib only where figures are wanted

            write_figures(out, map_loader=lambda _name: gridmap)  # a map file is known by its name only here
    except OSError as e:
        raise ended_early(f"cannot write {e.filename or out}: {os_reason(e)}") from None
    for name, stats in result.manifest["communication"].items():  # the nodes' own losses, last
        for failure in checkpoint_failures(stats["counters"]):
            print(f"cq-ros launch: warning: {name}: checkpoint {nodes[name][1]['checkpoint']} not written: "
                  f"{failure}; learning went on", file=sys.stderr)
    return result


def _unstick(children: list[Child], env: dict, listener: StatsListener) -> None:
    """Before the run's first step, start again an agent node that has said nothing for NODE_UP_S since it started
    (at most STUCK_TRIES times each), saying so. Seen with warehouse_32 as a process per node on 2 busy cores: one
    to five of the 32 agent processes hung for good inside rclpy's create_publisher (Fast DDS blocked on a lock
    while the other participants' discovery came in), while every other node logged within 35 s of the start;
    a fresh process comes up. The world is not restarted: agents may have heard it already."""
    if listener.world or (listener.at is not None and listener.at != (0, 0)):
        return
    now = time.monotonic()
    for child in children[1:]:
        if child.running and now - child.started_at > NODE_UP_S and child.stuck_starts < STUCK_TRIES and \
                not child.said_anything():
            pid = child.process.pid
            child.signal_group(signal.SIGKILL)
            child.process.wait(timeout=STOP_GRACE_S[-1][1])
            child.stuck_starts += 1
            child.start(env)
            tqdm.write(f"cq-ros launch: {child.name} (pid {pid}) said nothing {NODE_UP_S:g} s after its start, a "
                       f"start stuck in ROS: started it again (pid {child.process.pid})", file=sys.stderr)


def _stop_hung_at_exit(running: list[Child]) -> None:
    """Every episode heard: stop a node still a process EXIT_HANG_S after its report, its last word, saying so;
    its work is done and the launch goes on as if it had exited 0. Seen once beside two busy loops: a world on
    static unicast peers (tests/test_hosts.py) played all its episodes, printed its report, and was still a
    process 90 s later, somewhere in the teardown of its node and context, and the launch waited for it."""
    now = time.monotonic()
    for child in running:
        if child.reported_at is None:
            if now - child.looked_at >= 1.0:  # the log is read at most once a second
                child.looked_at = now
                if child.reports():
                    child.reported_at = now
        elif now - child.reported_at > EXIT_HANG_S:
            child.hung_at_exit = True
            child.signal_group(signal.SIGKILL)
            child.process.wait(timeout=STOP_GRACE_S[-1][1])
            tqdm.write(f"cq-ros launch: {child.name} (pid {child.process.pid}) still running {EXIT_HANG_S:g} s after "
                       "its report, every episode played: stopped it", file=sys.stderr)


def _ended_as(listener: StatsListener, learners: list[int]) -> dict:
    """The manifest's `ended` of a launch that heard every episode: clean, or degraded (and why: a departure
    from the offline engine, or statistics that conflicted with the first heard of their episode)."""
    found = departures(listener, learners)
    why = [describe_departures(found)] if found else []
    if listener.conflicts:
        named = listener.named_conflicts().items()
        why.append("conflicting statistics (the first heard of each episode kept): " + "; ".join(
            f"{topic} episode{'s' if ',' in e or '-' in e else ''} {e}" for topic, e in named))
    if why:
        return {"how": "degraded", "reason": "; ".join(why), "exit_status": EXIT_DEGRADED}
    return {"how": "finished", "reason": "every episode played as the offline engine plays it",
            "exit_status": EXIT_CLEAN}


def _remove(made: Path | None) -> None:
    """Remove the folder a launch made (`made_by`), when it ended before anything worth keeping."""
    if made is not None:
        shutil.rmtree(made, ignore_errors=True)


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


def _last_rows(executor: Any, listener: StatsListener, rows: EpisodeRows, stop: StopSignals) -> None:
    """Write the rows of every episode the world has said it played, as their statistics come in (at most
    LAST_ROWS_S): a run that ends on a failure keeps each episode it heard the end of. (A second system's world
    that stepped one episode before it yielded said "after 1 episodes" and kept no row: its agents' statistics
    of that episode were still on their way.) A killed agent's statistics of its last episode may never come:
    the failure's line counts the rows kept, not the world's episodes."""
    def written() -> bool:
        rows.take(listener)
        return rows.failure is not None or rows.written >= min(len(listener.world), rows.episodes)

    spin_until(executor, written, LAST_ROWS_S, stop)


def _where(listener: StatsListener, node_names: list[str]) -> str:
    """Where a run is between two episodes: before its first step how many of its nodes are in the graph, then
    the world's episode and step by its heartbeat."""
    if listener.at is None or (listener.at == (0, 0) and not listener.world):
        ns = listener.node.get_namespace()
        up = {name for name, namespace in listener.node.get_node_names_and_namespaces() if namespace == ns}
        return f"starting: {len(up & set(node_names))}/{len(node_names)} nodes up"
    return f"episode {listener.at[0]}, step {listener.at[1]}"


def _watch(children: list[Child], listener: StatsListener, executor: Any, stop: StopSignals, bar: Progress,
           learners: list[int], rows: EpisodeRows, restart_agents: int = 0, env: dict | None = None,
           compose: bool = False, restarts: Restarts | None = None,
           node_names: tuple[str, ...] | list[str] = ()) -> None:
    """Spin the listener, writing the rows heard, until every child has exited 0; LaunchError/Interrupted as
    soon as one fails (an agent node restarted instead while `restart_agents` allows), EndedEarly as soon as a
    row cannot be written. Between episodes, `bar` says where the run is (`_where` of `node_names`)."""
    world_done_at = None
    while True:
        if stop:
            raise Interrupted(f"interrupted by {stop.received} after {len(listener.world)}/{listener.episodes} "
                              "episodes")
        executor.spin_once(timeout_sec=0.05)
        rows.take(listener)
        _rows_failed(rows)
        if len(listener.world) != bar.shown:
            latest = [listener.newest[k] for k in learners if k in listener.newest]
            bar.update(len(listener.world), listener.collisions, sum(s.joint_states for s in latest),
                       sum(listener.heard[k] for k in learners))
        bar.within(lambda: _where(listener, node_names))
        if not compose:
            _unstick(children, env, listener)
        failed = [c for c in children if c.exit_code not in (None, 0) and not c.hung_at_exit]
        if failed and not compose and children[0].running and failed[0] is not children[0] and \
                sum(c.restarts for c in children) < restart_agents:
            restarts.restart(failed[0], env)
            continue
        if failed:  # the episodes it counts are those whose rows it keeps (a killed agent's last never come)
            _last_rows(executor, listener, rows, stop)
            raise LaunchError(f"{failed[0].describe_exit()} after {rows.written}/{listener.episodes} "
                              f"episodes (its log: {failed[0].log})")
        running = [c for c in children if c.running]
        if not running:
            return
        if len(listener.world) >= listener.episodes:
            _stop_hung_at_exit(running)
        if world_done_at is None and not children[0].running:
            world_done_at = time.monotonic()
        if world_done_at is not None and time.monotonic() - world_done_at > AGENT_EXIT_GRACE_S:
            raise LaunchError(f"{', '.join(c.name for c in running)} still running {AGENT_EXIT_GRACE_S:g} s "
                              "after the world finished")

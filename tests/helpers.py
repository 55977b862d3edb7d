"""The suite's shared helpers (conftest.py turns the ROS ones into fixtures); no test module imports another.

- `wait_until`: the one bounded wait. Every wait in the suite polls an event (a file's line, a process's state,
  a message heard) until it holds or a deadline passes, and fails naming what it waited for.
- `wait_for_line`, `launch_command`, `read_episodes`, `unique`, `alive_with`: a launch as a process, and what
  it leaves behind.
- `System`, `start_system`, `finish`, `offline_rows`: a world and its agents in this process, on one executor.
- `with_rules`, `ours_without`, `run_as`: the paper's CQ with one rule of ours, ours without one, and a run of
  such a learner, so that a test shows what one rule does.
"""

from __future__ import annotations

import csv
import math
import os
import pickle
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, TypeVar

import numpy as np

T = TypeVar("T")

SEED = 1  # the launches' seed
RUN_TIMEOUT_S = 300.0  # a bound for any one in-process system run; they take seconds (a minute at load 18)
# The in-process runs' grid_game_2 case: a window CQ fills within a few dozen episodes, and a few greedy episodes.
GRID = ("grid_game_2", 1, (("window", 5), ("eval_episodes", 3)))


# Each rule of our CQ as the methods of cq.CQLearner it puts in place of the paper's (cq_paper.CQPaperLearner).
OUR_RULES = {"w1_alone": ("_start_windows",), "look_if_decisive": ("_looks",), "all_met": ("_acted_on",),
             "bootstrap_acted": ("_bootstraps_from_next_act", "_bootstrap"), "mark_colliders": ("_marks",),
             "waits_fresh": ("_new_row",)}


def with_rules(*rules):
    """The paper's CQ with these rules of ours (with none, the paper's learner itself)."""
    from cq_ros.learners.cq import CQLearner
    from cq_ros.learners.cq_paper import CQPaperLearner

    if not rules:
        return CQPaperLearner
    return type("CQWith", (CQPaperLearner,), {m: getattr(CQLearner, m) for r in rules for m in OUR_RULES[r]})


def ours_without(rule):
    """Our CQ with the paper's reading of `rule`."""
    from cq_ros.learners.cq import CQLearner
    from cq_ros.learners.cq_paper import CQPaperLearner

    return type("CQWithout", (CQLearner,), {m: getattr(CQPaperLearner, m) for m in OUR_RULES[rule]})


def run_as(learner_class, gridmap, settings, seed: int, run_index: int, episodes: int) -> np.ndarray:
    """The learning episodes (cq_ros.episode's table) of a run as cq_ros.engine.run plays `cq`, with every
    learner made a `learner_class` once made (a rule of ours taken away or given alone)."""
    from cq_ros import engine

    learners = engine.make_learners("cq", gridmap, settings, seed, run_index)
    for learner in learners:
        learner.__class__ = learner_class
    team = engine.Team(engine.GridWorld(gridmap, settings, seed=engine.world_seed(seed, run_index)), learners)
    return engine.record.table(team.episode() for _ in range(episodes))


class WaitTimeout(AssertionError):
    """A bounded wait ran out (or what it waited on ended first)."""


def wait_until(predicate: Callable[[], T], timeout_s: float, what: str, *, between: Callable[[], object] | None = None,
               poll_s: float = 0.05, ended: Callable[[], bool] | None = None, detail: Callable[[], str] | None = None,
               fail: bool = True) -> T | bool:
    """Call predicate() until it returns something true, and return that. Between two calls, `between()` (spin an
    executor once, say) or a sleep of poll_s. Once timeout_s has passed, or `ended()` holds (a process that has
    exited will never log the line), raise WaitTimeout saying `what` was not seen, with `detail()` (a log's tail);
    with fail=False return False instead."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        stopped = ended is not None and ended()
        if stopped and (value := predicate()):  # it came just before the end
            return value
        if stopped or time.monotonic() > deadline:
            if not fail:
                return False
            why = "what it waited on ended first" if stopped else f"not within {timeout_s:g} s"
            raise WaitTimeout(f"{what}: {why}" + (f"\n{detail()}" if detail is not None else ""))
        if between is not None:
            between()
        else:
            time.sleep(poll_s)


def spin_until(executor, predicate: Callable[[], bool], timeout_s: float) -> bool:
    """Spin `executor` until predicate() holds: True, or False at the timeout (the caller asserts)."""
    return bool(wait_until(predicate, timeout_s, "spin_until", between=lambda: executor.spin_once(timeout_sec=0.05),
                           fail=False))


def _read(path: Path) -> str:
    try:
        return path.read_text(errors="replace")
    except FileNotFoundError:
        return ""


def wait_for_line(log: Path, phrase: str, timeout_s: float, process=None, detail: Path | None = None) -> str:
    """The first line of the file `log` that holds `phrase`, once written (bounded by timeout_s; fails sooner if
    `process` exits first), failing with the tail of `detail` (default: the log itself)."""

    def line() -> str | None:
        return next((s for s in _read(log).splitlines() if phrase in s), None)

    return wait_until(line, timeout_s, f"no {phrase!r} in {log.name}",
                      ended=None if process is None else lambda: process.poll() is not None,
                      detail=lambda: _read(detail or log)[-3000:])


def unique(prefix: str) -> str:
    """A name unique to one test (a namespace, say), for alive_with to find its processes by."""
    return f"{prefix}_{uuid.uuid4().hex[:8]}"


def launch_command(out: Path, namespace: str, map_name: str, algo: str, episodes: int, sets=(), *extra: str,
                   seed: int = SEED) -> list[str]:
    """`cq-ros launch` as a process, with `--set` for each of `sets` and further arguments `extra`."""
    return [sys.executable, "-m", "cq_ros.cli", "launch", "--map", map_name, "--algo", algo, "--episodes",
            str(episodes), "--seed", str(seed), "--out", str(out), "--namespace", namespace,
            *[arg for s in sets for arg in ("--set", s)], *extra]


def read_episodes(out: Path) -> np.ndarray:
    """episodes.csv's records as a cq_ros.episode table, as RunResult.episodes holds them."""
    from cq_ros.episode import COLUMNS, DTYPE

    with open(out / "episodes.csv", newline="") as f:
        return np.array([tuple(float(row[c]) for c in COLUMNS) for row in csv.DictReader(f)], dtype=DTYPE)


def alive_with(token: str) -> list[str]:
    """Command lines of live processes that mention `token` (a namespace or path unique to one test): no orphan may
    outlive its test."""
    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:  # gone meanwhile
            continue
        if token in cmdline and int(pid) != os.getpid():
            found.append(f"{pid}: {cmdline}")
    return found


@dataclass
class System:
    """A world, its agents and a probe recording world/stats and agv<k>/stats, on one executor."""

    world: object  # WorldNode
    agents: list  # of AgentNode
    executor: object  # SingleThreadedExecutor
    world_stats: list = field(default_factory=list)
    agent_stats: dict = field(default_factory=dict)
    others: list = field(default_factory=list)  # further nodes on the executor (probe, injectors)

    def add(self, node):
        self.others.append(node)
        self.executor.add_node(node)
        return node

    def finished(self) -> bool:
        return self.world.done.done() and all(a.done.done() for a in self.agents)

    def close(self) -> None:
        self.executor.shutdown()
        for node in [self.world, *self.agents, *self.others]:
            node.destroy_node()


def parameters(**values) -> list:
    from rclpy.parameter import Parameter

    return [Parameter(name, value=value) for name, value in values.items()]


def start_system(ctx, algo, map_name, seed, episodes, settings=(), *, world_extra=None,
                 agent_extra=None, common_extra=None, agent_class=None) -> System:
    """A world and its agents as a launcher starts them, and a probe recording every statistics message:
    the world waits for the probe's world/stats subscription and each agent holds its statistics until the
    probe's agv<k>/stats subscription has matched (min_stats_subscribers=1 for both). `common_extra` goes
    to every node, `agent_class` (agent id -> class) replaces AgentNode for some."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from agent_node import AgentNode
    from cq_ros.gridmap import load_map
    from msgs_spec import AGENT_STATS, WORLD_STATS, WORLD_STATS_TOPIC, agent_stats_topic, decode_agent_stats, \
        decode_world_stats
    from node_runtime.qos import profile
    from world_node import WorldNode

    common = {"map": map_name, "episodes": episodes, "seed": seed, **dict(settings), **(common_extra or {})}
    world = WorldNode(context=ctx, parameter_overrides=parameters(
        **{**common, "step_timeout": 30.0, "min_stats_subscribers": 1, **(world_extra or {})}))
    n = load_map(map_name).n_agents
    ids = [0] if algo == "jsa" else range(1, n + 1)
    agents = [(agent_class or {}).get(k, AgentNode)(f"agv{k}" if k else "central", context=ctx,
                                                    parameter_overrides=parameters(
        **common, algo=algo, agent_id=k, min_stats_subscribers=1, **(agent_extra or {}).get(k, {})))
        for k in ids]
    system = System(world, agents, SingleThreadedExecutor(context=ctx))
    probe = system.add(rclpy.create_node("probe", context=ctx))
    probe.create_subscription(WORLD_STATS.msg_type, WORLD_STATS_TOPIC,
                              lambda m: system.world_stats.append(decode_world_stats(m)), profile(WORLD_STATS.qos))
    for k in range(1, n + 1):
        system.agent_stats[k] = []
        probe.create_subscription(AGENT_STATS.msg_type, agent_stats_topic(k), lambda m, k=k: system.agent_stats[
            k].append(decode_agent_stats(m)), profile(AGENT_STATS.qos))
    for node in (*agents, world):
        system.executor.add_node(node)
    return system


def finish(system: System) -> System:
    """Spin `system` to its end (bounded) and until the probe has every statistics message; every node exited 0."""
    assert spin_until(system.executor, system.finished, RUN_TIMEOUT_S), "the run did not finish in time"
    episodes = system.world.config.total_episodes
    everything = [system.world_stats, *system.agent_stats.values()]
    assert spin_until(system.executor, lambda: all(len(got) >= episodes for got in everything), 30.0), \
        [len(got) for got in everything]
    assert system.world.done.result() == 0 and all(a.done.result() == 0 for a in system.agents)
    return system


def offline(algo, map_name, seed, episodes, settings=()):
    from cq_ros.engine import run
    from cq_ros.gridmap import load_map
    from cq_ros.settings import Settings

    return run(algo, load_map(map_name), Settings().with_overrides(dict(settings)), seed, 0, episodes)


def offline_rows(algo, map_name, seed, episodes, settings=()):
    """The engine's rows of every episode a ROS run plays: the learning ones, then the greedy ones."""
    result = offline(algo, map_name, seed, episodes, settings)
    return np.concatenate([result.episodes, result.greedy])


# -- checkpoints ------------------------------------------------------------------------------------------

class Payload:
    """Unpickling it creates `marker`: what a crafted checkpoint would do."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return open, (self.marker, "w")


def crafted_pickle(path, marker):
    """A checkpoint of the old pickled format whose learner, once unpickled, has run code (made `marker`)."""
    path.write_bytes(pickle.dumps({"format": 3, "algo": "cq", "map": "tunnel_to_goal", "agent": 0, "episode": 5,
                                   "learner": Payload(marker)}))


# -- a junk flood on every topic of a namespace ------------------------------------------------------------

def _array(ros_type, label: str, size: int, data) -> bytes:
    from rclpy.serialization import serialize_message
    from std_msgs.msg import MultiArrayDimension

    msg = ros_type()
    msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=size)]
    msg.data = list(data)
    return serialize_message(msg)


def _statistics(statuses: list[tuple[str, str, list[tuple[str, str]]]]) -> bytes:
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.serialization import serialize_message

    return serialize_message(DiagnosticArray(status=[
        DiagnosticStatus(name=name, hardware_id=hw, values=[KeyValue(key=k, value=v) for k, v in pairs])
        for name, hw, pairs in statuses]))


def junk(spec, agent: int | None, rng) -> list[bytes]:
    """Serialized junk for a topic of `spec` (agent k's, or the world's with None), one of each kind a flood
    without the key sends: garbage values, NaN and infinities (or int32's extremes), negative ids, a well-formed
    message without a MAC, a forged MAC, 20,000 values, a 10 KB label, a wrong length; on a statistics topic
    2,000 pairs, 500 statuses, a well-formed statistic without a MAC, garbage values, a 10 KB value."""
    from msgs_spec import AGENT_STATS, encode
    from msgs_spec.arrays import LAYOUT_BY_PAYLOAD
    from msgs_spec.payloads import INT32_MAX

    if spec.msg_type.__name__ == "DiagnosticArray":
        name, hw = (f"agv{agent}/stats", f"agv{agent}") if spec is AGENT_STATS else ("world/stats", "world")
        well_formed = [(kv.key, kv.value) for kv in encode(_example(spec)(agent)).status[0].values]
        return [_statistics([(name, hw, [(f"k{i}", str(rng.random())) for i in range(2000)])]),
                _statistics([(name, hw, well_formed)] * 500),
                _statistics([(name, hw, well_formed)]),
                _statistics([(name, hw, [(k, "nan" if i % 2 else "-3") for i, (k, _) in enumerate(well_formed)])]),
                _statistics([(name, hw, [*well_formed[:-1], (well_formed[-1][0], "9" * 10_000)])])]
    layout = LAYOUT_BY_PAYLOAD[spec.payload]
    floats = layout.ros_type.__name__ == "Float64MultiArray"
    n, label = layout.size, layout.label
    extremes = [math.nan, math.inf, -math.inf] if floats else [INT32_MAX, -INT32_MAX - 1]
    forged_mac = [rng.randrange(2**31) for _ in range(n + 7)]
    return [_array(layout.ros_type, label, n, [rng.randrange(-99, 10**6) for _ in range(n)]),
            _array(layout.ros_type, label, n, [extremes[i % len(extremes)] for i in range(n)]),
            _array(layout.ros_type, label, n, [-1 - i for i in range(n)]),
            _array(layout.ros_type, label, n, [agent or 1] + [0] * (n - 1)),
            _array(layout.ros_type, layout.keyed_label, n + 7, forged_mac),
            _array(layout.ros_type, label, 20_000, range(20_000)),
            _array(layout.ros_type, "x" * 10_000, n, range(n)),
            _array(layout.ros_type, label, n, range(n - 2))]


def _example(spec):
    from dataclasses import replace

    from msgs_spec import AGENT_STATS
    from msgs_spec.spec_doc import EXAMPLES

    if spec is AGENT_STATS:
        return lambda agent: replace(EXAMPLES["agent_stats"], agent=agent, marked=())
    return lambda _agent: EXAMPLES["world_stats"]


class Flood:
    """A node with a writer on every topic of a system's namespace (`n_agents` agents), sending junk (`junk`)
    round the topics, no key. `sent` counts what went to each topic (relative name); `refused_keyless` the
    heartbeats a reader without the key refuses too (the world reads heartbeats so: a twin has a key of its
    own). Writers keep 1000 messages for their readers (1 on the latched position topics, whose history each new
    subscription is sent). The context is its own, with the nodes' Fast DDS profile."""

    def __init__(self, namespace: str, n_agents: int, seed: int, domain_id: int):
        import random

        import rclpy
        from rclpy.context import Context

        from msgs_spec import HEARTBEAT, POSITION, agent_topics, decode_heartbeat
        from msgs_spec.topics import replace_depth
        from node_runtime.qos import profile
        from node_runtime.run import FASTDDS_PROFILE, FASTDDS_PROFILE_ENV

        before = os.environ.get(FASTDDS_PROFILE_ENV)
        os.environ.setdefault(FASTDDS_PROFILE_ENV, str(FASTDDS_PROFILE))  # read as the participant is made
        try:
            self.context = Context()
            rclpy.init(context=self.context, domain_id=domain_id)
            self.node = rclpy.create_node("flood", namespace=f"/{namespace}", context=self.context)
        finally:  # the test's other contexts as they were
            if before is None:
                del os.environ[FASTDDS_PROFILE_ENV]
        rng = random.Random(seed)
        self.topics = []  # (relative name, its writer, its junk)
        for name, spec, agent in agent_topics(n_agents):
            qos = profile(replace_depth(spec.qos, 1 if spec is POSITION else 1000))
            self.topics.append((name, self.node.create_publisher(spec.msg_type, name, qos), junk(spec, agent, rng)))
        self.sent = {name: 0 for name, _, _ in self.topics}
        self.refused_keyless = 0
        self._heartbeat = HEARTBEAT.pattern
        self._keyless = {}
        for name, _, messages in self.topics:
            if name == self._heartbeat:
                for raw in messages:
                    try:
                        decode_heartbeat(raw)
                        self._keyless[raw] = False
                    except Exception:
                        self._keyless[raw] = True
        self._turn = 0

    def matched(self, readers: dict[str, int]) -> bool:
        """Whether each topic named in `readers` has at least that many readers matched."""
        counts = {name: pub.get_subscription_count() for name, pub, _ in self.topics}
        return all(counts[name] >= n for name, n in readers.items())

    def send(self, n: int) -> None:
        """n more messages, a topic after the other, each topic's junk kinds in turn."""
        for _ in range(n):
            name, pub, messages = self.topics[self._turn % len(self.topics)]
            raw = messages[(self._turn // len(self.topics)) % len(messages)]
            pub.publish(raw)
            self.sent[name] += 1
            if name == self._heartbeat and self._keyless[raw]:
                self.refused_keyless += 1
            self._turn += 1

    @property
    def total(self) -> int:
        return self._turn

    def acknowledged(self, timeout_s: float) -> bool:
        """Whether every reader has acknowledged all that was sent, within timeout_s."""
        from rclpy.duration import Duration

        return all(pub.wait_for_all_acked(Duration(seconds=timeout_s)) for _, pub, _ in self.topics)

    def close(self) -> None:
        import rclpy

        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

"""What a launch hears and how it is written (ros_tools.launch runs it): the launcher's statistics
listener, episodes.csv written row by row as the episodes are heard, and the result files at the end.

Every end writes the manifest. Finished, a node that died, Ctrl-C or SIGTERM, a disk that filled, a twin: the
manifest says how the launch ended (`ended`: how, the one-line reason, the exit status) with the counters heard so
far (`write_ended_early`), and where the run left the offline engine's behaviour (`departures`: a step whose action
the world missed or did not apply, a feedback the agent never heard), and how many episodes that touched.

Disks fill. A row is written (whole, or not at all: a row cut short by a full disk is cut off again) as soon
as the world's and every learner's statistics of its episode are in, so a disk that fills keeps every row it
could take, and the launch ends early with one line naming the file and the OS's reason. At the start the
launcher also writes a small reserve file, given back when a write fails, so that the manifest saying the
run ended early, and why, still fits on a disk that is full.
"""

from __future__ import annotations

import csv
import errno
import io
import json
import os
import hashlib
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from cq_ros import episode as record
from cq_ros.engine import RunResult
from cq_ros.episode import Episode
from cq_ros.gridmap import GridMap
from cq_ros.lab.results import EPISODE_COLUMNS, EPISODES, MANIFEST, episode_row, manifest_for, write_results
from cq_ros.lab.output import OutputError, os_reason
from cq_ros.settings import Settings
from msgs_spec import (
    AGENT_STATS, HEARTBEAT, HEARTBEAT_TOPIC, WORLD_STATS, WORLD_STATS_TOPIC, AgentStats, Bounds, DropCounter, WireError,
    WorldStats, agent_stats_topic, decode_agent_stats, decode_heartbeat, decode_world_stats,
)
from node_runtime.qos import profile
from node_runtime.rclpy_workarounds import take_now
from node_runtime.report import rates

__all__ = ["RESERVE_NAME", "RESERVE_BYTES", "DEPARTURES", "StatsListener", "EpisodeRows", "LaunchResult", "write_heard",
           "write_ended_early", "checkpoint_failures", "departures", "describe_departures", "counted", "COMMUNICATION",
           "cost"]

RESERVE_NAME = ".reserve"  # in the result directory while the launch runs
RESERVE_BYTES = 64 * 1024  # room for the manifest (a few KiB) once the disk is full
TAKEN_AT_ONCE = 1000  # messages a listener's subscription takes per wake of the executor, at most (_subscribe)
# An agent's counters that say a step was not played as the offline engine plays it: an action the world did
# not apply (late or lost), a feedback never heard (caught up past it). The world's own is `missed_actions`.
DEPARTURES = ("unapplied_actions", "caught_up", "missed_feedback")


@dataclass
class LaunchResult:
    out: Path
    episodes: np.ndarray  # a cq_ros.episode table, as RunResult.episodes
    greedy: np.ndarray  # the same for the greedy episodes, as RunResult.greedy
    manifest: dict


def _ranges(numbers: list[int]) -> str:
    """[0, 1, 2, 5] -> '0-2, 5'."""
    spans: list[list[int]] = []
    for n in numbers:
        if spans and n == spans[-1][1] + 1:
            spans[-1][1] = n
        else:
            spans.append([n, n])
    return ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in spans)


class StatsListener:
    """The launcher's subscriptions: every WorldStats and AgentStats of the run (`episodes` of each: learning
    and greedy episodes alike), decoded through the contract (a bad message is logged, counted and dropped,
    never raised).

    With the run's `key` only this system's statistics count; given the `run` nonce, only this run's (one sealed
    with another, a recording of an earlier run under the same key file, is `dropped.other_run`). The first
    statistic heard for an episode is kept: a later one that says otherwise is a conflict, never a replacement,
    logged and counted (`dropped.conflicting`) and named by topic and episode (`conflicts`).

    Statistics are read as bytes and judged from their header before they are deserialized (msgs_spec.stats:
    a flood's 2,000 pairs or 500 statuses cost a header's reading). A heartbeat that does not decode is counted
    too (by its own counter, quietly: the heartbeat is only a display here, not worth a line)."""

    def __init__(self, node: Any, gridmap: GridMap, episodes: int, key: bytes | None = None, run: int | None = None):
        self.node, self.key, self.run = node, key, run
        self.episodes = episodes
        self.bounds = Bounds(gridmap.n_agents, gridmap.height, gridmap.width)
        # Until this run's first episode is heard, a dropped message is more likely a second system in the
        # namespace (its world then refuses, and the launch says so in one line) than a fault worth a line:
        # those lines are held, and shown once the run is heard (`show_held`) or dropped with the launch.
        self.held: list[str] | None = []
        self.drops = DropCounter(self._drop_line)
        self.beats_dropped = DropCounter()
        self.world: dict[int, WorldStats] = {}
        self.collisions = 0  # over the episodes heard so far, for the progress display
        self.agents: dict[int, dict[int, AgentStats]] = {k: {} for k in range(1, gridmap.n_agents + 1)}
        self.newest: dict[int, AgentStats] = {}  # each agent's statistics of its latest episode so far
        # each agent's peer messages: the positions its decisions took in (`heard`, cq_ros.episode), summed over
        # the episodes heard; the cost the offline engine counts too (COMMUNICATION says why not the deliveries)
        self.heard: dict[int, int] = {k: 0 for k in self.agents}
        self.conflicts: dict[str, list[int]] = {}  # topic -> episodes of which a statistic disagreed with the first
        # topic -> episode -> a digest of the first statistic heard: what a later one is compared with, once the
        # kept statistic has been slimmed (`settle`)
        self._digests: dict[str, dict[int, bytes]] = {}
        # Learners whose node the launch restarted: an episode of theirs never heard before a later one is one
        # they were away for (a node sends its statistics in order, and resumes where the world is).
        self.restarted: set[int] = set()
        # node -> per restart, the learning its learner lost: the episodes it had learnt past the checkpoint it
        # went back to (ros_tools.launch records them; the manifest's `restarts.learning_lost`)
        self.learning_lost: dict[str, list[dict[str, int]]] = {}
        self._agent_subs = [self._subscribe(AGENT_STATS, agent_stats_topic(k), partial(self._on_agent, k))
                            for k in self.agents]
        self._world_sub = self._subscribe(WORLD_STATS, WORLD_STATS_TOPIC, self._on_world)
        # Where the world is, by its heartbeat (every second): progress within an episode, which on a big map
        # can take minutes.
        self.at: tuple[int, int] | None = None
        self._heartbeat_sub = self._subscribe(HEARTBEAT, HEARTBEAT_TOPIC, self._on_heartbeat, HEARTBEAT.reader_qos)

    def _subscribe(self, spec: Any, topic: str, on_message: Any, qos: Any = None) -> Any:
        """A raw subscription to `topic` whose callback, woken by one message, also takes each further one its
        reader holds (at most TAKEN_AT_ONCE, then the other subscriptions get their turn). The executor takes one
        message per wait, a few hundred microseconds in rclpy 7.1.6 and more on a busy machine, while judging a
        junk statistic takes about 3 microseconds: a flood sent faster than that filled the reader's queue
        (READER_DEPTH, shared by every writer) and evicted real statistics (a suite run beside two busy loops:
        "the launcher never got agv1/stats episodes 276-277"). Taken in a burst, the queue drains as fast as the
        codec judges."""
        subscription = []

        def on_wake(msg: Any) -> None:
            on_message(msg)
            for _ in range(TAKEN_AT_ONCE - 1):
                taken = take_now(subscription[0])
                if taken is None:
                    return
                on_message(taken[0])

        subscription.append(self.node.create_subscription(spec.msg_type, topic, on_wake,
                                                          profile(qos or spec.qos), raw=True))
        return subscription[0]

    def _drop_line(self, line: str) -> None:
        if self.held is None:
            self.node.get_logger().warning(line)
        else:
            self.held.append(line)

    def show_held(self) -> None:
        """Log the drop lines held so far, and every later one as it comes."""
        held, self.held = self.held or [], None
        for line in held:
            self.node.get_logger().warning(line)

    def _on_world(self, msg: Any) -> None:
        stats = self.drops.guard(decode_world_stats, msg, bounds=self.bounds, key=self.key, run=self.run,
                                 source=WORLD_STATS_TOPIC)
        if stats is not None and self.held is not None:
            self.show_held()
        if stats is not None and self._first(self.world, stats, WORLD_STATS_TOPIC):
            self.collisions += stats.collisions

    def _on_heartbeat(self, msg: Any) -> None:
        beat = self.beats_dropped.guard(decode_heartbeat, msg, key=self.key, source=HEARTBEAT_TOPIC)
        if beat is not None:
            self.at = (beat.episode, beat.step)

    def _on_agent(self, agent: int, msg: Any) -> None:
        stats = self.drops.guard(decode_agent_stats, msg, bounds=self.bounds, agent=agent, key=self.key,
                                 run=self.run, source=agent_stats_topic(agent))
        if stats is not None and self._first(self.agents[agent], stats, agent_stats_topic(agent)):
            self.heard[agent] += stats.heard
            if agent not in self.newest or stats.episode > self.newest[agent].episode:
                self.newest[agent] = stats

    def _first(self, heard: dict[int, Any], stats: Any, topic: str) -> bool:
        """Keep `stats` if it is the first heard of its episode; one that differs from the first is a conflict
        (the same one again, a resend, is nothing)."""
        digests = self._digests.setdefault(topic, {})
        digest = hashlib.blake2b(repr(stats).encode(), digest_size=16).digest()
        kept = digests.setdefault(stats.episode, digest)
        if stats.episode not in heard:
            heard[stats.episode] = stats
            return True
        if kept != digest:
            self.drops.record(WireError("conflicting", f"episode {stats.episode} statistics unlike the first heard "
                                                       "of it (kept)"), topic)
            self.conflicts.setdefault(topic, []).append(stats.episode)
        return False

    def settle(self, episode: int) -> None:
        """Slim the statistics of `episode`, whose row is written and which no file reads whole again: what the
        departures and sums read stays (the world's figures, the learners' DEPARTURES counters); the marked joint
        states and the other counters go, so that a long run keeps a few hundred bytes an episode, not kilobytes
        (a CQ agent's marked joint states are in each of its statistics)."""
        w = self.world.get(episode)
        if w is not None:
            self.world[episode] = replace(w, counters={})
        for got in self.agents.values():
            a = got.get(episode)
            if a is not None:
                got[episode] = replace(a, marked=(), counters={k: a.counters[k] for k in DEPARTURES
                                                               if k in a.counters})

    def named_conflicts(self) -> dict[str, str]:
        """topic -> the episodes of which it carried conflicting statistics, as ranges ('3, 5-7')."""
        return {topic: _ranges(sorted(set(episodes))) for topic, episodes in self.conflicts.items()}

    def launcher_counts(self) -> dict[str, Any]:
        """The manifest's `launcher`: what the listener dropped, by kind and by topic, the topics it heard a flood
        on, and the conflicts by topic."""
        by_kind, by_topic = self.drops.as_counters(), dict(self.drops.by_source)
        for kind, n in self.beats_dropped.as_counters().items():
            by_kind[kind] = by_kind.get(kind, 0) + n
        for topic, n in self.beats_dropped.by_source.items():
            by_topic[topic] = by_topic.get(topic, 0) + n
        return {"dropped": dict(sorted(by_kind.items())),
                **({"dropped_on": dict(sorted(by_topic.items()))} if by_topic else {}),
                **({"floods": rates(self.drops.floods)} if self.drops.floods else {}),
                **({"conflicts": self.named_conflicts()} if self.conflicts else {})}

    def row(self, episode: int, learners: list[int]) -> Episode | None:
        """Episode `episode`'s record, as the engine's, once the world's statistics and every learner's of it
        are in (else None): steps, collisions and truncation and the return summed over the agents from
        WorldStats; joint plays, states and peer positions heard summed over the learners' AgentStats."""
        w = self.world.get(episode)
        a = [self.agents[k].get(episode) for k in learners if not self.away(k, episode)]
        if w is None or None in a:
            return None
        return Episode(steps=w.steps, collisions=w.collisions, joint_plays=sum(s.joint_plays for s in a),
                       states=sum(s.local_states + s.joint_states for s in a), ret=sum(w.returns),
                       truncated=w.truncated, heard=sum(s.heard for s in a))

    def away(self, agent: int, episode: int) -> bool:
        """Was `agent`'s node restarted, and away for `episode` (its statistics of a later one came, of this one
        none)?"""
        return agent in self.restarted and episode not in self.agents[agent] and \
            agent in self.newest and self.newest[agent].episode > episode

    def without(self) -> dict[int, list[int]]:
        """agent -> the episodes its restarted node was away for."""
        return {k: [e for e in range(self.episodes) if self.away(k, e)] for k in sorted(self.restarted)}

    def restarts(self) -> dict[str, Any]:
        """The manifest's `restarts` (empty without one): per restarted node the episodes it was away for and
        the learning each restart lost."""
        if not self.restarted:
            return {}
        return {"restarts": {"episodes_without": {f"agv{k}": _ranges(v) for k, v in self.without().items() if v},
                             "learning_lost": self.learning_lost}}

    @property
    def complete(self) -> bool:
        return len(self.world) == self.episodes and all(
            len(s) == self.episodes or (k in self.restarted and all(e in s or self.away(k, e)
                                                                     for e in range(self.episodes)))
            for k, s in self.agents.items())

    def missing(self) -> list[str]:
        """What has not come yet, e.g. ['world/stats episodes 7-9', 'agv2/stats episode 0']."""
        wanted = range(self.episodes)
        out = []
        heard = [(WORLD_STATS_TOPIC, self.world, None)] + [(agent_stats_topic(k), v, k) for k, v in self.agents.items()]
        for topic, got, agent in heard:
            gone = [e for e in wanted if e not in got and (agent is None or not self.away(agent, e))]
            if gone:
                out.append(f"{topic} episode{'s' if len(gone) > 1 else ''} {_ranges(gone)}")
        return out


class EpisodeRows:
    """episodes.csv of a launch, a row per learning episode, in order, each written as soon as it is heard.

    `failure` is None until a write fails; then it names the file and the OS's reason, the file ends with the
    last whole row, and the reserve is given back. Before each row the file is looked up by its path (one
    stat an episode): if the folder, or the file, was removed or moved, `gone` is set with `failure`, as
    nothing more can be kept there. OutputError at the start when the folder cannot take the reserve and
    the header."""

    def __init__(self, out: Path, map_name: str, algo: str, learners: list[int], episodes: int):
        self.path, self.reserve = out / EPISODES, out / RESERVE_NAME
        self.map_name, self.algo, self.learners, self.episodes = map_name, algo, learners, episodes
        self.written = 0  # rows on disk
        self.failure: str | None = None
        self.gone = False  # the file is no longer at its path: its folder (or it) was removed or moved
        self._fd = -1
        try:
            with open(self.reserve, "wb") as f:
                f.write(bytes(RESERVE_BYTES))
                f.flush()
                os.fsync(f.fileno())
            self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            self._write(EPISODE_COLUMNS)
        except OSError as e:
            self.close()
            self.free()
            raise OutputError(f"output directory {out}: cannot write there: {os_reason(e)}") from None

    def take(self, listener: StatsListener) -> None:
        """Write every row heard since the last call, in order (none after a failure)."""
        while self.failure is None and self.written < self.episodes:
            heard = listener.row(self.written, self.learners)
            if heard is None:
                return
            if not self._in_place():
                self.gone = True
                self.failure = f"results folder {self.path.parent} was removed or moved ({self.path.name} is no " \
                               "longer there)"
                self.close()
                return
            try:
                self._write(episode_row(self.map_name, self.algo, 0, self.written, record.table([heard])[0]))
            except OSError as e:
                self.failure = f"cannot write {self.path}: {os_reason(e)}"
                self.close()
                self.free()
                return
            self.written += 1
            if self.written >= 2:  # the newest row's statistics stay whole: the last heard, if the run ends now
                listener.settle(self.written - 2)

    def _in_place(self) -> bool:
        """Whether the file written is still the one at its path."""
        try:
            here, written = os.stat(self.path), os.fstat(self._fd)
        except FileNotFoundError:
            return False
        return (here.st_dev, here.st_ino) == (written.st_dev, written.st_ino)

    def _write(self, row) -> None:
        line = io.StringIO()
        csv.writer(line).writerow(row)
        data = line.getvalue().encode()
        start = os.lseek(self._fd, 0, os.SEEK_CUR)
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(self._fd, view):]
        except OSError:
            os.ftruncate(self._fd, start)  # no half row: a reader sees whole rows only
            raise

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def free(self) -> None:
        """Give the reserve back (at the end, or to make room for the manifest on a full disk)."""
        self.reserve.unlink(missing_ok=True)


def departures(listener: StatsListener, learners: list[int]) -> dict[str, Any]:
    """Where the run heard so far left the offline engine's behaviour: the world's missed actions and each
    DEPARTURES counter of the learners (summed), the episodes in which any of them grew, and the first of those
    (from there on, learning went another way: every later episode may differ too). Empty: none did."""
    totals: dict[str, int] = {}
    touched = []
    before = {k: {} for k in learners}  # each learner's cumulative counters at its previous episode heard
    for e in sorted(listener.world):
        grew = listener.world[e].missed_actions > 0
        totals["missed_actions"] = totals.get("missed_actions", 0) + listener.world[e].missed_actions
        for k in learners:
            stats = listener.agents[k].get(e)
            if stats is None:
                continue
            for name in DEPARTURES:
                now, was = stats.counters.get(name, 0), before[k].get(name, 0)
                was = 0 if now < was else was  # a restarted node counts from 0 again
                if now > was:
                    grew = True
                    totals[name] = totals.get(name, 0) + now - was
            before[k] = stats.counters
        if grew:
            touched.append(e)
    totals = {k: v for k, v in totals.items() if v}
    if not touched:
        return {}
    return {**totals, "episodes": len(touched), "first_episode": touched[0]}


def describe_departures(found: dict[str, Any]) -> str:
    """One line for the summary of a run that left the offline engine's behaviour (`departures`)."""
    what = ", ".join(f"{found[k]} {k.replace('_', ' ')}" for k in ("missed_actions", *DEPARTURES) if k in found)
    return (f"this run left the offline engine's behaviour: {what}, in {found['episodes']} episode"
            f"{'s' if found['episodes'] != 1 else ''} (the first: episode {found['first_episode']}; learning "
            "went another way from there)")


def checkpoint_failures(counters: dict[str, int]) -> list[str]:
    """'[Errno 28] No space left on device (4 times)' for each checkpoint_failed.<errno> an agent counted."""
    out = []
    for key, n in counters.items():
        if key.startswith("checkpoint_failed."):
            code = getattr(errno, key.split(".", 1)[1].upper(), None)
            reason = f"[Errno {code}] {os.strerror(code)}" if code else key.split(".", 1)[1]
            out.append(f"{reason} ({n} time{'s' if n != 1 else ''})")
    return out


def counted(name: str, last: Any, reports: Mapping[str, dict]) -> dict[str, Any]:
    """A node's counters for the manifest: those of its report at exit (node_runtime.report) where it left one,
    so that what it counted after its last statistics is in, with its drops by topic and its floods; else those
    of its last statistics `last` (None: none heard). `counters_as_of` says which."""
    report = reports.get(name)
    if report is not None:
        return {"counters": report["counters"], "counters_as_of": "exit",
                **{part: report[part] for part in ("dropped_on", "floods") if report[part]}}
    if last is None:
        return {"counters": {}, "counters_as_of": "nothing heard"}
    return {"counters": dict(last.counters), "counters_as_of": f"episode {last.episode} (its last statistics)"}


def write_heard(out: Path, gridmap: GridMap, algo: str, episodes: int, seed: int, settings: Settings,
                wall: float, listener: StatsListener, learners: list[int], learner_nodes: list[str],
                nodes: dict, run_info: dict, *, episodes_written: bool = False,
                ended: dict | None = None, reports: Mapping[str, dict] | None = None) -> LaunchResult:
    """episodes.csv (unless `episodes_written`: a launch's EpisodeRows wrote it), observe.csv, greedy.csv and
    manifest.json from the statistics heard: the first `episodes` (learning) and the greedy ones after them
    (ros_tools.launch says what comes from where); `nodes` is the manifest's account of the nodes (a launch's
    commands and exit codes), run_info the run's own entries, `ended` how the launch ended (as
    write_ended_early's), `reports` the nodes' reports at exit (`counted`). `cq-ros collect` (ros_tools.collect)
    writes through it too. OSError if the disk refuses them."""
    reports = reports or {}
    played = range(listener.episodes)
    world = [listener.world[e] for e in played]
    per_learner = [[listener.agents[k][e] for k in learners if e in listener.agents[k]] for e in played]
    rows = record.table(listener.row(e, learners) for e in played)
    table, greedy = rows[:episodes], rows[episodes:]
    kept = [(s.agent - 1, gridmap.index(m.row, m.col), m.peer - 1, gridmap.index(m.peer_row, m.peer_col),
             m.confidence) for s in per_learner[episodes - 1] for m in s.marked]
    final = [listener.newest[k] for k in learners]  # the counters are cumulative: the last hold the launch's
    manifest = manifest_for(
        gridmap, [algo], 1, episodes, seed, settings, wall, **run_info, nodes=nodes,
        communication={name: {"subscriptions_created": s.subscriptions_created,
                              "subscriptions_active": s.subscriptions_active, **cost(listener, k),
                              **counted(name, s, reports)}
                       for name, k, s in zip(learner_nodes, learners, final)},
        world={"missed_actions": sum(w.missed_actions for w in world), **counted("world", world[-1], reports),
               "stepping_s": round(sum(w.duration_s for w in world), 3)},
        launcher=listener.launcher_counts(),
        departures=departures(listener, learners), **({"ended": ended} if ended is not None else {}),
        **listener.restarts())
    write_results(out, gridmap, [RunResult(algo, 0, table, kept, greedy)], manifest, episodes_written=episodes_written)
    return LaunchResult(out, table, greedy, manifest)


# What an agent's peer messages are, in the manifest's `communication`: `peer_messages`, the peer positions its
# decisions took in, one per peer it looked at per decision step (the `heard` column of episodes.csv and
# greedy.csv, summed over its episodes): the cost the offline engine counts, so one figure offline, composed and
# a process per node. `peer_deliveries` is what its peer subscriptions were delivered, which depends on the
# middleware's timing, so on the mode: a new subscription's first sample is the latched position of an earlier
# step, a lingering one takes positions nobody decides on, a renewed one is delivered again (docs/ros.md).
COMMUNICATION = ("peer_messages", "peer_deliveries")


def cost(listener: StatsListener, agent: int) -> dict[str, int]:
    """`agent`'s peer messages (COMMUNICATION) as the listener heard them."""
    return dict(zip(COMMUNICATION, (listener.heard[agent], listener.newest[agent].peer_messages)))


def write_ended_early(out: Path, gridmap: GridMap, algo: str, episodes: int, seed: int, settings: Settings,
                      wall: float, rows: EpisodeRows, nodes: dict, run_info: dict, reason: str,
                      listener: StatsListener | None = None, learners: list[int] | None = None,
                      learner_nodes: list[str] | None = None, ended: dict | None = None,
                      reports: Mapping[str, dict] | None = None) -> str:
    """manifest.json of a launch that ended early (`reason`), with the rows written and, given the `listener`,
    the counters (each node's report at exit, else its last statistics: `counted`) and the departures from the
    offline run; what became of it, for the launch's last line."""
    heard = {}
    reports = reports or {}
    if listener is not None and learners is not None:
        world = [listener.world[e] for e in sorted(listener.world)]
        heard = {"departures": departures(listener, learners),
                 "world": {"missed_actions": sum(w.missed_actions for w in world),
                           **counted("world", world[-1] if world else None, reports)},
                 "communication": {name: {"episodes_heard": len(listener.agents[k]),
                                          **(cost(listener, k) if k in listener.newest else {}),
                                          **counted(name, listener.newest.get(k), reports)}
                                   for name, k in zip(learner_nodes or [], learners)
                                   if k in listener.newest or name in reports},
                 "launcher": listener.launcher_counts(), **listener.restarts()}
    manifest = manifest_for(gridmap, [algo], 1, episodes, seed, settings, wall, **run_info, nodes=nodes,
                            ended_early={"reason": reason, "episodes_written": rows.written}, **heard,
                            **({"ended": ended} if ended is not None else {}))
    rows.free()  # room for the manifest on a full disk
    try:
        (out / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
    except OSError as e:
        return f"{MANIFEST} not written either: {os_reason(e)}"
    return f"{out / MANIFEST} says so"

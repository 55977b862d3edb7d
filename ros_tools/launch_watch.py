"""The watch loop of a launch: spin the listener and write the rows heard until every child has exited 0, and end
the launch as soon as one fails (an agent node started again instead while `restart_agents` allows:
ros_tools.restarts), hangs, or a row cannot be written. Between episodes the progress says where the run is.
"""

from __future__ import annotations

import signal
import sys
import time
from typing import Any

from tqdm import tqdm

from .children import STOP_GRACE_S, Child
from .launch_end import Interrupted, LaunchError, rows_failed
from .launch_results import EpisodeRows, StatsListener
from .progress import Progress
from .restarts import Restarts
from .session import StopSignals, spin_until

__all__ = ["watch"]

NODE_UP_S, STUCK_TRIES = 60.0, 2  # a node process that logs nothing this long after its start is started again
AGENT_EXIT_GRACE_S = 10.0  # an agent still running this long after the world finished is stuck
# A node still a process this long after its report (its last word) hangs in its teardown, every episode heard:
# it is stopped (`_stop_hung_at_exit`).
EXIT_HANG_S = 5.0
# after a child fails, how long to wait for the rows of the episodes the world has said it played: the agents'
# statistics of its last episode are sent at the same moment as its own and may still be on their way
LAST_ROWS_S = 2.0


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


def watch(children: list[Child], listener: StatsListener, executor: Any, stop: StopSignals, bar: Progress,
          learners: list[int], rows: EpisodeRows, restart_agents: int, env: dict, compose: bool,
          restarts: Restarts, node_names: list[str]) -> None:
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
        rows_failed(rows)
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

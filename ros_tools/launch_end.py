"""How a launch ends: its exit status, the errors it raises, and what each end leaves in the result folder.

Every end writes manifest.json: `ended` says how (finished, degraded, node_failed, twin, interrupted, disk,
incomplete: a node hung or statistics never came), the one-line reason and the exit status, beside each node's
counters (ros_tools.launch_results). Only a launch that refused at its start (a second system in its namespace,
or its world's twin) before a row of its own leaves nothing but its line: the folder it made is removed.
"""

from __future__ import annotations

import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from cq_ros.gridmap import GridMap
from cq_ros.lab.output import os_reason
from cq_ros.settings import Settings
from world_node.lockstep import TWIN_EXIT as WORLD_TWIN

from .children import Child, stop_children
from .launch_results import (
    EpisodeRows, LaunchResult, StatsListener, checkpoint_failures, departures, describe_departures, write_ended_early,
    write_heard,
)

__all__ = ["EXIT_CLEAN", "EXIT_FAILED", "EXIT_DEGRADED", "EXIT_INTERRUPTED", "LaunchError", "Interrupted",
           "NamespaceTaken", "EndedEarly", "ResultsGone", "rows_failed", "remove", "Ending"]

# The launch's exit status (`cq-ros launch`): every episode played as the offline engine plays it; a launch that
# failed or ended early; every episode played, but some step not as offline (a missed or unapplied action, a
# feedback never heard: the summary says where); Ctrl-C or SIGTERM.
EXIT_CLEAN, EXIT_FAILED, EXIT_DEGRADED, EXIT_INTERRUPTED = 0, 1, 3, 130


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


def rows_failed(rows: EpisodeRows) -> None:
    """Raise what a failure of episodes.csv ends the launch with, if there was one."""
    if rows.failure:
        raise (ResultsGone if rows.gone else EndedEarly)(rows.failure)


def remove(made: Path | None) -> None:
    """Remove the folder a launch made (`made_by`), when it ended before anything worth keeping."""
    if made is not None:
        shutil.rmtree(made, ignore_errors=True)


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


@dataclass
class Ending:
    """What one launch writes at its end: `finished` once every episode is heard, `failed` for a LaunchError
    (each gives what to raise, its line saying what became of the run). `made` is the folder the launch made
    (`made_by`), `started` its time.perf_counter() at the start."""

    out: Path
    gridmap: GridMap
    algo: str
    episodes: int
    seed: int
    settings: Settings
    run_info: dict
    children: list[Child]
    rows: EpisodeRows
    listener: StatsListener
    learners: list[int]
    learner_nodes: list[str]
    made: Path | None
    started: float

    def node_info(self) -> dict:
        return {c.name: {"command": c.command, "exit_code": c.exit_code, "log": str(c.log.relative_to(self.out)),
                         **({"restarts": c.restarts} if c.restarts else {}),
                         **({"stuck_starts": c.stuck_starts} if c.stuck_starts else {})} for c in self.children}

    def reports(self) -> dict[str, dict]:
        """Every node's report at its end (each child's log, since its latest start): its final counters."""
        return {name: report for c in self.children for name, report in c.reports().items()}

    def write_ended(self, reason: str, how: str, status: int) -> str:
        """The manifest of a launch that ended before its results (`reason`): what became of it, for the line."""
        return write_ended_early(self.out, self.gridmap, self.algo, self.episodes, self.seed, self.settings,
                                 time.perf_counter() - self.started, self.rows, self.node_info(), self.run_info,
                                 reason, self.listener, self.learners, self.learner_nodes,
                                 ended={"how": how, "reason": reason, "exit_status": status}, reports=self.reports())

    def ended_early(self, reason: str) -> EndedEarly:
        kept = self.write_ended(f"the launcher {reason}", "disk", EndedEarly.exit_status)
        return EndedEarly(f"the launcher {reason}: the run ended early after {self.rows.written}/{self.episodes} "
                          f"episodes; those rows are in {self.rows.path}, and {kept}")

    def failed(self, e: LaunchError) -> LaunchError:
        """Stop every child and write what the failure `e` leaves."""
        children, rows = self.children, self.rows
        stopping = [c.name for c in children if c.running]
        stop_children(children)
        rows.close()
        if isinstance(e, EndedEarly):
            return self.ended_early(str(e))
        if isinstance(e, ResultsGone):  # nowhere left to write a manifest or read a log
            return ResultsGone(f"{e}: the run stopped after {rows.written}/{self.episodes} episodes; stopped "
                               f"{', '.join(stopping) or 'nothing'}")
        stopped = f"; stopped {', '.join(stopping)}" if stopping else ""
        # A launch or node that refused (a second system here) before any row of this run leaves nothing worth
        # keeping, and the line says why; a node that crashed or was stopped leaves its log to read, and the
        # manifest says how the run ended, with the counters of each node.
        refused = isinstance(e, NamespaceTaken) or any(c.exit_code == 2 for c in children)
        if rows.written == 0 and refused and self.made is not None:
            rows.free()
            remove(self.made)
            return type(e)(f"{e}{stopped}; {self.made} removed")
        if not refused:
            self.listener.show_held()
        failed = any(c.exit_code not in (None, 0) for c in children)
        how = "interrupted" if isinstance(e, Interrupted) else "twin" if children[0].exit_code == WORLD_TWIN \
            else "node_failed" if failed else "incomplete"  # incomplete: a node hung, or statistics never came
        kept = self.write_ended(f"{e}{stopped}", how, e.exit_status)
        return type(e)(f"{e}{stopped} (logs in {self.out / 'logs'}; {kept})")

    def finished(self, nodes: dict[str, tuple[str, dict]], figures: bool) -> LaunchResult:
        """The results of a launch that heard every episode, its children stopped: degraded or clean, known from
        the statistics only, so the manifest is written with both and then told."""
        self.rows.close()
        try:
            result = write_heard(self.out, self.gridmap, self.algo, self.episodes, self.seed, self.settings,
                                 time.perf_counter() - self.started, self.listener, self.learners,
                                 self.learner_nodes, self.node_info(), self.run_info, episodes_written=True,
                                 ended=_ended_as(self.listener, self.learners), reports=self.reports())
            self.rows.free()
            if figures:
                from cq_ros.lab.plots import write_figures  # matplotlib only where figures are wanted

                # a map file is known by its name only here
                write_figures(self.out, map_loader=lambda _name: self.gridmap)
        except OSError as e:
            raise self.ended_early(f"cannot write {e.filename or self.out}: {os_reason(e)}") from None
        for name, stats in result.manifest["communication"].items():  # the nodes' own losses, last
            for failure in checkpoint_failures(stats["counters"]):
                print(f"cq-ros launch: warning: {name}: checkpoint {nodes[name][1]['checkpoint']} not written: "
                      f"{failure}; learning went on", file=sys.stderr)
        return result

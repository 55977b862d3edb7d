"""A node process's last word: what it counted, as it stands once its executor has stopped, in one line of its log.

A node's statistics carry its counters as of its latest episode; whatever it counts after that (junk that goes on
coming while it finishes, or while a launch is stopped mid-episode) would be lost with the process. `run_node`
prints this line for every node it ran, after the executor stopped (nothing more can be counted then), whatever
ended it: finished, gave up, Ctrl-C or SIGTERM (only kill -9 leaves none). `cq-ros launch` reads the last one of
each node from the logs it keeps, and writes those counters to the manifest (ros_tools.launch_results).

    cq-ros node report: {"counters": {...}, "dropped_on": {"agv1/action": 120}, "floods": {...}, "node": "world"}

`counters` are the ones the node's statistics carry; `dropped_on` its drops by topic, `floods` the topics it
reported a flood on, at the rate it said (msgs_spec.DropCounter).
"""

from __future__ import annotations

import json
from typing import Any, Mapping

from msgs_spec import DropCounter

__all__ = ["PREFIX", "node_report", "report_line", "read_reports", "rates"]

PREFIX = "cq-ros node report: "


def rates(floods: Mapping[str, float]) -> dict[str, int]:
    """topic -> drops a second, whole, as a flood was reported."""
    return {source: round(rate) for source, rate in sorted(floods.items())}


def node_report(name: str, counters: Mapping[str, int], drops: DropCounter) -> dict[str, Any]:
    """What a node says at its end: its name, its counters, its drops by topic and its floods."""
    return {"node": name, "counters": dict(sorted(counters.items())),
            "dropped_on": dict(sorted(drops.by_source.items())), "floods": rates(drops.floods)}


def report_line(report: Mapping[str, Any]) -> str:
    return PREFIX + json.dumps(report, sort_keys=True)


def _well_formed(report: Any) -> bool:
    def counts(d: Any) -> bool:
        return isinstance(d, dict) and all(isinstance(k, str) and type(v) is int and v >= 0 for k, v in d.items())

    return isinstance(report, dict) and isinstance(report.get("node"), str) and all(
        counts(report.get(part)) for part in ("counters", "dropped_on", "floods"))


def read_reports(text: str) -> dict[str, dict[str, Any]]:
    """node name -> its last report in `text` (a log; a composed process's holds several nodes'); a line cut
    short or not of this form is no report."""
    found = {}
    for line in text.splitlines():
        if not line.startswith(PREFIX):
            continue
        try:
            report = json.loads(line[len(PREFIX):])
        except ValueError:
            continue
        if _well_formed(report):
            found[report["node"]] = report
    return found

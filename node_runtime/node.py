"""What the world node and the agent node share around their cores: declaring their kind's parameters (a bad one
destroys the node and raises), the graph watch, the timers that stop when the node finishes, the report of what
it counted, and ending once, with `done` holding the exit code.

A node's `core` (world_node.lockstep.Lockstep, an agent_node.driver driver) makes every decision; it counts its
drops (`drops`), reports its counters (`counters()`) and takes the node's own counts in `extra_counters`.
"""

from __future__ import annotations

from typing import Any, Callable

from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.task import Future

from cq_ros.settings import SettingsError

from .graph import CHECK_PERIOD_S, GraphWatch, watch_graph
from .parameters import declare_node_parameters
from .report import node_report

__all__ = ["RunNode"]


class RunNode(Node):
    """`make(values, log)` -> (config, core) from the parameters of node kind `kind` (node_runtime.parameters);
    a bad value raises cq_ros.settings.SettingsError, or rclpy's ParameterException for a value of the wrong
    type (either: one line naming the parameter), and the node is destroyed. A subclass says how it ends
    (`close(code)`, which sets `done` once its last messages are out)."""

    def __init__(self, node_name: str, kind: str, make: Callable[[dict, Callable], tuple[Any, Any]], **kwargs: Any):
        super().__init__(node_name, **kwargs)
        try:
            self.config, self.core = make(declare_node_parameters(self, kind), self.get_logger().warning)
        except (SettingsError, ParameterException):
            self.destroy_node()
            raise
        self.done = Future()
        self.closing = False  # finishing: flushing the last messages before `done`
        self._timers: list = []
        self._graph = GraphWatch(self.get_name(), self.get_namespace(), self.get_logger().warning)
        self._graph_topics: list[str] = []

    def every(self, period: float, callback: Callable[[], Any]) -> Any:
        """A timer of the node's that stops when it finishes."""
        timer = self.create_timer(period, callback)
        self._timers.append(timer)
        return timer

    def watch(self, topics: list[str]) -> None:
        """Look at the writers of `topics` every CHECK_PERIOD_S (node_runtime.graph), counted by the core."""
        self._graph_topics = topics
        self.every(CHECK_PERIOD_S, self.check_graph)

    def check_graph(self) -> None:
        watch_graph(self, self._graph, self._graph_topics)
        self.core.extra_counters.update(self._graph.counters())

    def report(self) -> dict:
        """What it counted so far, by kind and by topic (node_runtime.report)."""
        return node_report(self.get_name(), self.core.counters(), self.core.drops)

    def finish(self, code: int) -> None:
        """End with exit code `code`, once: the timers stop, then `close` sends what is left."""
        if self.closing:
            return
        self.closing = True
        for timer in self._timers:
            timer.cancel()
        self.close(code)

    def close(self, code: int) -> None:
        raise NotImplementedError

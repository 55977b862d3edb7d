"""What a node makes of the ROS graph around it: second writers on its topics, a second system. `GraphWatch`
decides without ROS; `watch_graph` hands it what a node sees of the graph. `Matched` keeps a publisher's
matched-subscription count from its events, for what a node checks every step.

rclpy 7.1.6's message info names no publisher, so a second writer cannot be told apart message by message;
the graph (`get_publishers_info_by_topic`) does list every writer. Every topic of ours has one rightful
writer (the world, or one agent node), so more than one writer on a topic is logged, once per new set of
writers, and counted (`second_writers` in the node's statistics). Writers that all bear one node's name are
counted apart (`same_name_writers`): a restarted node's ghost (its DDS entry stays until its lease runs out,
about 20 s), a false alarm as a second writer, or a twin of it, which the run's key tells apart (the world
ends the run on a twin agent: world_node.lockstep).

A second system on the same ROS_DOMAIN_ID and namespace shows as a second node with our name in our
namespace, which `check` logs once. What a world does about a twin is world_node.twin's rule; for an agent a
twin is only logged: a killed process stays in the graph until its DDS lease runs out (about 20 s), so an
agent restarted after a crash would see its own ghost. `writers` lists a topic's writers by node name.
"""

from __future__ import annotations

from typing import Any, Callable, Iterable, Mapping

__all__ = ["CHECK_PERIOD_S", "UNKNOWN_NODE", "GraphWatch", "watch_graph", "writers", "writers_and_namesakes", "Matched"]

CHECK_PERIOD_S = 1.0  # how often a node looks at the graph
# The name the graph gives a writer whose node it has not learnt yet (rmw_dds_common's graph cache: endpoints
# and node names are discovered apart)
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"


class GraphWatch:
    """Feed it the graph now and then (`check`); it logs and counts."""

    def __init__(self, name: str, namespace: str, log: Callable[[str], Any] | None = None):
        self.name, self.namespace = name, namespace
        self._log = log or (lambda _msg: None)
        self._seen: dict[str, frozenset] = {}  # topic -> the set of writers last logged
        self.second_writers = 0  # times a topic was seen with a new set of more than one writer
        self.same_name_writers = 0  # the same, when every writer bears one node's name (a restart's ghost)
        self._twin_logged = False

    def check(self, nodes: Iterable[tuple[str, str]], writers: Mapping[str, list[tuple[str, str, Any]]]) -> None:
        """`nodes`: (name, namespace) of every node in the graph; `writers`: topic -> (node name, namespace,
        endpoint gid) of each of its publishers."""
        twins = sum(1 for n in nodes if tuple(n) == (self.name, self.namespace)) > 1
        if twins and not self._twin_logged:
            self._twin_logged = True
            self._log(f"a second node named {self.namespace.rstrip('/')}/{self.name} is on this ROS_DOMAIN_ID (a "
                      "second system in our namespace, or a restarted node's ghost)")
        for topic, pubs in writers.items():
            if len(pubs) <= 1:
                continue
            who = frozenset((n, ns, bytes(gid)) for n, ns, gid in pubs)
            if who != self._seen.get(topic):
                self._seen[topic] = who
                names = sorted({f"{ns.rstrip('/')}/{n}" for n, ns, _ in who})
                if len(names) == 1:
                    self.same_name_writers += 1
                    self._log(f"{len(pubs)} writers on {topic}, all named {names[0]}: a restarted node's ghost "
                              "until its DDS lease runs out (about 20 s), or a twin of it (with the run's key, a "
                              "twin agent ends the run)")
                    continue
                self.second_writers += 1
                self._log(f"{len(pubs)} writers on {topic} ({', '.join(names)}): it has one rightful writer; "
                          "messages of the others are dropped only if they fail the checks (a key makes sure "
                          "they do)")

    def counters(self) -> dict[str, int]:
        out = {"second_writers": self.second_writers, "same_name_writers": self.same_name_writers}
        return {k: v for k, v in out.items() if v}


def writers(node: Any, topic: str) -> list[tuple[str, str, Any]]:
    """(node name, namespace, endpoint gid) of each writer of `topic` (UNKNOWN_NODE for a node not learnt yet)."""
    return [(p.node_name, p.node_namespace, p.endpoint_gid) for p in node.get_publishers_info_by_topic(topic)]


def writers_and_namesakes(node: Any, topic: str) -> tuple[list[tuple[str, str, Any]], int]:
    """What world_node.twin reads of the graph: the writers of `topic` (when there is more than the node's own
    one), and how many nodes bear the node's name and namespace."""
    beating = writers(node, topic) if node.count_publishers(topic) > 1 else []
    me = (node.get_name(), node.get_namespace())
    return beating, sum(1 for n in node.get_node_names_and_namespaces() if tuple(n) == me)


def watch_graph(node: Any, watch: Any, topics: list[str]) -> None:
    """Hand the graph around `node` (its peers' names, every writer of `topics`) to a GraphWatch."""
    # Only a topic with a second writer has anything to tell, and counting is cheap where listing each writer
    # is not (every node of a composed warehouse looks at dozens of topics each second).
    seen = {node.resolve_topic_name(t): writers(node, t) for t in topics if node.count_publishers(t) > 1}
    watch.check(node.get_node_names_and_namespaces(), seen)


class Matched:
    """How many subscriptions a publisher has matched, as its matched events tell: give it as the publisher's
    `PublisherEventCallbacks(matched=...)`. Reading `count` costs nothing, where get_subscription_count() asks
    the graph each time: what a node checks every step (is anyone watching?) reads this. It lags the graph
    until the executor has handled the event; `then` is called after each change."""

    def __init__(self, then: Callable[[], Any] | None = None):
        self.count = 0
        self._then = then

    def __call__(self, info: Any) -> None:
        self.count = info.current_count
        if self._then is not None:
            self._then()

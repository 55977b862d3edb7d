"""What every ROS tool of ours stands on: its own rclpy Context and node (`ros_session`), environment variables
rcl reads at init (`environment`), Ctrl-C and SIGTERM as a flag a loop checks (`StopSignals`), bounded spinning
(`spin_until`), waiting for discovery to settle (`settle`), and finding a running system on the graph
(`find_system`). The user commands (commands.py,
launch.py and its parts, collect.py, view.py) import it; it imports none of them.
"""

from __future__ import annotations

import os
import re
import signal
import threading
import time
from contextlib import contextmanager
from typing import Any, Callable, Iterator

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

__all__ = ["ToolError", "StopSignals", "environment", "environment_domain", "ros_session", "spin_until", "settle",
           "graph_now", "others_in", "find_system", "WORLD", "FIND_S", "QUIET_S", "SETTLE_S"]

# How long to look for the system's nodes by default: a node process takes seconds to start on 2 busy cores.
FIND_S = 60.0
WORLD = "world"
# Discovery has settled once the graph has not changed for QUIET_S, looked at for SETTLE_S at the most. A node
# process shows up 0.05-2.8 s after it starts (docs/design.md, field notes), and the nodes of a launch started
# together come one after another over seconds: `cq-ros topics` with a fixed 3 s listed 9 of a fresh launch's 16
# topics. Ours shows up at once, and those already running within a few hundred milliseconds, from their first
# burst of announcements; on 2 cores beside two busy loops that burst can go unheard, and the next announcement
# comes 3 s later (Fast DDS's period): with 1.5 s of quiet, `topics` ended before it had heard a node already
# there, and a second launch found its namespace empty and started. So the quiet spans one such period.
QUIET_S, SETTLE_S = 3.5, 15.0
_AGENT_NODE = re.compile(r"agv[1-9][0-9]*|jsa")


class ToolError(RuntimeError):
    """A tool could not do its job (topic not found, no message before the timeout, ...): one line."""


class StopSignals:
    """Within `with StopSignals() as stop:`, SIGINT and SIGTERM set `stop.received` (the signal's name)
    instead of raising, so a loop that checks `stop` between short waits ends cleanly (closes its bag,
    stops its children). Outside the main thread Python cannot install handlers: then it does nothing."""

    def __init__(self) -> None:
        self.received: str | None = None
        self._saved: dict[int, Any] = {}

    def __bool__(self) -> bool:
        return self.received is not None

    def __enter__(self) -> "StopSignals":
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._saved[sig] = signal.signal(sig, self._on_signal)
        return self

    def __exit__(self, *exc: Any) -> None:
        for sig, handler in self._saved.items():
            signal.signal(sig, handler)

    def _on_signal(self, signum: int, _frame: Any) -> None:
        self.received = signal.Signals(signum).name


@contextmanager
def environment(**values: str) -> Iterator[None]:
    """Set these environment variables (rcl reads some only at init) and restore them afterwards."""
    saved = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def environment_domain() -> int | None:
    """The ROS_DOMAIN_ID the user set (None when unset or empty, as rcl reads it); ValueError naming the variable
    when it is no domain id (0..232, as --domain-id takes: Fast DDS derives its ports from it)."""
    value = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not value:
        return None
    if not value.isdigit() or int(value) > 232:
        raise ValueError(f"ROS_DOMAIN_ID={value!r} in the environment is not a domain id (an integer 0..232)")
    return int(value)


@contextmanager
def ros_session(name: str, *, domain_id: int | None = None, namespace: str | None = None,
                localhost_only: bool = False, hidden: bool = True) -> Iterator[tuple[Any, SingleThreadedExecutor]]:
    """(node, executor) on a fresh rclpy Context, torn down in the Jazzy order (executor, node, context).

    `domain_id` None: ROS_DOMAIN_ID from the environment (`environment_domain`), as every ROS tool, else rcl's 0.
    `localhost_only` keeps discovery on this host (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, read by rcl at init
    only). A `hidden` node's name starts with '_' (hidden from `nodes`, as ros2cli's own nodes are). rclpy
    installs no signal handlers: use StopSignals."""
    ctx = Context()
    env = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"} if localhost_only else {}
    with environment(**env):
        rclpy.init(context=ctx, domain_id=environment_domain() if domain_id is None else domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
    node = executor = None
    try:
        node = rclpy.create_node(f"_{name}_{os.getpid()}" if hidden else name, context=ctx, namespace=namespace,
                                 enable_rosout=False, start_parameter_services=False)
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        yield node, executor
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=ctx)


def spin_until(executor: SingleThreadedExecutor, done: Callable[[], bool], timeout_s: float | None,
               stop: StopSignals | None = None) -> bool:
    """Spin until done() (True), the timeout passes or a stop signal comes (False). None: no timeout."""
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    while not done():
        if stop or (deadline is not None and time.monotonic() >= deadline):
            return False
        executor.spin_once(timeout_sec=0.05)
    return True


def graph_now(node: Any) -> tuple[frozenset, frozenset]:
    """What a change of the graph is seen in: its nodes (name, namespace) and its topics with their types."""
    return (frozenset(map(tuple, node.get_node_names_and_namespaces())),
            frozenset((name, tuple(types)) for name, types in node.get_topic_names_and_types()))


def settle(node: Any, executor: Any, stop: StopSignals | None = None, bound_s: float = SETTLE_S,
           quiet_s: float = QUIET_S, look: Callable[[Any], Any] = graph_now) -> bool:
    """Spin until what `look` sees of the graph has not changed for `quiet_s`, at most `bound_s` (or a stop
    signal); True if it settled. rclpy 7.1.6 has no graph event to wait on (its own wait_for_node polls too),
    so the graph is looked at between spins."""
    seen, since = look(node), time.monotonic()

    def quiet() -> bool:
        nonlocal seen, since
        now = look(node)
        if now != seen:
            seen, since = now, time.monotonic()
        return time.monotonic() - since >= quiet_s

    return spin_until(executor, quiet, bound_s, stop)


def others_in(node: Any, executor: Any, namespace: str, stop: StopSignals | None = None) -> list[str]:
    """The nodes of a system in `namespace` ('/name') beside `node` once discovery has settled there, sorted:
    a world, agents, or a namesake of `node` (a second launcher's listener). Other nodes there (a monitor, a
    recorder) are no system and do not count."""
    def there(n: Any) -> list[str]:
        return sorted(name for name, ns in n.get_node_names_and_namespaces() if ns == namespace
                      and (name in (WORLD, node.get_name()) or _AGENT_NODE.fullmatch(name)))

    settle(node, executor, stop, look=there)
    found = there(node)
    if node.get_namespace() == namespace and node.get_name() in found:
        found.remove(node.get_name())  # ourselves, once
    return found


def find_system(node: Any, executor: Any, namespace: str | None, stop: StopSignals,
                wait_s: float = FIND_S) -> tuple[str, list[str]]:
    """(namespace, agent node names) of the one system on the graph (its `world` node's namespace), or of the
    one in `namespace`; ToolError when there is none or, without `namespace`, several."""
    def systems() -> dict[str, list[str]]:
        found: dict[str, list[str]] = {}
        pairs = node.get_node_names_and_namespaces()
        for name, ns in pairs:
            if name == WORLD:
                found.setdefault(ns, [])
        for name, ns in pairs:
            if ns in found and _AGENT_NODE.fullmatch(name):
                found[ns].append(name)
        return {ns: agents for ns, agents in found.items() if namespace is None or ns == namespace}

    # Then settled: a system's agent nodes may be discovered after its world.
    deadline = time.monotonic() + wait_s
    if spin_until(executor, lambda: any(systems().values()), wait_s, stop):
        settle(node, executor, stop, min(SETTLE_S, max(0.0, deadline - time.monotonic())))
    found = systems()
    if not found or not any(found.values()):
        where = f"namespace {namespace}" if namespace else "this domain"
        raise ToolError(f"no system (a `world` node and its agent nodes) on {where} after {wait_s:g} s")
    if len(found) > 1:
        raise ToolError(f"several systems on this domain ({', '.join(sorted(found))}): choose one with --namespace")
    (ns, agents), = found.items()
    return ns, sorted(agents, key=lambda a: (len(a), a))

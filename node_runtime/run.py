"""The run loop of a node process: `python -m world_node`, `python -m agent_node` and the composed container
(`python -m ros_tools.compose`) all spin their nodes through `run_node`, on the executor `make_executor` picks;
the two node programs' whole main is `node_main`.

rclpy's EventsExecutor is the default, stepped in bounded spins (spin_until_future_complete with a timeout; its
unbounded spin() in rclpy 7.1.6 busy-loops and ignores signals, docs/design.md, field notes);
`$CQ_ROS_EXECUTOR=single` picks the SingleThreadedExecutor.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any, Callable

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

from cq_ros.settings import SettingsError

from .parameters import help_requested, print_help
from .report import report_line

__all__ = ["EXECUTORS", "EXECUTOR_ENV", "SPIN_S", "FASTDDS_PROFILE", "FASTDDS_PROFILE_ENV", "executor_kind",
           "make_executor", "spin_nodes", "run_node", "node_main", "POLL_S", "when", "FLUSH_TIMEOUT_S", "when_acked"]


# The executors a node process can spin on (`$CQ_ROS_EXECUTOR`, `cq-ros launch --executor`). rclpy's
# EventsExecutor is the default: lockstep in one process ran 4.5x as fast on it as on the
# SingleThreadedExecutor, and never slower across processes (benchmarks/bench_ros.py --executors).
EXECUTORS = ("events", "single")
EXECUTOR_ENV = "CQ_ROS_EXECUTOR"
SPIN_S = 0.05  # the longest a node process spins in one call before it looks at its nodes again
# Fast DDS protocol timers for node processes (the file says why): a new peer subscription gets its first
# sample in a few ms instead of up to 70 ms.
FASTDDS_PROFILE = Path(__file__).with_name("fastdds_profile.xml")
FASTDDS_PROFILE_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"


def executor_kind(kind: str | None = None) -> str:
    """`kind`, else $CQ_ROS_EXECUTOR, else "events"; ValueError (one line) if it is not one of EXECUTORS."""
    kind = kind or os.environ.get(EXECUTOR_ENV) or EXECUTORS[0]
    if kind not in EXECUTORS:
        raise ValueError(f"executor {kind!r} (${EXECUTOR_ENV} or --executor): choose from {', '.join(EXECUTORS)}")
    return kind


def make_executor(kind: str | None = None, context: Context | None = None) -> Any:
    """A new executor of `executor_kind(kind)` on `context` (None: the default, initialised already).

    Spin it in bounded calls in a loop (`spin_nodes`), never spin(): the EventsExecutor's spin() in rclpy 7.1.6
    busy-loops and ignores signals (docs/design.md, field notes)."""
    if executor_kind(kind) == "single":
        return SingleThreadedExecutor(context=context)
    from rclpy.experimental import EventsExecutor

    return EventsExecutor(context=context)


def spin_nodes(executor: Any, nodes: list[Any], stop: Callable[[], bool] = lambda: False) -> int | None:
    """Spin until every node's `done` Future holds its exit code (then the largest of them), or until their
    context is shut down (a signal, under rclpy's handlers) or stop() turns true: None."""
    from rclpy.task import Future

    context = nodes[0].context
    pending = list(nodes)
    # One call runs every callback due until a node is done or SPIN_S has passed: a composed warehouse has
    # dozens of callbacks a step, and a spin_once per callback cost a call into the executor (its lock, the GIL
    # released and taken back) and a turn of this loop each. The EventsExecutor's bounded form returns on time
    # and hands a signal on as spin_once does; its unbounded spin() is the one that never returns (docs/design.md,
    # field notes). Each call waits on a Future of its own, woken by any node's `done`: the executor adds a
    # callback to the Future it is given at every call, which on a node's `done` would pile up all run long.
    woken: list[Any] = [Future()]

    def wake(_done: Any) -> None:
        if not woken[0].done():
            woken[0].set_result(None)

    for node in nodes:
        node.done.add_done_callback(wake)
    while pending:
        if pending[-1].done.done():
            pending.pop()
            continue
        if not context.ok() or stop():
            return None
        woken[0] = Future()
        executor.spin_until_future_complete(woken[0], timeout_sec=SPIN_S)
    return max(node.done.result() for node in nodes)


def run_node(make_node: Callable[[], Any], program: str, bad_input: tuple[type[Exception], ...]) -> int:
    """The `python -m world_node|agent_node|ros_tools.compose` main: spin the node, or the list of nodes,
    made by make_node() on the default context, on one executor (`make_executor`), until every `done`
    Future holds its exit code; the process exits with the largest. Each node's report (node_runtime.report:
    its counters as they stand at the end) is printed once the executor has stopped. A bad parameter (an exception in
    bad_input) is one line on stderr and exit code 2; Ctrl-C or SIGTERM exit code 130. make_node() must
    destroy what it made before it raises. Fast DDS reads FASTDDS_PROFILE unless $FASTRTPS_DEFAULT_PROFILES_FILE
    names another file."""
    from rclpy.exceptions import ParameterException
    from rclpy.executors import ExternalShutdownException

    try:
        kind = executor_kind()
    except ValueError as e:
        print(f"{program}: {e}", file=sys.stderr)
        return 2
    missing = _missing_params_files(sys.argv)
    if missing:
        print(f"{program}: --params-file {missing}: no such file", file=sys.stderr)
        return 2
    os.environ.setdefault(FASTDDS_PROFILE_ENV, str(FASTDDS_PROFILE))  # read when rclpy.init makes the participant
    try:
        rclpy.init(args=sys.argv)
    except RuntimeError as e:  # rcl refused the arguments (e.g. a parameters file it cannot parse)
        print(f"{program}: bad ROS arguments: {str(e).splitlines()[0]}", file=sys.stderr)
        return 2
    executor = make_executor(kind)
    nodes: list[Any] = []
    code = 130
    # Ctrl-C is two events: rclpy's handler shuts the context down (a spin or a call into rcl then raises
    # RCLError), then Python's raises KeyboardInterrupt at its next bytecode, which may fall inside the handler of
    # that RCLError: the outer try takes it wherever it lands.
    try:
        try:
            made = make_node()
            nodes = made if isinstance(made, list) else [made]
            for node in nodes:
                executor.add_node(node)
            finished = spin_nodes(executor, nodes)
            code = 130 if finished is None else finished  # None: shut down by a signal
        except (*bad_input, ParameterException) as e:
            print(f"{program}: {e}", file=sys.stderr)
            code = 2
        except Exception:
            if rclpy.ok():  # a real error; otherwise a signal shut the context down while the node was starting
                raise
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        # Jazzy order (docs/design.md, field notes): executor, then nodes, then the context.
        executor.shutdown()
        for node in nodes:  # nothing more is counted once the executor stopped: each node's last word
            print(report_line(node.report()), flush=True)
            node.destroy_node()
        rclpy.try_shutdown()
    return code


def node_main(usage: str, kind: str, make_node: Callable[[], Any]) -> int:
    """The main of `python -m world_node` and `python -m agent_node` (`kind` "world" or "agent"): -h or --help
    prints `usage` (the module's docstring) and the kind's parameters and starts nothing; otherwise
    `run_node(make_node, ...)`, a bad setting (SettingsError) read as a bad parameter."""
    if help_requested(sys.argv):
        return print_help(usage, (kind,))
    return run_node(make_node, f"{kind}_node", (SettingsError,))


def _missing_params_files(argv: list[str]) -> str | None:
    """The first `--params-file PATH` after --ros-args that names no readable file."""
    for flag, path in zip(argv, argv[1:]):
        if flag == "--params-file" and not os.access(path, os.R_OK):
            return path
    return None


POLL_S = 0.05  # how often `when` looks again


def when(node: Any, ready: Callable[[], bool], timeout_s: float, then: Callable[[bool], Any]) -> None:
    """then(True) as soon as ready() holds (looked at now, then every POLL_S on a timer of `node`), or
    then(False) once timeout_s has passed; the executor runs on meanwhile. A node must never wait inside a
    callback: in a composed process it would stall every other node (an agent's blocking wait for the
    acknowledgement of its last statistics took up to 2 s, and the world timed out agents still playing)."""
    if ready():
        then(True)
        return
    deadline = time.monotonic() + timeout_s

    def look() -> None:
        done = ready()
        if done or time.monotonic() >= deadline:
            timer.cancel()
            node.destroy_timer(timer)
            then(done)

    timer = node.create_timer(POLL_S, look)


# At the end, how long a node gives its readers to acknowledge the last reliable messages it sent: they go
# with the process otherwise (an exited node's reader is no longer waited for).
FLUSH_TIMEOUT_S = 2.0


def when_acked(node: Any, publishers: list[Any], then: Callable[[], Any]) -> None:
    """then() once every matched reader of `publishers` has acknowledged all they sent, or after
    FLUSH_TIMEOUT_S: `when` on that condition, so the node never waits inside a callback."""
    from rclpy.duration import Duration

    when(node, lambda: all(pub.wait_for_all_acked(Duration(seconds=0)) for pub in publishers), FLUSH_TIMEOUT_S,
         lambda _acked: then())

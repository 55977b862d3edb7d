"""The `cq-ros` command: maps, offline experiments, the paper's reproduction, the planner, and the ROS tools.

Bad arguments print one line naming what is wrong and exit with code 2, as argparse does.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import signal
import sys
import threading
from contextlib import contextmanager

from ..gridmap import MapError
from ..lab.cluster import ClusterError
from ..lab.runner import RunFailed
from ..settings import SettingsError
from .arguments import Parser
from .offline_parser import add_offline_parsers, add_render_parser
from .pipe import reader_may_leave
from .ros_parser import add_ros_parsers


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="cq-ros", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=Parser)
    add_offline_parsers(sub)
    add_ros_parsers(sub)
    add_render_parser(sub)  # an offline command, listed last: it draws from the engine or from a recorded bag
    return parser


def main(argv: list[str] | None = None) -> int:
    return reader_may_leave(lambda: _main(argv))


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # `launch --hosts` runs them again on the world's host
    try:
        with _sigterm_as_ctrl_c():
            return _dispatch(args)
    except BrokenPipeError:  # the reader left (`cq-ros maps | head`): main's to end quietly, not an OSError below
        raise
    except (MapError, SettingsError, FileExistsError, ValueError) as e:
        parser.exit(2, f"cq-ros {args.command}: error: {e}\n")
    except RunFailed as e:  # the traceback (the worker's, wherever the run was), then the line naming the run
        parser.exit(1, f"{e.details}cq-ros {args.command}: error: {e}\n")
    except (ClusterError, OSError) as e:  # OSError: a disk that filled after the start's checks, one line
        parser.exit(1, f"cq-ros {args.command}: error: {e}\n")
    except Terminated:  # 130 as for Ctrl-C, as `launch` answers SIGTERM
        print("interrupted by SIGTERM", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C's KeyboardInterrupt would be: a command unwinds as it does on Ctrl-C (an
    experiment cut short removes the folder it made)."""


@contextmanager
def _sigterm_as_ctrl_c():
    """SIGTERM raises Terminated in the main thread and stops this process's worker processes, as Ctrl-C at a
    terminal reaches the whole process group; a ROS command's own StopSignals takes SIGTERM over while it runs."""
    if threading.current_thread() is not threading.main_thread():  # only the main thread may set handlers
        yield
        return

    owner = os.getpid()

    def on_sigterm(signum, _frame):
        if os.getpid() != owner:  # a forked worker inherits the handler: it dies of SIGTERM as it would have
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        for child in multiprocessing.active_children():
            child.terminate()
        raise Terminated

    saved = signal.signal(signal.SIGTERM, on_sigterm)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, saved)


def _dispatch(args) -> int:
    """Run the parsed command: the offline ones (offline.py), the planner (plan.py) and the ROS ones (ros.py),
    each module imported only when one of its commands runs."""
    from . import offline

    if args.command in offline.COMMANDS:
        return offline.COMMANDS[args.command](args)
    if args.command == "plan":
        from .plan import run

        return run(args)
    from . import ros  # imports no ROS until one of its commands runs

    if args.command in ("echo", "topics", "nodes", "record"):
        return ros.ros_tool(args)
    return getattr(ros, args.command)(args)


if __name__ == "__main__":  # `python -m cq_ros.cli.main`, beside `python -m cq_ros.cli` and `cq-ros`
    sys.exit(main())

"""A command whose reader leaves early (`cq-ros maps | head -1`, `python -m world_node --help | head -1`) ends
quietly, as `ls | head` does: no BrokenPipeError traceback, neither raised nor at the interpreter's exit. The
`cq-ros` command and both node programs run through it."""

from __future__ import annotations

import os
import sys
from typing import Callable


def reader_may_leave(work: Callable[[], int]) -> int:
    """work()'s exit status, or 0 when stdout's reader left before all was written (there is no one left to
    tell). stdout is flushed here, where a gone reader can still be caught, not at exit; SystemExit (argparse's
    --help) passes through once flushed."""
    try:
        try:
            return work()
        finally:
            sys.stdout.flush()
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # Python's own flush at exit finds no pipe
        return 0

"""`cq-ros checkpoint convert OLD NEW`: an agent checkpoint of the old pickled format, which the user trusts,
written as the current one (agent_node.checkpoint). Unpickling runs whatever code the file holds, so this is
the only place a checkpoint is unpickled, and only on the user's word."""

from __future__ import annotations

import pickle
from pathlib import Path

from agent_node.checkpoint import convert_pickle

__all__ = ["convert"]


def convert(old: Path, new: Path) -> str:
    """Convert `old` into `new` (which must not exist); the line saying what was written. ValueError (or
    FileExistsError) for a file that is no pickled checkpoint of format 3, one line."""
    if new.exists():
        raise FileExistsError(f"{new} exists; give a new file")
    try:
        algo, episode = convert_pickle(old, new)
    except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, KeyError) as e:
        raise ValueError(f"{old}: not a pickled checkpoint: {type(e).__name__}: {e}") from None
    return f"{new}: the {algo} learner of {old}, episodes up to {episode} learnt"

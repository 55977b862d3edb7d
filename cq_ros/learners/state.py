"""A learner's state as named arrays, and back: what a checkpoint holds (agent_node.checkpoint writes them to
an .npz that loads without pickle) and what a compiled twin of the learners can read.

    arrays = to_arrays(learner)                       # dict[str, np.ndarray]: numbers and strings only
    learner = from_arrays(arrays, gridmap, settings)  # StateError naming the field if anything is off

State is taken between steps (after `learn`, before the next `observe`), where a learner keeps only its tables,
counters, epsilon, its random.Random (as the integers of getstate) and, for CQ, JS and near, the step whose
update waits; so a restored learner plays on exactly as the original would. `from_arrays` checks every field
as it restores it (type, shape against the map, range, the settings as the run's) and returns a learner only
when all pass.

A table keyed by tuples is two arrays, `<table>.keys` (one row of integers per key, in the dict's order, which
CQ's tie-breaking depends on) and `<table>.rows`. Keys whose peers vary (loc's Q^C, near's) are one slot per
agent: the peer's cell, or -1 where that peer is not in the key.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping

import numpy as np

from ..gridmap import GridMap
from ..settings import Settings
from . import CQ_LEARNERS, LEARNERS
from .base import N_MOVES, Learner
from .cq_paper import CQPaperLearner, Step
from .next_state import NextStateLearner

__all__ = ["STATE_FORMAT", "StateError", "from_arrays", "scalar", "to_arrays"]

STATE_FORMAT = 1
_RNG_WORDS = 625  # random.Random.getstate()[1]: 624 words of the Mersenne twister and its position
_NONE = -1
MAX_SETTINGS_CHARS = 16_384  # the settings' JSON in a checkpoint: about 600 characters today


class StateError(ValueError):
    """A field of a learner's state that is missing or wrong: `field` names it."""

    def __init__(self, field: str, what: str):
        super().__init__(f"field {field}: {what}")
        self.field = field


# -- which tables each learner keeps -------------------------------------------------------------------------
# (attribute, key kind, columns of a row); key kind: "cells" a list indexed by cell; "joint" (cell and every
# peer's cell, JS and JSA: n_agents cells); "slots" (cell and, per agent, a peer's cell or -1: loc, near);
# "cq" (cell, peer, peer's cell).

def _tables(algo: str, n_agents: int) -> list[tuple[str, str, int]]:
    return {
        "indep": [("q_local", "cells", N_MOVES)],
        "loc": [("q_local", "cells", N_MOVES + 1), ("q_coord", "slots", N_MOVES)],
        "near": [("q_local", "cells", N_MOVES), ("q_near", "slots", N_MOVES)],
        "js": [("q_joint", "joint", N_MOVES)],
        "jsa": [("q_joint", "joint", N_MOVES ** n_agents)],
        **dict.fromkeys(CQ_LEARNERS, [("q_local", "cells", N_MOVES), ("q_joint", "cq", N_MOVES)]),
    }[algo]


def _key_columns(kind: str, n_agents: int) -> int:
    return {"joint": n_agents, "slots": 1 + n_agents, "cq": 3}[kind]


def _encode_key(kind: str, key, n_agents: int) -> list[int]:
    if kind == "slots":
        cell, near = key
        slots = [_NONE] * n_agents
        for j, c in near:
            slots[j] = c
        return [cell, *slots]
    return list(key)


def _decode_key(kind: str, row: list[int]):
    if kind == "slots":
        return row[0], tuple((j, c) for j, c in enumerate(row[1:]) if c != _NONE)
    return tuple(row)


# -- learner -> arrays ---------------------------------------------------------------------------------------

def to_arrays(learner: Learner) -> dict[str, np.ndarray]:
    """The learner's state (between steps) as named arrays of numbers and strings."""
    version, words, gauss = learner.rng.getstate()
    out = {
        "format": np.int64(STATE_FORMAT), "algo": np.str_(learner.name), "agent": np.int64(learner.agent),
        "settings": np.str_(json.dumps(learner.settings.as_dict(), sort_keys=True)),
        "rng": np.array(words, dtype=np.int64), "rng_gauss": np.float64(math.nan if gauss is None else gauss),
        "epsilon": np.float64(learner.epsilon), "learning": np.bool_(learner.learning),
        "joint_plays": np.int64(learner.joint_plays), "heard": np.int64(learner.heard),
        "episodes_played": np.int64(learner.episodes_played),
    }
    for name, kind, width in _tables(learner.name, learner.n_agents):
        table = getattr(learner, name)
        if kind == "cells":
            out[name] = np.array(table, dtype=np.float64).reshape(-1, width)
            continue
        out[f"{name}.keys"] = np.array([_encode_key(kind, k, learner.n_agents) for k in table],
                                       dtype=np.int64).reshape(len(table), _key_columns(kind, learner.n_agents))
        out[f"{name}.rows"] = np.array(list(table.values()), dtype=np.float64).reshape(-1, width)
    if isinstance(learner, CQPaperLearner):
        out.update(_cq_arrays(learner))
    elif isinstance(learner, NextStateLearner):
        out.update(_next_state_arrays(learner))
    return out


def _cq_arrays(learner: CQPaperLearner) -> dict[str, np.ndarray]:
    size = learner.settings.window
    windows = learner.windows
    pad = [0.0] * size
    w1 = np.array([w.w1 + pad[len(w.w1):] for w in windows], dtype=np.float64).reshape(-1, size)
    w2 = np.array([w.w2 + pad[len(w.w2):] for w in windows], dtype=np.float64).reshape(-1, size)
    out = {
        "confidence": np.array([learner.confidence[js] for js in learner.q_joint], dtype=np.float64),
        "dropped_updates": np.int64(learner.dropped_updates),
        "windows.n1": np.array([w.n1 for w in windows], dtype=np.int64), "windows.w1": w1,
        "windows.sum1": np.array([w.sum1 for w in windows]), "windows.sq1": np.array([w.sq1 for w in windows]),
        "windows.n2": np.array([len(w.w2) for w in windows], dtype=np.int64), "windows.w2": w2,
        "windows.head": np.array([w.head for w in windows], dtype=np.int64),
        "windows.sum2": np.array([w.sum2 for w in windows]), "windows.sq2": np.array([w.sq2 for w in windows]),
        "windows.exact2": np.array([w.exact2 for w in windows], dtype=np.bool_),
    }
    step = learner.waiting
    if step is None:
        out.update({"waiting": np.zeros(0, dtype=np.int64), "waiting.reward": np.float64(0.0),
                    "waiting.keys": np.zeros((0, 3), dtype=np.int64)})
    else:
        out.update({"waiting": np.array([step.cell, step.action, step.next_cell, step.done, step.conflict,
                                         step.learnt], dtype=np.int64),
                    "waiting.reward": np.float64(step.reward),
                    "waiting.keys": np.array([[_NONE] * 3 if k is None else list(k) for k in step.keys],
                                             dtype=np.int64).reshape(-1, 3)})
    return out


def _all_rows(learner: Learner) -> list[list[float]]:
    """Every row of the learner's tables, in to_arrays' order: what a waiting step's row index counts."""
    rows = []
    for name, kind, _ in _tables(learner.name, learner.n_agents):
        table = getattr(learner, name)
        rows.extend(table if kind == "cells" else table.values())
    return rows


def _next_state_arrays(learner: NextStateLearner) -> dict[str, np.ndarray]:
    """The waiting step (row, action, reward): its row by index among the tables' rows (-1: a row of no table,
    a frozen learner's), and its values."""
    if learner.waiting is None:
        return {"waiting": np.zeros(0, dtype=np.int64), "waiting.reward": np.float64(0.0),
                "waiting.row": np.zeros(N_MOVES)}
    row, action, reward = learner.waiting
    index = next((i for i, r in enumerate(_all_rows(learner)) if r is row), _NONE)
    return {"waiting": np.array([index, action], dtype=np.int64), "waiting.reward": np.float64(reward),
            "waiting.row": np.array(row, dtype=np.float64)}


# -- arrays -> learner, every field checked ----------------------------------------------------------------

def _field(arrays: Mapping[str, np.ndarray], name: str, kind: str, shape: tuple, low=None, high=None,
           finite: bool = True) -> np.ndarray:
    """arrays[name], checked: its dtype kind ('i' integer, 'f' float, 'b' bool, 'U' string), its shape (None:
    any length), its values within [low, high] and, for floats, finite."""
    if name not in arrays:
        raise StateError(name, "missing")
    a = np.asarray(arrays[name])
    kinds = {"i": "iu", "f": "f", "b": "b", "U": "U"}[kind]
    if a.dtype.kind not in kinds:
        what = {"i": "integers", "f": "floats", "b": "booleans", "U": "a string"}[kind]
        raise StateError(name, f"holds {a.dtype} where it must hold {what}")
    if len(a.shape) != len(shape) or any(want is not None and got != want for got, want in zip(a.shape, shape)):
        want = str(tuple("any" if w is None else w for w in shape)).replace("'", "")
        raise StateError(name, f"has shape {a.shape} where this map and these settings make it {want}")
    if kind == "f" and finite and a.size and not np.isfinite(a).all():
        raise StateError(name, "holds a value that is not a finite number")
    if a.size and low is not None and a.min() < low:
        raise StateError(name, f"holds {a.min()}, below its least value {low}")
    if a.size and high is not None and a.max() > high:
        raise StateError(name, f"holds {a.max()}, above its greatest value {high}")
    return a


def scalar(arrays: Mapping[str, np.ndarray], name: str, kind: str, low=None, high=None):
    """arrays[name], a checked scalar (`_field`), as a Python value."""
    return _field(arrays, name, kind, (), low, high).item()


def from_arrays(arrays: Mapping[str, np.ndarray], gridmap: GridMap, settings: Settings) -> Learner:
    """The learner whose state `arrays` holds (to_arrays'), on this map under these settings (which must be
    the ones it learnt under); StateError naming the first field that is missing or wrong."""
    fmt = scalar(arrays, "format", "i")
    if fmt != STATE_FORMAT:
        raise StateError("format", f"is {fmt}; this version reads format {STATE_FORMAT}")
    algo = scalar(arrays, "algo", "U")
    if algo not in LEARNERS:
        raise StateError("algo", f"unknown algorithm {algo!r}; algorithms are: {', '.join(LEARNERS)}")
    cls = LEARNERS[algo]
    n, cells = gridmap.n_agents, gridmap.n_cells
    agent = scalar(arrays, "agent", "i", 0, 0 if cls.central else n - 1)
    _check_settings(scalar(arrays, "settings", "U"), settings)
    words = _field(arrays, "rng", "i", (_RNG_WORDS,), 0, 2**32 - 1)
    if words[-1] > 624:
        raise StateError("rng", f"position {words[-1]} lies past the generator's 624 words")
    gauss = _field(arrays, "rng_gauss", "f", (), finite=False).item()
    if math.isinf(gauss):
        raise StateError("rng_gauss", "is infinite")
    try:
        learner = cls(agent, gridmap, settings, 0)
    except ValueError as e:  # jsa on a map with too many agents
        raise StateError("algo", str(e)) from None
    try:
        learner.rng.setstate((3, tuple(words.tolist()), None if math.isnan(gauss) else gauss))
    except (ValueError, TypeError, OverflowError) as e:
        raise StateError("rng", f"not a generator's state: {e}") from None
    learner.epsilon = scalar(arrays, "epsilon", "f", 0.0, 1.0)
    learner.learning = bool(scalar(arrays, "learning", "b"))
    for name in ("joint_plays", "heard", "episodes_played"):
        setattr(learner, name, scalar(arrays, name, "i", 0))
    for name, kind, width in _tables(algo, n):
        if kind == "cells":
            setattr(learner, name, _field(arrays, name, "f", (cells, width)).tolist())
        else:
            setattr(learner, name, _table(arrays, name, kind, width, learner))
    if isinstance(learner, CQPaperLearner):
        _restore_cq(arrays, learner)
    elif isinstance(learner, NextStateLearner):
        _restore_next_state(arrays, learner)
    return learner


def _check_settings(text: str, settings: Settings) -> None:
    # A flat mapping of a few dozen settings is under a kilobyte: refused before parsing past that, and parsed
    # with nesting refused, since json.loads recurses once per level and deep nesting ends in a RecursionError.
    if len(text) > MAX_SETTINGS_CHARS:
        raise StateError("settings", f"is {len(text):,} characters long, more than settings take "
                                     f"({MAX_SETTINGS_CHARS:,})")
    try:
        saved = json.loads(text)
    except RecursionError:
        raise StateError("settings", "nested too deeply: not a mapping of settings") from None
    except ValueError as e:
        raise StateError("settings", f"not JSON: {e}") from None
    if not isinstance(saved, dict):
        raise StateError("settings", "not a mapping of settings")
    nested = sorted(name for name, value in saved.items() if isinstance(value, (dict, list)))
    if nested:
        raise StateError("settings", f"{nested[0]} holds a {type(saved[nested[0]]).__name__}, where every "
                                     "setting is a number, a string or a boolean")
    ours = settings.as_dict()
    for name in sorted(set(saved) | set(ours)):
        if saved.get(name) != ours.get(name):
            raise StateError("settings", f"{name} is {saved.get(name)!r}; this run's is {ours.get(name)!r}")


def _table(arrays, name: str, kind: str, width: int, learner: Learner) -> dict:
    n, cells = learner.n_agents, learner.n_cells
    keys = _field(arrays, f"{name}.keys", "i", (None, _key_columns(kind, n)), _NONE, cells - 1)
    rows = _field(arrays, f"{name}.rows", "f", (len(keys), width))
    where = f"{name}.keys"
    if kind == "joint" and keys.size and keys.min() < 0:
        raise StateError(where, "holds a cell -1")
    if kind == "cq" and keys.size:
        if keys[:, [0, 2]].min() < 0:
            raise StateError(where, "holds a cell -1")
        if not np.isin(keys[:, 1], learner.peers).all():
            raise StateError(where, f"names a peer that is not one of {list(learner.peers)}")
    if kind == "slots" and keys.size:
        if keys[:, 0].min() < 0 or (keys[:, 1 + learner.agent] != _NONE).any():
            raise StateError(where, "holds a cell -1, or the agent as its own peer")
        if ((keys[:, 1:] != _NONE).sum(axis=1) == 0).any():
            raise StateError(where, "holds a key with no peer in it")
    table = {_decode_key(kind, k): r for k, r in zip(keys.tolist(), rows.tolist())}
    if len(table) != len(keys):
        raise StateError(where, "holds a key twice")
    return table


def _restore_cq(arrays, learner: CQPaperLearner) -> None:
    size, count = learner.settings.window, learner.n_cells * N_MOVES
    confidence = _field(arrays, "confidence", "f", (len(learner.q_joint),))
    learner.confidence = dict(zip(learner.q_joint, confidence.tolist()))
    learner.marked, learner.watch = {}, {}
    for js in learner.q_joint:
        learner.marked.setdefault(js[0], []).append(js)
    for s in learner.marked:
        learner._rewatch(s)
    learner.dropped_updates = scalar(arrays, "dropped_updates", "i", 0)
    w = {name: _field(arrays, f"windows.{name}", kind, shape, *bounds) for name, kind, shape, *bounds in (
        ("n1", "i", (count,), 0, size), ("w1", "f", (count, size)), ("sum1", "f", (count,)),
        ("sq1", "f", (count,), 0.0), ("n2", "i", (count,), 0, size), ("w2", "f", (count, size)),
        ("head", "i", (count,), 0, size - 1), ("sum2", "f", (count,)), ("sq2", "f", (count,), 0.0),
        ("exact2", "b", (count,)))}
    if ((w["n2"] > 0) & (w["n1"] < size)).any():
        raise StateError("windows.n2", "W2 holds rewards where W1 is not yet full")
    if ((w["head"] > 0) & (w["n2"] < size)).any():
        raise StateError("windows.head", "W2 slides before it is full")
    columns = {name: a.tolist() for name, a in w.items()}
    for i, window in enumerate(learner.windows):
        n1, n2 = columns["n1"][i], columns["n2"][i]
        window.n1, window.w1 = n1, columns["w1"][i][:n1] if n1 < size else []
        window.sum1, window.sq1 = columns["sum1"][i], columns["sq1"][i]
        window.w2, window.head = columns["w2"][i][:n2], columns["head"][i]
        window.sum2, window.sq2, window.exact2 = columns["sum2"][i], columns["sq2"][i], columns["exact2"][i]
    step = _field(arrays, "waiting", "i", (None,), 0)
    keys = _field(arrays, "waiting.keys", "i", (None, 3), _NONE, learner.n_cells - 1)
    reward = scalar(arrays, "waiting.reward", "f")
    if len(step) == 0:
        learner.waiting = None
        return
    if len(step) != 6:
        raise StateError("waiting", f"has {len(step)} values; a waiting step has 6 (or none, 0)")
    cell, action, next_cell, done, conflict, learnt = step.tolist()
    if max(cell, next_cell) >= learner.n_cells or action >= N_MOVES or max(done, conflict, learnt) > 1:
        raise StateError("waiting", f"{step.tolist()} is not (cell, action, next cell, done, conflict, learnt)")
    learner.waiting = Step(cell, [None if k[0] == _NONE else tuple(k) for k in keys.tolist()], action, reward,
                           next_cell, bool(done), conflict=bool(conflict), learnt=bool(learnt))


def _restore_next_state(arrays, learner: NextStateLearner) -> None:
    rows = _all_rows(learner)
    step = _field(arrays, "waiting", "i", (None,), _NONE)
    values = _field(arrays, "waiting.row", "f", (N_MOVES,))
    reward = scalar(arrays, "waiting.reward", "f")
    if len(step) == 0:
        learner.waiting = None
        return
    if len(step) != 2 or step[0] >= len(rows) or not 0 <= step[1] < N_MOVES:
        raise StateError("waiting", f"{step.tolist()} is not (row index below {len(rows)} or -1, action)")
    index, action = step.tolist()
    learner.waiting = (rows[index] if index != _NONE else values.tolist(), action, reward)

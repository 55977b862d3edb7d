"""Value checks shared by every encoder and decoder of msgs_spec: exact int32 integers, finite floats, 0/1
flags, and the range and sequence checks that raise `WireError` with the kind a receiver counts."""

from __future__ import annotations

import math
import operator
from typing import Any, Callable

from .errors import WireError
from .payloads import INT32_MAX, Bounds

__all__ = ["as_int", "as_float", "as_flag", "CONVERT", "check_type", "check_nonneg", "check_agent", "check_cell",
           "check_sequence", "check_beat"]


def as_int(name: str, v: Any, *, wide: bool = False) -> int:
    """An exact integer from an int-like or an integral finite float; else WireError. It must fit int32
    unless `wide` (a count carried as text, as a statistic's state count is)."""
    if type(v) is int and (wide or -INT32_MAX - 1 <= v <= INT32_MAX):  # the common case, first
        return v
    if isinstance(v, bool):
        return int(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise WireError("not_finite", f"{name} = {v!r}")
        if v != int(v):
            raise WireError("not_integer", f"{name} = {v!r}")
        v = int(v)
    else:
        try:
            v = operator.index(v)
        except TypeError:
            raise WireError("not_integer", f"{name} = {v!r} ({type(v).__name__})") from None
    if not wide and not -INT32_MAX - 1 <= v <= INT32_MAX:
        raise WireError("out_of_range", f"{name} = {v} does not fit int32")
    return v


def as_float(name: str, v: Any, text: bool = False) -> float:
    """A finite float from a number, or `text` (a statistic's value) from its decimal text; else WireError."""
    if type(v) is float and math.isfinite(v):  # the common case, first
        return v
    if isinstance(v, (str, bytes)) and not text:
        raise WireError("malformed", f"{name} = {v!r} is not a number")
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise WireError("malformed", f"{name} = {v!r} is not a number") from None
    if not math.isfinite(f):
        raise WireError("not_finite", f"{name} = {f!r}")
    return f


def as_flag(name: str, v: Any) -> bool:
    if isinstance(v, bool):
        return v
    if isinstance(v, float) and not math.isfinite(v):
        raise WireError("not_finite", f"{name} = {v!r}")
    if v == 0 or v == 1:
        return bool(v)
    raise WireError("malformed", f"flag {name} = {v!r}, must be 0 or 1")


CONVERT: dict[str, Callable[[str, Any], Any]] = {"int": as_int, "float": as_float, "flag": as_flag}


def check_type(value: Any, expected: type) -> None:
    if type(value) is not expected:
        raise WireError("wrong_type", f"expected {expected.__name__}, got {type(value).__name__}")


def check_nonneg(name: str, v: int) -> None:
    if v < 0:
        raise WireError("out_of_range", f"{name} = {v} is negative")


def check_agent(v: int, bounds: Bounds | None, agent: int | None, what: str = "agent") -> None:
    if v < 1 or (bounds is not None and v > bounds.n_agents):
        known = f"1..{bounds.n_agents}" if bounds is not None else ">= 1"
        raise WireError("unknown_agent", f"{what} {v}, known agents {known}")
    if agent is not None and v != agent:
        raise WireError("wrong_agent", f"{what} {v} on the topic of agent {agent}")


def check_cell(row: int, col: int, bounds: Bounds | None, what: str = "cell") -> None:
    if row < 0 or col < 0 or (bounds is not None and (row >= bounds.rows or col >= bounds.cols)):
        grid = f"{bounds.rows}x{bounds.cols}" if bounds is not None else "grid"
        raise WireError("cell_out_of_range", f"{what} ({row}, {col}) outside the {grid} grid")


def check_sequence(ep: int, st: int | None, episode: int | None, step: int | None) -> None:
    """WireError stale_*/future_* when (ep, st) is not the expected (episode, step) (None: not checked)."""
    if episode is not None:
        if ep < episode:
            raise WireError("stale_episode", f"episode {ep}, expected {episode}")
        if ep > episode:
            raise WireError("future_episode", f"episode {ep}, expected {episode}")
    if step is not None and st is not None:
        if st < step:
            raise WireError("stale_step", f"episode {ep} step {st}, expected step {step}")
        if st > step:
            raise WireError("future_step", f"episode {ep} step {st}, expected step {step}")


def check_beat(beat: int, after: int | None) -> None:
    """WireError replayed when `beat` is not above `after`, the last beat heard (None: not checked)."""
    if after is not None and beat <= after:
        raise WireError("replayed", f"beat {beat}, the last one heard was {after}")

"""The checks the world node's and the agent node's parameters share: numbers in range, the map, the
learning settings. Each failure is a `SettingsError` whose one line names the parameter.

A node declares every field of `Settings` as a parameter without a value (SETTING_NAMES): one left out comes
from the map's defaults (its `set` lines) or Settings', as in `cq-ros experiment` (`run_settings`)."""

from __future__ import annotations

import difflib
import math
from dataclasses import fields
from typing import Any, Iterable, Mapping

from .gridmap import GridMap, MapError, load_map
from .settings import Settings, SettingsError, run_settings

__all__ = ["SETTING_NAMES", "check_names", "check_numbers", "map_and_settings"]

SETTING_NAMES = frozenset(f.name for f in fields(Settings))


def check_names(given: Iterable[str], known: Iterable[str], elsewhere: Iterable[str] = (),
                what: str = "parameter") -> None:
    """Every name in `given` must be `known` (or known `elsewhere`: a name another node of the system takes,
    which one parameters file may give to every node); else one line naming the closest known name."""
    known = set(known)
    everything = known | set(elsewhere)
    for name in sorted(set(given) - everything):
        close = difflib.get_close_matches(name, sorted(known), n=1) or difflib.get_close_matches(
            name, sorted(everything), n=1)
        hint = f"; did you mean {close[0]!r}?" if close else f"; known: {', '.join(sorted(known))}"
        raise SettingsError(f"unknown {what} {name!r}{hint}")


def check_numbers(values: Mapping[str, Any], rules: Iterable[tuple[str, float, bool]]) -> None:
    """Every float in `values` must be finite; each (name, low, strict): values[name] must be >= low, or
    > low when strict."""
    for name, v in values.items():
        if isinstance(v, float) and not math.isfinite(v):
            raise SettingsError(f"parameter {name} must be a finite number, got {v!r}")
    for name, low, strict in rules:
        v = values[name]
        if v < low or (strict and v == low):
            raise SettingsError(f"parameter {name} must be {'>' if strict else '>='} {low}, got {v!r}")


def map_and_settings(values: Mapping[str, Any]) -> tuple[GridMap, Settings]:
    """The map named by values['map'] and the run's settings: those among `values` over the map's defaults."""
    try:
        gridmap = load_map(values["map"])
    except MapError as e:
        raise SettingsError(f"parameter map: {e}") from None
    return gridmap, run_settings(gridmap, {name: values[name] for name in SETTING_NAMES & values.keys()})

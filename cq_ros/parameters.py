"""The checks the world node's and the agent node's parameters share: numbers in range, the map, the
learning settings. Each failure is a `SettingsError` whose one line names the parameter.

A node declares every field of `Settings` as a parameter without a value (SETTING_NAMES): one left out comes
from the map's defaults (its `set` lines) or Settings', as in `cq-ros experiment` (`run_settings`)."""

from __future__ import annotations

from dataclasses import fields
from typing import Any, Iterable, Mapping

from .gridmap import GridMap, MapError, load_map
from .settings import Settings, SettingsError, run_settings

__all__ = ["SETTING_NAMES", "check_numbers", "map_and_settings"]

SETTING_NAMES = frozenset(f.name for f in fields(Settings))


def check_numbers(values: Mapping[str, Any], rules: Iterable[tuple[str, float, bool]]) -> None:
    """Each (name, low, strict): values[name] must be >= low, or > low when strict."""
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

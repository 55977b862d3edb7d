"""The checks the world node's and the agent node's parameters share: numbers in range, the map, the
learning settings. Each failure is a `SettingsError` whose one line names the parameter."""

from __future__ import annotations

from dataclasses import fields
from typing import Any, Iterable, Mapping

from .gridmap import GridMap, MapError, load_map
from .settings import Settings, SettingsError

__all__ = ["check_numbers", "map_and_settings"]


def check_numbers(values: Mapping[str, Any], rules: Iterable[tuple[str, float, bool]]) -> None:
    """Each (name, low, strict): values[name] must be >= low, or > low when strict."""
    for name, low, strict in rules:
        v = values[name]
        if v < low or (strict and v == low):
            raise SettingsError(f"parameter {name} must be {'>' if strict else '>='} {low}, got {v!r}")


def map_and_settings(values: Mapping[str, Any]) -> tuple[GridMap, Settings]:
    """The map named by values['map'] and the Settings made of the values of its fields."""
    try:
        gridmap = load_map(values["map"])
    except MapError as e:
        raise SettingsError(f"parameter map: {e}") from None
    return gridmap, Settings().with_overrides({f.name: values[f.name] for f in fields(Settings)})

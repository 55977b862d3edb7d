"""Tests of cq_ros.settings: defaults, `with_overrides` as the CLI's `--set key=value` reaches it, and
`run_settings` (the map's defaults under the user's)."""

import dataclasses
import math

import pytest

from cq_ros.lab.results import manifest_for
from cq_ros.gridmap import load_map, parse_map
from cq_ros.settings import CONF_DROP, CONF_INIT, Settings, SettingsError, run_settings

FIELDS = [f.name for f in dataclasses.fields(Settings)]
INT_FIELDS = [f.name for f in dataclasses.fields(Settings) if f.type in ("int", int)]


def test_defaults_are_valid_and_the_papers():
    s = Settings()
    assert (s.alpha, s.epsilon, s.window) == (0.1, 0.1, 60)  # the paper's settings
    assert 0.0 <= s.gamma < 1.0 and 0.0 < s.significance < 0.5
    assert CONF_DROP < CONF_INIT <= s.conf_max
    assert s.slip == 0.0  # deterministic transitions, as in the paper
    d = s.as_dict()
    assert sorted(d) == sorted(FIELDS)
    assert all(math.isfinite(v) for v in d.values())
    assert Settings(**d) == s  # the manifest round-trips
    assert {"window", "start_hold", "step_cap"} <= set(INT_FIELDS)
    assert all(type(d[name]) is int for name in INT_FIELDS)


def test_overrides_parse_ints_and_floats():
    s = Settings().with_overrides(["alpha=0.25", "window=7", "gamma = 0.5", "step_cap=100", "reward_step=-1"])
    assert s.alpha == 0.25 and isinstance(s.alpha, float)
    assert s.window == 7 and type(s.window) is int
    assert s.gamma == 0.5
    assert s.step_cap == 100 and type(s.step_cap) is int
    assert s.reward_step == -1.0 and isinstance(s.reward_step, float)
    # everything else untouched, and the original is not modified (frozen)
    assert s.epsilon == Settings().epsilon and Settings().alpha == 0.1


def test_overrides_from_a_dict():
    s = Settings().with_overrides({"alpha": "0.3", "window": 9, "start_hold": 3.0})
    assert (s.alpha, s.window, s.start_hold) == (0.3, 9, 3)
    assert type(s.start_hold) is int
    assert Settings().with_overrides({}) == Settings()
    assert Settings().with_overrides([]) == Settings()


def test_unknown_key_lists_the_settings():
    with pytest.raises(SettingsError) as info:
        Settings().with_overrides(["alpah=0.2"])
    msg = str(info.value)
    assert "alpah" in msg
    for name in FIELDS:
        assert name in msg


@pytest.mark.parametrize(
    "pair, key",
    [
        ("alpha=abc", "alpha"),
        ("alpha=", "alpha"),
        ("window=2.5", "window"),
        ("window=abc", "window"),
        ("step_cap=1e3", "step_cap"),
        ("step_cap=inf", "step_cap"),
        ("gamma=0,5", "gamma"),
    ],
)
def test_wrong_types_are_refused(pair, key):
    with pytest.raises(SettingsError, match=key):
        Settings().with_overrides([pair])


@pytest.mark.parametrize("value", [True, 2.5, "2.5", None, [3]])
def test_wrong_types_from_a_dict(value):
    with pytest.raises(SettingsError, match="window"):
        Settings().with_overrides({"window": value})


@pytest.mark.parametrize(
    "pair",
    [
        "alpha=0",
        "alpha=1.5",
        "alpha=-0.1",
        "alpha=nan",
        "epsilon=1.01",
        "epsilon=-0.5",
        "window=1",
        "window=0",
        "gamma=1",
        "gamma=-0.1",
        "significance=0",
        "significance=0.5",
        "conf_up=-1",
        "conf_down=-0.1",
        "conf_max=0.5",  # below CONF_INIT
        "start_hold=-1",
        "step_cap=0",
        "slip=1.5",
        "slip=1",
        "slip=-0.1",
        "reward_goal=inf",
        "reward_step=nan",
        "loc_cost=-inf",
    ],
)
def test_out_of_range_values_are_refused(pair):
    key = pair.partition("=")[0]
    with pytest.raises(SettingsError) as info:
        Settings().with_overrides([pair])
    assert key in str(info.value)


def test_settings_error_is_a_value_error():
    assert issubclass(SettingsError, ValueError)
    with pytest.raises(ValueError):
        Settings(alpha=0.0)


@pytest.mark.parametrize("pair", ["noequals", "=0.2", "  =1", ""])
def test_malformed_pairs_are_refused(pair):
    with pytest.raises(SettingsError, match="key=value"):
        Settings().with_overrides([pair])


def test_a_bad_pair_loses_nothing_and_changes_nothing():
    base = Settings()
    with pytest.raises(SettingsError):
        base.with_overrides(["alpha=0.2", "window=2.5"])
    assert base == Settings()


def test_boundary_values_are_accepted():
    s = Settings().with_overrides(
        ["alpha=1", "epsilon=0", "window=2", "gamma=0", "slip=0.999", "conf_max=1", "step_cap=1", "epsilon=1"]
    )
    assert (s.alpha, s.epsilon, s.window, s.gamma, s.slip, s.conf_max, s.step_cap) == (1.0, 1.0, 2, 0.0, 0.999, 1, 1)
    assert Settings().with_overrides(["step_cap=10", "start_hold=9"]).start_hold == 9


@pytest.mark.parametrize("pairs, reason", [
    (["slip=1"], "setting slip must be in [0, 1) (at 1 every move fails: no AGV ever moves), got 1.0"),
    (["step_cap=10", "start_hold=10"], "setting start_hold must be below step_cap=10 (a hold that long can keep an "
                                       "AGV at its dock for the whole episode), got 10"),
])
def test_absurd_delays_are_refused_with_their_reason(pairs, reason):
    with pytest.raises(SettingsError) as info:
        Settings().with_overrides(pairs)
    assert str(info.value) == reason


def test_run_settings_puts_the_maps_defaults_under_the_users_overrides():
    warehouse = parse_map("agent 1: start 0,0  goal 0,1\nset reward_step=-1\nset window=30\n+-+-+\n|. .|\n+-+-+\n")
    assert run_settings(load_map("tunnel_to_goal")) == Settings()
    assert run_settings(load_map("tunnel_to_goal"), ["alpha=0.2"]) == Settings(alpha=0.2)
    assert run_settings(warehouse) == Settings(reward_step=-1.0, window=30)
    assert run_settings(warehouse, ["reward_step=0", "alpha=0.2"]) == Settings(window=30, alpha=0.2)
    assert run_settings(warehouse, {"window": 60}) == Settings(reward_step=-1.0)
    with pytest.raises(SettingsError, match="unknown setting 'alhpa'"):
        run_settings(warehouse, ["alhpa=1"])
    # The manifest says which of the map's defaults the run used.
    for overrides, from_map in (((), {"reward_step": -1.0, "window": 30}), (["window=10"], {"reward_step": -1.0})):
        manifest = manifest_for(warehouse, ["cq"], 1, 1, 0, run_settings(warehouse, overrides), 0.0)
        assert manifest["map_defaults"] == {"reward_step": -1.0, "window": 30}
        assert manifest["settings_from_map"] == from_map


PAPER_MAPS = ("grid_game_2", "tunnel_to_goal", "tunnel_to_goal_3", "isr", "cit", "cmu")


def test_a_runs_settings_are_the_defaults_the_maps_then_the_users_and_no_map_changes_an_algorithm():
    """A delayed map brings its own set lines and nothing else: which CQ plays is its name (cq or cq_paper),
    never a setting; the switches that once chose CQ's rules are unknown settings."""
    for name in (*PAPER_MAPS, "warehouse_8", "warehouse_8_delayed"):
        assert run_settings(load_map(name)) == Settings().with_overrides(load_map(name).defaults), name
    delayed = load_map("warehouse_8_delayed")
    assert run_settings(delayed, ["slip=0.2", "window=9"]) == Settings().with_overrides(
        {**delayed.defaults, "slip": 0.2, "window": 9})
    assert run_settings(None) == Settings()
    with pytest.raises(SettingsError, match="unknown setting 'cq_w1_alone'"):
        run_settings(delayed, ["cq_w1_alone=0"])


def test_every_setting_is_described_once_for_the_cli_the_nodes_and_the_docs():
    from node_runtime.parameters import PARAMETERS

    for name in FIELDS:
        description = Settings.describe(name)
        assert len(description) > 15, name  # a sentence, not a placeholder
        for table in PARAMETERS.values():
            assert table[name][1].startswith(description)
    with pytest.raises(KeyError):
        Settings.describe("no_such_setting")



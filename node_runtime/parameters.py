"""The parameters of the node kinds (`world`, `agent`) and how a node declares them: read-only, with their
descriptions (`ros2 param describe`), strictly checked: numbers in range, the map, the learning settings, each
failure a `SettingsError` whose one line names the parameter.

One table per kind: name -> (default, description); the default also fixes the ROS type. Every field of
cq_ros.settings.Settings is a parameter of both, declared without a value (SETTING_NAMES): one
not given is the map's default (its `set` lines) or Settings'. Both tables live here, below both node packages,
because each node accepts the names the other takes (one `--params-file` serves the whole system) and the
launcher sends each node only its own.
"""

from __future__ import annotations

import difflib
import math
import textwrap
from dataclasses import fields
from typing import Any, Iterable, Mapping

from cq_ros.cli.pipe import reader_may_leave
from cq_ros.gridmap import GridMap, MapError, load_map
from cq_ros.learners import LEARNERS
from cq_ros.settings import Settings, SettingsError, run_settings
from msgs_spec import KeyFileError, read_key
from msgs_spec.auth import RunKey, new_run

from .rclpy_workarounds import given_parameters

__all__ = ["SETTING_NAMES", "check_names", "check_numbers", "map_and_settings", "WORLD_PARAMETERS",
           "AGENT_PARAMETERS", "PARAMETERS", "declare_node_parameters", "declare_parameters", "undeclared_overrides",
           "read_key_parameter", "run_key_parameters", "ros_type", "describe_parameters", "help_requested",
           "print_help", "MIN_HEARTBEAT_PERIOD"]


SETTING_NAMES = frozenset(f.name for f in fields(Settings))
# The fastest a world beats: what bounds how far a heartbeat's beat may jump at an agent (agent_node.world_link).
MIN_HEARTBEAT_PERIOD = 0.01


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


def _with_settings(use: str, table: dict[str, tuple[Any, str]]) -> dict[str, tuple[Any, str]]:
    """`table` and every field of Settings as a parameter of the same name and type (`use`: what the node
    makes of them)."""
    return {**table, **{f.name: (f.default, f"{Settings.describe(f.name)}; setting {f.name} ({use}); not given: "
                                            "the map's default, else this one") for f in fields(Settings)}}


# Every parameter of the world node (with the Settings fields: _with_settings).
WORLD_PARAMETERS: dict[str, tuple[Any, str]] = _with_settings(
    "world dynamics use the rewards, step_cap and the delays (slip, start_hold)", {
    "map": ("tunnel_to_goal", "map shipped with cq_ros (e.g. tunnel_to_goal_3) or path to a map file"),
    "episodes": (500, "learning episodes; then eval_episodes more, where the agents play their greedy policy "
                      "(cq_ros.engine.greedy_episodes); the node exits 0 after the last of all"),
    "seed": (0, "experiment seed; with run it seeds the world's RNG (used only for delays: slip, start_hold), "
                "as cq_ros.engine.world_seed"),
    "run": (0, "run index (cq_ros.engine.world_seed)"),
    "step_timeout": (2.0, "seconds to wait for an acting agent's action; past it the agent stays for "
                          "that step (warned and counted as missed_actions)"),
    "startup_timeout": (30.0, "seconds to wait before the first step until every agent's action and "
                              "feedback topics are matched; past it the node exits 1. Mid-run, the least "
                              "time no agent acts before the world ends the run (a restarted agent's join)"),
    "min_stats_subscribers": (0, "before the first step also wait for this many matched world/stats "
                                 "subscriptions (a recorder that must not miss an episode sets 1)"),
    "heartbeat_period": (1.0, "seconds between two world/heartbeat messages (sent from the start, whether or "
                              "not anyone acts), at least 0.01; keep it well below the agents' feedback_timeout"),
    "key_file": ("", "file holding the run's key (hex, readable by its owner only; cq-ros launch writes one): "
                     "key every message that steers the run and drop actions without a matching MAC; empty: "
                     "no authentication"),
    "run_nonce": (0, "with key_file: the run's nonce every keyed message is sealed with (cq-ros launch draws one "
                     "per launch); 0: this node draws one at start and the agents learn it from its first message"),
    "markers": (True, "publish for viewers (RViz2, Foxglove, bags; msgs_spec/viz.py) while someone subscribes: "
                          "world/map (latched) and world/markers every step; false: not even the publishers"),
})

# Every parameter of the agent node (with the Settings fields: _with_settings).
AGENT_PARAMETERS: dict[str, tuple[Any, str]] = _with_settings("learning settings and rewards, as the world's", {
    "agent_id": (0, "the AGV this node drives, 1..N as numbered in the map; leave 0 for algo jsa, whose "
                    "one central node drives every AGV"),
    "algo": ("cq", f"learner: {', '.join(LEARNERS)} (cq_ros.learners)"),
    "map": ("tunnel_to_goal", "map shipped with cq_ros (e.g. tunnel_to_goal_3) or path to a map file; "
                              "the same as the world's"),
    "episodes": (500, "learning episodes (the same as the world's); then eval_episodes greedy ones (epsilon 0, "
                      "on a copy of the learner, as cq_ros.engine.greedy_episodes); the node exits 0 after the "
                      "last of all"),
    "seed": (0, "experiment seed; with run and the agent it seeds the learner (cq_ros.engine.learner_seed)"),
    "run": (0, "run index (cq_ros.engine.learner_seed)"),
    "checkpoint": ("", "learner checkpoint file: loaded at start when it exists (resume), written every "
                       "checkpoint_every episodes and after the last learning one (never in the greedy "
                       "episodes); empty: no checkpoints"),
    "checkpoint_every": (50, "episodes between checkpoints"),
    "feedback_timeout": (30.0, "seconds without a valid message from the world (feedback or heartbeat) after "
                               "which the node gives up (exit 1)"),
    "peer_linger_steps": (0, "decision steps a peer subscription is kept after the learner last named the "
                             "peer (0: drop at the first step without need)"),
    "min_stats_subscribers": (0, "hold this node's agv<k>/stats messages until that many subscribers are "
                                 "matched, then send them in order (cq-ros launch: 1, so that it hears every "
                                 "episode); learning never waits for them, the exit at most 10 s"),
    "key_file": ("", "file holding the run's key (as the world's key_file): key every action, drop feedback, "
                     "positions and heartbeats without a matching MAC; empty: no authentication"),
    "run_nonce": (0, "with key_file: the run's nonce (as the world's); 0: learnt from the world's first keyed "
                     "message, and messages of any other run refused (other_run)"),
    "max_catch_up": (100, "episodes a later feedback may be ahead of the one expected and still be caught up to "
                          "(its episodes ended one by one); one further ahead is refused (far_ahead)"),
    "markers": (True, "publish for viewers (RViz2, Foxglove, bags; msgs_spec/viz.py) while someone subscribes: "
                          "agv<k>/looks at every decision; false: not even the publishers"),
})

# node kind -> its parameters
PARAMETERS: dict[str, dict[str, tuple[Any, str]]] = {"world": WORLD_PARAMETERS, "agent": AGENT_PARAMETERS}


def declare_node_parameters(node: Any, kind: str) -> dict[str, Any]:
    """Declare the parameters of node kind `kind` on `node` (declare_parameters, the Settings fields unset)
    and return their values; SettingsError naming a parameter given to it that no kind of node takes."""
    own = PARAMETERS[kind]
    values = declare_parameters(node, own, unset=SETTING_NAMES)
    others = {name for other, table in PARAMETERS.items() if other != kind for name in table}
    check_names(undeclared_overrides(node), own, others)
    if node.get_parameter("use_sim_time").value:  # every rclpy node declares it; docs/ros.md says why we refuse
        raise SettingsError("parameter use_sim_time: true is refused: the lockstep has no simulated clock (its "
                            "timeouts wait in wall time for actions, and the step is each message's episode and "
                            "step); stamps are this host's clock")
    return values


def declare_parameters(node: Any, parameters: dict[str, tuple[Any, str]], unset: frozenset[str]) -> dict[str, Any]:
    """Declare `parameters` (name -> (default, description)) read-only on `node` and return their values.

    Those named in `unset` are declared with their default's type but no value, and are in the result only
    when given (-p name:=value): the node then knows which were given, e.g. which settings override its map's
    defaults (cq_ros.settings.run_settings). The default still documents them."""
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.parameter import Parameter

    values = {}
    for name, (default, description) in parameters.items():
        descriptor = ParameterDescriptor(description=description, read_only=True)
        value = Parameter.Type.from_parameter_value(default) if name in unset else default
        values[name] = node.declare_parameter(name, value, descriptor).value
    return {name: value for name, value in values.items() if not (name in unset and value is None)}


def undeclared_overrides(node: Any) -> list[str]:
    """Parameter names given to `node` (command line, parameters file, parameter_overrides) that it did not
    declare: rclpy ignores them silently, so a typo would run with the default."""
    return sorted(name for name in given_parameters(node) if not node.has_parameter(name))


def read_key_parameter(path: str) -> bytes | None:
    """The key in parameter key_file (None when empty); SettingsError naming the parameter otherwise."""
    try:
        return read_key(path) if path else None
    except KeyFileError as e:
        raise SettingsError(str(e)) from None


def run_key_parameters(values: dict[str, Any], world: bool) -> RunKey | None:
    """The node's RunKey from parameters key_file and run_nonce (None without a key): the world draws a run
    when none is given, an agent learns it from the world."""
    secret = read_key_parameter(values["key_file"])
    run = values["run_nonce"]
    if run < 0:
        raise SettingsError(f"parameter run_nonce must be 1..2**63-1, or 0 for none, got {run}")
    if secret is None:
        return None
    return RunKey(secret, run=run or (new_run() if world else None))


# The ROS 2 type each parameter's default gives it, as `ros2 param describe` names it.
_ROS_TYPES = {bool: "bool", int: "integer", float: "double", str: "string"}


def ros_type(default: Any) -> str:
    """The ROS parameter type a parameter declared with `default` takes: 'double' for 3.0, 'integer' for 3."""
    return _ROS_TYPES[type(default)]


def describe_parameters(kind: str) -> str:
    """Every parameter of node kind `kind`, one entry each: name, ROS type, default, then its description
    indented (what `--help` on a node prints; the descriptors hold the same text)."""
    lines = []
    for name, (default, description) in PARAMETERS[kind].items():
        lines.append(f"  {name} ({ros_type(default)}, default {default!r})")
        lines.extend(textwrap.wrap(description, width=100, initial_indent=" " * 6, subsequent_indent=" " * 6))
    return "\n".join(lines)


def help_requested(argv: list[str]) -> bool:
    """Whether `argv` (sys.argv) asks for -h or --help outside its --ros-args ... [--] (read here, not by rcl:
    bad ROS arguments are run_node's to report)."""
    among_ros = False
    for arg in argv[1:]:
        if arg == "--ros-args":
            among_ros = True
        elif arg == "--":
            among_ros = False
        elif not among_ros and arg in ("-h", "--help"):
            return True
    return False


def print_help(usage: str, kinds: tuple[str, ...]) -> int:
    """The `--help` of a node program: its usage (the module docstring), then the parameters of each node
    kind it runs; nothing is started. Its exit status: 0, a reader that left early (`| head -1`) included."""
    def write() -> int:
        print(usage.strip())
        for kind in kinds:
            print(f"\nParameters of the {kind} node (-p NAME:=VALUE, or a --params-file):")
            print(describe_parameters(kind))
        return 0

    return reader_may_leave(write)

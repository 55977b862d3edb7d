"""The run as a viewer sees it (RViz2, Foxglove, a bag): the map, the AGVs and their goals, and whom each
agent is looking at, as standard messages (`nav_msgs/OccupancyGrid`, `visualization_msgs/MarkerArray`), with
validating encode/decode (a decoder raises only `WireError`). The geometry and the markers: msgs_spec/README.md,
"Topics for viewers".
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from nav_msgs.msg import OccupancyGrid
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from .checks import check_agent, check_cell, check_type
from .errors import WireError
from .payloads import ID_DIGITS, Bounds
from .topics import AGENT_PREFIX, Qos, TopicSpec, _agent_id, parse_name, taking

__all__ = [
    "FRAME_ID", "LATTICE_RESOLUTION", "PALETTE", "OCCUPIED", "QOS_MAP", "QOS_MARKERS",
    "Occupancy", "Scene", "Looks", "cell_xy", "xy_cell",
    "encode_occupancy", "decode_occupancy", "encode_scene", "decode_scene", "encode_looks", "decode_looks",
    "MAP", "SCENE", "LOOKS", "VIEW_TOPICS", "MAP_TOPIC", "SCENE_TOPIC", "looks_topic", "parse_view_topic",
]

FRAME_ID = "map"
LATTICE_RESOLUTION = 0.5  # metres per lattice element: cells and walls alike
OCCUPIED = 100
# matplotlib's tab10, so that a rendered GIF (cq_ros.lab.render) shows each AGV in the colour RViz shows it in
PALETTE = ((0.122, 0.467, 0.706), (1.0, 0.498, 0.055), (0.173, 0.627, 0.173), (0.839, 0.153, 0.157),
           (0.580, 0.404, 0.741), (0.549, 0.337, 0.294), (0.890, 0.467, 0.761), (0.498, 0.498, 0.498),
           (0.737, 0.741, 0.133), (0.090, 0.745, 0.812))

# The map is latched, as RViz's and Foxglove's map displays expect; markers are volatile and deep enough that a
# recorder a few steps behind loses none.
QOS_MAP = Qos("reliable", "transient_local", 1)
QOS_MARKERS = Qos("reliable", "volatile", 100)


@dataclass(frozen=True)
class Occupancy:
    """The map's occupancy lattice, (2H+1) rows of (2W+1) flags, True = occupied (see the module docstring)."""

    lattice: tuple[tuple[bool, ...], ...]


@dataclass(frozen=True)
class Scene:
    """Where every AGV is at (episode, step), and every AGV's goal: (row, col) of agent k at index k-1."""

    episode: int
    step: int
    cells: tuple[tuple[int, int], ...]
    goals: tuple[tuple[int, int], ...]


@dataclass(frozen=True)
class Looks:
    """Whom agent `agent`, at (row, col), looks at to choose its action of (episode, step): (peer, row, col)
    of each, in order; () when it looks at nobody."""

    agent: int
    episode: int
    step: int
    row: int
    col: int
    peers: tuple[tuple[int, int, int], ...] = ()


def cell_xy(row: int, col: int) -> tuple[float, float]:
    return col + 0.5, -(row + 0.5)


def xy_cell(x: float, y: float, bounds: Bounds | None, what: str) -> tuple[int, int]:
    """The (row, col) whose centre is (x, y); WireError unless it is exactly one in the grid."""
    if not (math.isfinite(x) and math.isfinite(y)):
        raise WireError("not_finite", f"{what} at ({x!r}, {y!r})")
    col, row = x - 0.5, -y - 0.5
    if col != round(col) or row != round(row):
        raise WireError("not_integer", f"{what} at ({x}, {y}) is not the centre of a cell")
    row, col = int(round(row)), int(round(col))
    check_cell(row, col, bounds, f"{what} at cell")
    return row, col


# -- the map -------------------------------------------------------------------------------------------------


def encode_occupancy(occ: Occupancy, *, stamp: Time | None = None) -> OccupancyGrid:
    rows = len(occ.lattice)
    cols = len(occ.lattice[0]) if rows else 0
    if rows % 2 == 0 or cols % 2 == 0 or any(len(r) != cols for r in occ.lattice):
        raise WireError("malformed", f"a lattice is (2H+1) x (2W+1), got {rows} rows of {cols}")
    msg = OccupancyGrid()
    msg.header.frame_id = FRAME_ID
    msg.header.stamp = stamp or Time()
    msg.info.resolution = LATTICE_RESOLUTION
    msg.info.width, msg.info.height = cols, rows
    # grid row 0 is the lowest (the map's last lattice row); element (i, j) is centred at (j / 2, -i / 2)
    msg.info.origin.position.x = -LATTICE_RESOLUTION / 2
    msg.info.origin.position.y = -(rows - 1) * LATTICE_RESOLUTION - LATTICE_RESOLUTION / 2
    msg.info.origin.orientation.w = 1.0
    msg.data = [OCCUPIED if v else 0 for row in reversed(occ.lattice) for v in row]
    return msg


def decode_occupancy(msg: Any) -> Occupancy:
    check_type(msg, OccupancyGrid)
    info = msg.info
    rows, cols = info.height, info.width
    if (msg.header.frame_id != FRAME_ID or info.resolution != LATTICE_RESOLUTION or rows % 2 == 0
            or cols % 2 == 0 or len(msg.data) != rows * cols):
        raise WireError("wrong_layout", f"frame {msg.header.frame_id!r}, resolution {info.resolution}, "
                                        f"{rows} x {cols} holding {len(msg.data)} values: not a cq_ros map")
    data = list(msg.data)
    if any(v not in (0, OCCUPIED) for v in data):
        raise WireError("malformed", f"occupancy values other than 0 and {OCCUPIED}")
    grid = [tuple(v == OCCUPIED for v in data[r * cols:(r + 1) * cols]) for r in range(rows)]
    return Occupancy(tuple(reversed(grid)))


# -- markers -------------------------------------------------------------------------------------------------

_STAMP = re.compile(r"episode (0|{0}) step (0|{0})".format(ID_DIGITS))
_LOOKS_TEXT = re.compile(_STAMP.pattern + r":((?: " + AGENT_PREFIX + ID_DIGITS + ")*)")


def _colour(agent: int, alpha: float = 1.0) -> ColorRGBA:
    r, g, b = PALETTE[(agent - 1) % len(PALETTE)]
    return ColorRGBA(r=r, g=g, b=b, a=alpha)


def _marker(ns: str, ident: int, kind: int, stamp: Time | None, xyz: tuple[float, float, float],
            scale: tuple[float, float, float], colour: ColorRGBA, text: str = "") -> Marker:
    m = Marker(ns=ns, id=ident, type=kind, action=Marker.ADD, color=colour, text=text)
    m.header.frame_id = FRAME_ID
    m.header.stamp = stamp or Time()
    m.pose.position.x, m.pose.position.y, m.pose.position.z = xyz
    m.pose.orientation.w = 1.0
    m.scale.x, m.scale.y, m.scale.z = scale
    return m


def encode_scene(scene: Scene, *, stamp: Time | None = None) -> MarkerArray:
    if len(scene.cells) != len(scene.goals) or not scene.cells:
        raise WireError("malformed", f"{len(scene.cells)} cells and {len(scene.goals)} goals")
    markers = []
    for k, ((row, col), (grow, gcol)) in enumerate(zip(scene.cells, scene.goals), start=1):
        x, y = cell_xy(row, col)
        markers.append(_marker("agv", k, Marker.CYLINDER, stamp, (x, y, 0.25), (0.7, 0.7, 0.5), _colour(k)))
        markers.append(_marker("goal", k, Marker.CUBE, stamp, (*cell_xy(grow, gcol), 0.025), (0.9, 0.9, 0.05),
                               _colour(k, 0.35)))
        markers.append(_marker("label", k, Marker.TEXT_VIEW_FACING, stamp, (x, y, 0.8), (0, 0, 0.5),
                               ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0), str(k)))
    markers.append(_marker("step", 0, Marker.TEXT_VIEW_FACING, stamp, (0.0, 0.6, 0.5), (0, 0, 0.6),
                           ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0), f"episode {scene.episode} step {scene.step}"))
    return MarkerArray(markers=markers)


def decode_scene(msg: Any, *, bounds: Bounds | None = None) -> Scene:
    check_type(msg, MarkerArray)
    by_ns: dict[str, dict[int, Any]] = {"agv": {}, "goal": {}, "label": {}, "step": {}}
    for m in msg.markers:
        if m.ns not in by_ns or m.id in by_ns[m.ns]:
            raise WireError("wrong_layout", f"marker ns {m.ns!r} id {m.id}: unknown or repeated")
        by_ns[m.ns][m.id] = m
    n = len(by_ns["agv"])
    agents = set(range(1, n + 1))
    if not n or set(by_ns["agv"]) != agents or set(by_ns["goal"]) != agents or set(by_ns["step"]) != {0}:
        raise WireError("wrong_layout", f"agv markers {sorted(by_ns['agv'])}, goal markers "
                                        f"{sorted(by_ns['goal'])}: expected 1..N of each and one step marker")
    if bounds is not None and n != bounds.n_agents:
        raise WireError("unknown_agent", f"{n} agents, known agents 1..{bounds.n_agents}")
    stamp = _STAMP.fullmatch(text := by_ns["step"][0].text)
    if not stamp:
        raise WireError("malformed", f"step marker text {text!r}, expected 'episode E step S'")
    cells = {ns: tuple(xy_cell(m.pose.position.x, m.pose.position.y, bounds, f"{ns} {k}")
                       for k, m in sorted(by_ns[ns].items())) for ns in ("agv", "goal")}
    return Scene(int(stamp.group(1)), int(stamp.group(2)), cells["agv"], cells["goal"])


def encode_looks(looks: Looks, *, stamp: Time | None = None) -> MarkerArray:
    agent = _agent_id(looks.agent)
    names = "".join(f" {AGENT_PREFIX}{_agent_id(p)}" for p, _, _ in looks.peers)
    x, y = cell_xy(looks.row, looks.col)
    m = _marker(f"{AGENT_PREFIX}{agent}/looks", 0, Marker.LINE_LIST, stamp, (x, y, 0.5), (0.08, 0.0, 0.0),
                _colour(agent), f"episode {looks.episode} step {looks.step}:{names}")
    if not looks.peers:
        m.action = Marker.DELETE
    for _, row, col in looks.peers:  # relative to the pose: the agent's own cell
        px, py = cell_xy(row, col)
        m.points += [Point(), Point(x=px - x, y=py - y)]
    return MarkerArray(markers=[m])


def decode_looks(msg: Any, *, bounds: Bounds | None = None, agent: int | None = None) -> Looks:
    """Looks from `msg`; `agent`: the agent whose topic it came on."""
    check_type(msg, MarkerArray)
    if len(msg.markers) != 1:
        raise WireError("wrong_layout", f"{len(msg.markers)} markers, expected 1")
    m = msg.markers[0]
    found = re.fullmatch(AGENT_PREFIX + f"({ID_DIGITS})/looks", m.ns)
    if not found or m.id != 0 or m.type != Marker.LINE_LIST:
        raise WireError("wrong_layout", f"marker ns {m.ns!r} id {m.id} type {m.type}, expected "
                                        f"'{AGENT_PREFIX}<k>/looks' 0 LINE_LIST")
    who = int(found.group(1))
    check_agent(who, bounds, agent)
    text = _LOOKS_TEXT.fullmatch(m.text)
    if not text:
        raise WireError("malformed", f"text {m.text!r}, expected 'episode E step S: agv<j> ...'")
    peers = [int(p[len(AGENT_PREFIX):]) for p in text.group(3).split()]
    points = list(m.points)
    if m.action != (Marker.ADD if peers else Marker.DELETE) or len(points) != 2 * len(peers):
        raise WireError("malformed", f"{len(peers)} peers named, {len(points)} points, action {m.action}")
    x, y = m.pose.position.x, m.pose.position.y
    row, col = xy_cell(x, y, bounds, "the looking agent")
    if any((p.x, p.y) != (0.0, 0.0) for p in points[::2]):
        raise WireError("malformed", "a line does not start at the looking agent")
    ends = [xy_cell(x + p.x, y + p.y, bounds, f"line end {i}") for i, p in enumerate(points[1::2])]
    return Looks(who, int(text.group(1)), int(text.group(2)), row, col,
                 tuple((p, r, c) for p, (r, c) in zip(peers, ends)))


# -- topics --------------------------------------------------------------------------------------------------


_ENCODERS = {Occupancy: encode_occupancy, Scene: encode_scene, Looks: encode_looks}


def _encode(payload: Any, **kwargs: Any) -> Any:
    return _ENCODERS[type(payload)](payload, **kwargs)  # looked up per call (tests count what is built)


MAP = TopicSpec(
    "map", "world/map", OccupancyGrid, QOS_MAP, Occupancy,
    "world, once at start (latched)", "viewers (RViz2 Map display, Foxglove), tools",
    "0.5 m lattice of cells and the walls between them (0 free, 100 occupied), frame 'map'",
    decoder=taking(decode_occupancy), encoder=_encode,
)
SCENE = TopicSpec(
    "scene", "world/markers", MarkerArray, QOS_MARKERS, Scene,
    "world, every step (only while someone subscribes)", "viewers (RViz2 MarkerArray display, Foxglove), tools",
    "markers ns agv/goal/label id k per agent, ns step id 0 with text 'episode E step S'",
    decoder=taking(decode_scene, "bounds"), encoder=_encode,
)
LOOKS = TopicSpec(
    "looks", AGENT_PREFIX + "{agent}/looks", MarkerArray, QOS_MARKERS, Looks,
    "agent k at each decision (the JSA central node: every agent's; only while someone subscribes)",
    "viewers, tools", "one LINE_LIST ns 'agv<k>/looks' from agent k to each peer it looks at; DELETE for none",
    decoder=taking(decode_looks, "bounds", "agent"), encoder=_encode,  # a viewer takes any episode and step
)
VIEW_TOPICS: tuple[TopicSpec, ...] = (MAP, SCENE, LOOKS)
MAP_TOPIC, SCENE_TOPIC = MAP.pattern, SCENE.pattern


def looks_topic(agent: int) -> str:
    return LOOKS.name(agent)


def parse_view_topic(name: str) -> tuple[TopicSpec, int | None]:
    """(spec, agent) for a viewer topic name, relative or under any namespace; ValueError for any other."""
    return parse_name(name, VIEW_TOPICS, "cq_ros viewer topic")

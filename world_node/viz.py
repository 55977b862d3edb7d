"""The world's publications for viewers (msgs_spec/viz.py): the map once, latched, and the scene (every AGV
and its goal) of every step, built only while someone subscribes (as the publisher's matched events tell: an
unwatched run pays nothing for it)."""

from __future__ import annotations

from typing import Any

from rclpy.event_handler import PublisherEventCallbacks

from cq_ros.gridmap import GridMap
from cq_ros.gridmap import lattice
from msgs_spec import Position
from msgs_spec.viz import MAP, MAP_TOPIC, SCENE, SCENE_TOPIC, Occupancy, Scene
from node_runtime.qos import profile
from node_runtime.graph import Matched

__all__ = ["WorldView"]


class WorldView:
    def __init__(self, node: Any, gridmap: GridMap, watchers: Matched):
        """`watchers`: the scene's matched readers, shared with the position topics (world_node.positions: while
        someone watches, the core makes every agent's position, which the scene shows)."""
        self.node = node
        self.n = gridmap.n_agents
        self.goals = tuple(gridmap.cells[g] for g in gridmap.goals)
        self.map = node.create_publisher(MAP.msg_type, MAP_TOPIC, profile(MAP.qos))
        self.map.publish(MAP.encode(Occupancy(lattice(gridmap)), stamp=node.get_clock().now().to_msg()))
        self.watchers = watchers
        self.scene = node.create_publisher(SCENE.msg_type, SCENE_TOPIC, profile(SCENE.qos),
                                           event_callbacks=PublisherEventCallbacks(matched=self.watchers))

    def publish(self, out: list) -> None:
        """The scene of every step whose positions are in `out` (the world's outbox: the N positions of a step
        come together, agent 1 first)."""
        if not self.watchers.count:
            return
        cells: list[tuple[int, int]] = []
        for payload in out:
            if isinstance(payload, Position):
                cells.append((payload.row, payload.col))
                if len(cells) == self.n:
                    self.scene.publish(SCENE.encode(Scene(payload.episode, payload.step, tuple(cells), self.goals),
                                                    stamp=self.node.get_clock().now().to_msg()))
                    cells = []

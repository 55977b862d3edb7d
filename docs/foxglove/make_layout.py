"""Writes docs/foxglove/layout.json (foxglove-sdk's layout builder, the extra `view`): a 3D panel on frame `map`
with the world's grid and markers and every agent's looks, and a plot of collisions per episode, for the system
in namespace /demo (`cq-ros launch --namespace demo ... --view 8765`, or `cq-ros view` beside it).

    .venv/bin/python docs/foxglove/make_layout.py [--agents N]
"""

import argparse
from pathlib import Path

from foxglove import layouts as fl

NAMESPACE = "/demo"
OUT = Path(__file__).with_name("layout.json")


def layout(agents: int) -> str:
    topics = {f"{NAMESPACE}/world/map": fl.BaseRendererRosOccupancyGridTopicSettings(visible=True),
              f"{NAMESPACE}/world/markers": fl.BaseRendererRosMarkerTopicSettings(visible=True),
              **{f"{NAMESPACE}/agv{k}/looks": fl.BaseRendererRosMarkerTopicSettings(visible=True)
                 for k in range(1, agents + 1)}}
    scene = fl.ThreeDeePanel(title="AGVs on the map", config=fl.ThreeDeeConfig(fixed_frame="map", follow_tf="map",
                                                                              topics=topics))
    # world/stats is one DiagnosticStatus whose values are KeyValue pairs (msgs_spec/README.md).
    collisions = fl.PlotPanel(title="collisions per episode", config=fl.PlotConfig(paths=[fl.PlotSeries(
        value=f'{NAMESPACE}/world/stats.status[0].values[:]{{key=="collisions"}}.value', label="collisions",
        enabled=True)]))
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=2, content=scene), fl.SplitItem(proportion=1, content=collisions)])).to_json()


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agents", type=int, default=2, help="agents whose looks to show (default 2)")
    OUT.write_text(layout(parser.parse_args().agents) + "\n")
    print(f"wrote {OUT}")

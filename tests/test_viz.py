"""A run you can watch: the world's map (OccupancyGrid) and markers and each agent's looks (MarkerArray),
decoded from a live run and from a bag of `cq-ros record`, show exactly what the offline engine's episode shows
(where every AGV is, whom each agent looks at); nothing is built while nobody watches; `cq-ros render` draws
an episode as a GIF with one frame per step, from the engine or from the bag."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest
from PIL import Image

from cq_ros.engine import run
from cq_ros.gridmap import load_map
from cq_ros.gridmap import lattice
from cq_ros.lab.render import (CELL_INCHES, DPI, Picture, cut_by_bag, engine_frames, episode_to_draw, frames_from,
                               write_animation)
from cq_ros.settings import Settings
from msgs_spec import Bounds
from msgs_spec import viz
from node_runtime.qos import profile
from ros_tools.commands import read_view_bag
from helpers import finish, wait_until

GRID = ("grid_game_2", 1, (("window", 5), ("eval_episodes", 0)))
EPISODES = 30  # CQ marks joint states by then, so its agents look at each other now and then
WAIT_S = 20.0  # bound on a subscription's match


def offline_frames(algo: str, episode: int) -> list:
    map_name, seed, settings = GRID
    return engine_frames(load_map(map_name), algo, Settings().with_overrides(dict(settings)), seed, EPISODES,
                         episode)


def watch(ctx, system) -> dict:
    """Subscribe a viewer to the map, the scene and every agent's looks (decoded as they come)."""
    import rclpy

    gridmap = load_map(GRID[0])
    bounds = Bounds(gridmap.n_agents, gridmap.height, gridmap.width)
    seen = {"map": [], "scenes": [], "looks": []}
    viewer = system.add(rclpy.create_node("viewer", context=ctx))
    viewer.create_subscription(viz.MAP.msg_type, viz.MAP_TOPIC,
                               lambda m: seen["map"].append(viz.MAP.decode(m)), profile(viz.MAP.qos))
    viewer.create_subscription(viz.SCENE.msg_type, viz.SCENE_TOPIC,
                               lambda m: seen["scenes"].append(viz.SCENE.decode(m, bounds=bounds)),
                               profile(viz.SCENE.qos))
    for k in range(1, gridmap.n_agents + 1):
        viewer.create_subscription(viz.LOOKS.msg_type, viz.looks_topic(k), lambda m, k=k: seen["looks"].append(
            viz.LOOKS.decode(m, bounds=bounds, agent=k)), profile(viz.LOOKS.qos))
    return seen


def viewer_publishers(system) -> list:
    return [system.world._view.scene] + [p for a in system.agents for p in a._view.pubs.values()]


def matched(system, stats_subscribers: int) -> bool:
    """Every viewer publication of the system has a subscriber, and world/stats `stats_subscribers` (asking
    needs no spinning)."""
    return (all(p.get_subscription_count() >= 1 for p in viewer_publishers(system))
            and system.world._stats.get_subscription_count() >= stats_subscribers)


def wait_matched(system, stats_subscribers: int = 1) -> None:
    wait_until(lambda: matched(system, stats_subscribers), WAIT_S, "the viewer's subscriptions never matched",
               poll_s=0.02)


def acknowledged(system) -> bool:
    """Every subscriber (a recorder) has acknowledged every message of the viewer publications and world/stats
    (all reliable)."""
    from rclpy.duration import Duration

    return all(p.wait_for_all_acked(Duration(seconds=1)) for p in [*viewer_publishers(system), system.world._stats])


@pytest.mark.parametrize("algo", ["cq", "jsa"])  # decentralised looks, and the central node's for every AGV
def test_a_live_run_shows_what_the_offline_episode_shows(system_in, ros_context, spin_until, algo):
    map_name, seed, settings = GRID
    system = system_in(algo, map_name, seed, EPISODES, settings)
    seen = watch(ros_context, system)
    wait_matched(system)  # before the first step: the world steps only once it is spun
    finish(system)
    assert spin_until(system.executor, lambda: seen["map"] and {s.episode for s in seen["scenes"]} >= {EPISODES - 1}
                      and len(seen["scenes"]) == sum(s.steps + 1 for s in system.world_stats), 5.0)
    assert [m.lattice for m in seen["map"]] == [lattice(load_map(map_name))]
    frames = frames_from(seen["scenes"], seen["looks"])
    for episode in (0, EPISODES - 1):
        assert [f for f in frames if f.episode == episode] == offline_frames(algo, episode)
    assert any(f.looks for f in frames)
    goals = load_map(map_name)
    assert all(s.goals == tuple(goals.cells[g] for g in goals.goals) for s in seen["scenes"])


def test_nothing_is_built_for_viewers_while_nobody_subscribes(system_in, ros_context, spin_until, monkeypatch):
    built = {payload: 0 for payload in viz._ENCODERS}
    for payload, encode in list(viz._ENCODERS.items()):
        monkeypatch.setitem(viz._ENCODERS, payload,
                            lambda p, _encode=encode, **kw: (built.__setitem__(type(p), built[type(p)] + 1),
                                                             _encode(p, **kw))[1])
    map_name, seed, settings = GRID
    finish(system_in("cq", map_name, seed, 10, settings))
    assert built == {viz.Occupancy: 1, viz.Scene: 0, viz.Looks: 0}  # the latched map, once


def test_markers_false_creates_no_publisher_for_viewers(system_in, spin_until):
    map_name, seed, settings = GRID
    off = system_in("indep", map_name, seed, 2, settings, world_extra={"markers": False},
                    agent_extra={k: {"markers": False} for k in (1, 2)})
    node = off.world
    assert off.world._view is None and all(a._view is None for a in off.agents)
    assert node.count_publishers(viz.SCENE_TOPIC) == node.count_publishers(viz.MAP_TOPIC) == 0
    finish(off)


@pytest.mark.slow
def test_a_recorded_bag_replays_the_run_and_renders_as_a_gif(system_in, tmp_path, spin_until, ros_domain_id):
    bag, gif = tmp_path / "bag", tmp_path / "episode.gif"
    env = {**os.environ, "ROS_DOMAIN_ID": str(ros_domain_id)}
    recorder = subprocess.Popen([sys.executable, "-m", "cq_ros.cli", "record", "--out", str(bag), "--duration", "90"],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        map_name, seed, settings = GRID
        system = system_in("cq", map_name, seed, EPISODES, settings)
        wait_matched(system, stats_subscribers=2)  # the probe's statistics subscription, and the recorder's
        finish(system)
        wait_until(lambda: acknowledged(system), WAIT_S, "the recorder never acknowledged the run's last messages")
        recorder.send_signal(signal.SIGINT)
        out, err = recorder.communicate(timeout=30)
        assert recorder.returncode == 0, err
    finally:
        if recorder.poll() is None:
            recorder.kill()
            recorder.wait(timeout=30)
    occupancy, scenes, looks = read_view_bag(bag)
    assert occupancy.lattice == lattice(load_map(map_name))
    frames = frames_from(scenes, looks)
    last = offline_frames("cq", EPISODES - 1)
    for episode in (0, EPISODES - 1):
        assert [f for f in frames if f.episode == episode] == offline_frames("cq", episode)
    # reading one episode's looks only (render's way) draws that episode as reading them all does
    _, _, its_looks = read_view_bag(bag, episode_of=lambda scenes: 1)
    assert frames_from([s for s in scenes if s.episode == 1], its_looks) == offline_frames("cq", 1)

    done = subprocess.run([sys.executable, "-m", "cq_ros.cli", "render", "--bag", str(bag), "--out", str(gif)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "cut by the bag" not in done.stderr + done.stdout  # the bag holds every step of the run
    with Image.open(gif) as image:  # one frame per step of the last episode, at the size the map asks
        assert image.format == "GIF" and image.n_frames == len(last)
        gridmap = load_map(map_name)
        assert image.size == (round(max(3.0, gridmap.width * CELL_INCHES) * DPI),
                              round(max(2.5, gridmap.height * CELL_INCHES + 0.5) * DPI))


def test_render_says_when_the_bag_cut_the_episode_it_draws():
    from types import SimpleNamespace as Scene

    goals = ((0, 2), (2, 2))
    whole = [Scene(episode=3, step=t, cells=((0, t), (2, t)), goals=goals) for t in range(3)]
    assert cut_by_bag(whole, 3) is None
    assert "starts it at step 1, not 0" in cut_by_bag(whole[1:], 3)
    assert "ends at its step 1 with AGVs short of their goals" in cut_by_bag(whole[:2], 3)
    later = [*whole[:2], Scene(episode=4, step=0, cells=((0, 0), (2, 0)), goals=goals)]
    assert cut_by_bag(later, 3) is None  # ended short of the goals, but the next episode began: the step cap


def test_a_bag_recorded_mid_run_draws_its_last_whole_episode_by_default():
    from types import SimpleNamespace as Scene

    goals = ((0, 2), (2, 2))

    def episode(number, steps, home=True):
        last = [Scene(episode=number, step=steps - 1, cells=goals if home else ((0, 0), (2, 0)), goals=goals)]
        return [Scene(episode=number, step=t, cells=((0, t), (2, t)), goals=goals) for t in range(steps - 1)] + last

    started_late = episode(7, 5)[2:]  # the recording began at its step 2
    assert episode_to_draw([*started_late, *episode(8, 4), *episode(9, 3)[:2]]) == 8  # 9: stopped mid-episode
    assert episode_to_draw([*started_late, *episode(8, 4), *episode(9, 3)]) == 9  # 9 ended home: whole
    assert episode_to_draw([*episode(8, 4, home=False), *episode(9, 3)[:1]]) == 8  # ran to the step cap
    assert episode_to_draw(started_late) == 7  # cut, but the only one


def write_bag(bag, gridmap, episodes: list[list]) -> None:
    """A bag as `cq-ros record` writes one, under a namespace: the map, then each frame's scene and looks."""
    from rclpy.serialization import serialize_message
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    goals = tuple(gridmap.cells[g] for g in gridmap.goals)
    writer = Writer(bag, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    topics = {name: writer.add_connection(f"/cq_t/{name}", kind, typestore=typestore) for name, kind in (
        (viz.MAP_TOPIC, "nav_msgs/msg/OccupancyGrid"), (viz.SCENE_TOPIC, "visualization_msgs/msg/MarkerArray"),
        *((viz.looks_topic(k + 1), "visualization_msgs/msg/MarkerArray") for k in range(gridmap.n_agents)))}
    stamp = 10**9
    writer.write(topics[viz.MAP_TOPIC], stamp, serialize_message(viz.encode_occupancy(viz.Occupancy(lattice(gridmap)))))
    for frames in episodes:
        for f in frames:
            stamp += 10**8
            writer.write(topics[viz.SCENE_TOPIC], stamp,
                         serialize_message(viz.encode_scene(viz.Scene(f.episode, f.step, f.cells, goals))))
            for agent, peers in f.looks.items():
                look = viz.Looks(agent, f.episode, f.step, *f.cells[agent - 1], peers)
                writer.write(topics[viz.looks_topic(agent)], stamp + 10**7, serialize_message(viz.encode_looks(look)))
    writer.close()


def test_render_of_a_bag_recorded_mid_run_draws_its_whole_episode(tmp_path):
    """The README's `cq-ros render --bag DIR --out X.gif` on a bag that began in episode 0's step 2 and stopped
    in episode 2: it draws episode 1, every step; an --episode the bag does not hold names those it does."""
    gridmap = load_map("tunnel_to_goal")
    settings = Settings(step_cap=60)
    played = [engine_frames(gridmap, "cq", settings, seed=3, episodes=3, episode=e) for e in range(3)]
    bag = tmp_path / "bag"
    write_bag(bag, gridmap, [played[0][2:], played[1], played[2][:2]])
    done = subprocess.run([sys.executable, "-m", "cq_ros.cli", "render", "--bag", str(bag), "--out",
                           str(tmp_path / "run.gif")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"{tmp_path / 'run.gif'}: episode 1, {len(played[1])} frames"
    occupancy, scenes, looks = read_view_bag(bag, episode_of=episode_to_draw)
    assert frames_from([s for s in scenes if s.episode == 1], looks) == played[1]
    bad = subprocess.run([sys.executable, "-m", "cq_ros.cli", "render", "--bag", str(bag), "--episode", "12",
                          "--out", str(tmp_path / "x.gif")], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert bad.stderr.strip() == f"cq-ros render: error: episode 12 is not in {bag}: it holds episodes 0..2, whole: 1"


def test_each_gif_frame_is_the_whole_picture_drawn_at_its_step(tmp_path):
    """The GIF draws the moving parts over a background drawn once, in the first frame's palette: each frame
    is still the picture a whole draw makes, up to antialiased edges."""
    import numpy as np

    gridmap = load_map("tunnel_to_goal")
    frames = engine_frames(gridmap, "cq", Settings(step_cap=40), seed=1, episodes=3)
    occupancy, goals = lattice(gridmap), tuple(gridmap.cells[g] for g in gridmap.goals)
    gif = write_animation(tmp_path / "e.gif", occupancy, goals, frames, title="t", fps=5)
    whole = Picture(occupancy, goals, title="t", blit=False)
    with Image.open(gif) as image:
        assert image.n_frames == len(frames) and image.info["duration"] == 200
        for k in (0, len(frames) // 2, len(frames) - 1):
            image.seek(k)
            whole.show(frames[k])
            off = np.abs(np.asarray(image.convert("RGB"), dtype=int) - whole.rgb()).sum(axis=2)
            assert (off > 60).mean() < 0.01, k  # the same picture: only edges' shades differ


@pytest.mark.slow
def test_render_draws_an_offline_episode_with_one_frame_per_step(tmp_path):
    gif = tmp_path / "tunnel.gif"
    args = ["--map", "tunnel_to_goal", "--algo", "cq", "--episodes", "20", "--seed", "3", "--set", "step_cap=60"]
    done = subprocess.run([sys.executable, "-m", "cq_ros.cli", "render", *args, "--episode", "4", "--out", str(gif)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    learnt = run("cq", load_map("tunnel_to_goal"), Settings().with_overrides({"step_cap": 60}), 3, 0, 20)
    steps = learnt.episodes["steps"][4]
    with Image.open(gif) as image:
        assert image.n_frames == int(steps) + 1 and min(image.size) >= 150
    bad = subprocess.run([sys.executable, "-m", "cq_ros.cli", "render", *args, "--episode", "20", "--out",
                          str(tmp_path / "x.gif")], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "episode 20 is not one of the 20 episodes" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1, bad.stderr  # before any learning, not after it
    assert not (tmp_path / "x.gif").exists()


@pytest.mark.slow
def test_render_draws_the_greedy_episode_after_learning_at_the_dpi_asked(tmp_path):
    gif = tmp_path / "greedy.gif"
    gridmap = load_map("tunnel_to_goal")
    args = ["--map", "tunnel_to_goal", "--algo", "cq", "--episodes", "20", "--seed", "3", "--set", "step_cap=60"]
    done = subprocess.run([sys.executable, "-m", "cq_ros.cli", "render", *args, "--greedy", "--dpi", "40",
                           "--out", str(gif)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "episode 20," in done.stdout  # numbered after the 20 learning episodes, as a ROS run numbers it
    settings = Settings().with_overrides({"step_cap": 60, "eval_episodes": 1})
    steps = run("cq", gridmap, settings, 3, 0, 20).greedy["steps"][0]  # the run's first greedy episode
    with Image.open(gif) as image:
        assert image.n_frames == int(steps) + 1
        assert image.size == (round(max(3.0, gridmap.width * CELL_INCHES) * 40),
                              round(max(2.5, gridmap.height * CELL_INCHES + 0.5) * 40))
    for bad, says in (([*args, "--greedy", "--episode", "3"], "not both"), ([*args, "--dpi", "0"], "--dpi"),
                      (["--bag", str(tmp_path), "--greedy"], "--greedy applies to --map"),
                      (["--bag", str(tmp_path), "--seed", "0"], "--seed applies to --map"),
                      (["--bag", str(tmp_path), "--algo", "cq"], "--algo applies to --map")):
        done = subprocess.run([sys.executable, "-m", "cq_ros.cli", "render", *bad, "--out", str(tmp_path / "x.gif")],
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 2 and says in done.stderr, done.stderr
        assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert not (tmp_path / "x.gif").exists()

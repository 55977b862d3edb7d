"""An episode as an animation: the map, the AGVs and their goals, and a line from each agent to every peer it
looks at to choose its move (CQ's sparse attention), step by step, as an animated GIF (matplotlib's
animation writers: Pillow for GIF, ffmpeg for MP4 where it is installed).

The same picture as a ROS viewer gets from the world's and the agents' markers (msgs_spec/viz.py), with the
same geometry (cell (row, col) centred at x = col + 0.5, y = -(row + 0.5)), the same map lattice and the same
colours (matplotlib's tab10). Frames come from the offline engine (`engine_frames`, which films one episode
of `cq_ros.engine.run` through Team's per-step hook, without changing it) or from a recorded bag (`frames_from`,
given the decoded messages). No ROS import here.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from .. import compiled
from ..engine import Team, greedy_team, make_learners, world_seed
from ..gridmap import GridMap
from ..settings import Settings
from ..world import GridWorld

__all__ = ["Frame", "Picture", "engine_frames", "frames_from", "cut_by_bag", "episode_to_draw", "check_output",
           "write_animation", "FORMATS"]

FORMATS = {".gif": "pillow", ".mp4": "ffmpeg"}  # output suffix -> matplotlib animation writer
CELL_INCHES = 0.6
DPI = 72


@dataclass(frozen=True)
class Frame:
    """One step of an episode: where each AGV is (agent k at index k-1) and, for each agent that chose a move
    at this step, the (peer, row, col) of every peer it looked at (agents 1-based; none at the last step)."""

    episode: int
    step: int
    cells: tuple[tuple[int, int], ...]
    looks: dict[int, tuple[tuple[int, int, int], ...]] = field(default_factory=dict)


def engine_frames(gridmap: GridMap, algo: str, settings: Settings, seed: int, episodes: int,
                  episode: int | None = None, progress: Callable[[int], Any] | None = None,
                  greedy: bool = False, engine: str = "compiled") -> list[Frame]:
    """The frames of learning episode `episode` (0-based; None: the last of `episodes`) of the offline run
    `cq_ros.engine.run(algo, gridmap, settings, seed, 0, episodes)`: every step from 0 to the last. With
    `greedy`, instead the run's first greedy episode after its `episodes` learning ones (numbered `episodes`,
    as a ROS run numbers it; the first row of the run's greedy.csv). `progress(e)` is called after each
    episode e played before it. Those play on `engine` (cq_ros.compiled.play), the filmed one on the reference
    engine from the learners they left (team_of), as the reference would have played it."""
    if greedy and episode is not None:
        raise ValueError("draw either a learning episode or the greedy one after learning, not both")
    episode = episodes - 1 if episode is None else episode
    if not 0 <= episode < episodes:
        raise ValueError(f"episode {episode} is not one of the {episodes} episodes (0..{episodes - 1})")
    before = episodes if greedy else episode
    if compiled.engine_of(algo, engine) == "compiled":
        from ..compiled.engine import Kernel, team_of

        kernel = Kernel(algo, gridmap, settings, seed, 0)
        played = iter(range(before))
        kernel.play(before, None if progress is None else lambda: progress(next(played)))
        team = team_of(kernel)
    else:
        team = Team(GridWorld(gridmap, settings, seed=world_seed(seed, 0)), make_learners(algo, gridmap, settings,
                                                                                         seed, 0))
        for e in range(before):
            team.episode()
            if progress is not None:
                progress(e)
    if greedy:
        team, episode = greedy_team(team, keep=False), episodes  # the run is not needed after: no copy
    frames: list[Frame] = []
    place = gridmap.cells

    def shoot(world: GridWorld, _actions: Any, looks: Any) -> None:
        cells = tuple(place[c] for c in world.cells)
        frames.append(Frame(episode, world.t, cells, {i + 1: tuple((j + 1, *cells[j]) for j in peers)
                                                      for i, peers in enumerate(looks) if peers}))

    team.episode(on_step=shoot)
    w = team.world
    frames.append(Frame(episode, w.t, tuple(place[c] for c in w.cells), {}))
    return frames


def frames_from(scenes: Iterable[Any], looks: Iterable[Any]) -> list[Frame]:
    """Frames from what a ROS run published: each scene (.episode, .step, .cells) with the looks (.agent,
    .episode, .step, .peers) stamped with its step; a look with no peers draws nothing."""
    by_step: dict[tuple[int, int], dict[int, tuple]] = {}
    for look in looks:
        if look.peers:
            by_step.setdefault((look.episode, look.step), {})[look.agent] = tuple(look.peers)
    return [Frame(s.episode, s.step, tuple(s.cells), by_step.get((s.episode, s.step), {})) for s in scenes]


def cut_by_bag(scenes: list[Any], episode: int) -> str | None:
    """How a bag's `scenes` (.episode, .step, .cells, .goals, in the bag's order) cut `episode`, or None when
    they hold all of it: its first step is not step 0 (the recording began after it did), or it is the bag's
    last episode and its last scene has an AGV short of its goal (the recording ended first, or the episode
    ran to the step cap)."""
    mine = [s for s in scenes if s.episode == episode]
    cuts = []
    if mine[0].step != 0:
        cuts.append(f"the bag starts it at step {mine[0].step}, not 0")
    if scenes[-1].episode == episode and tuple(mine[-1].cells) != tuple(mine[-1].goals):
        cuts.append(f"the bag ends at its step {mine[-1].step} with AGVs short of their goals (the recording "
                    "stopped first, or the episode ran to the step cap)")
    return "; ".join(cuts) or None


def episode_to_draw(scenes: list[Any]) -> int:
    """The episode `render --bag` draws by default: the bag's last episode that it holds whole (`cut_by_bag`),
    or its last when it cuts every one. A recording stopped by hand almost always cuts its last episode, and one
    started mid-run its first."""
    episodes = list(dict.fromkeys(s.episode for s in scenes))
    return next((e for e in reversed(episodes) if cut_by_bag(scenes, e) is None), episodes[-1])


def check_output(path: Path) -> str:
    """The matplotlib writer for `path`; ValueError (one line) for a suffix we cannot write here."""
    from matplotlib import animation

    writer_name = FORMATS.get(path.suffix.lower())
    if writer_name is None:
        raise ValueError(f"{path}: the animation's file name must end in {' or '.join(FORMATS)}")
    if not animation.writers.is_available(writer_name):
        raise ValueError(f"{path}: writing {path.suffix} needs {writer_name}, which is not installed here")
    return writer_name


class Picture:
    """The drawing of one map's episodes, a frame at a time: the map, the goals, the AGVs and their looks,
    `dpi` pixels an inch (a cell is CELL_INCHES). `show(frame)` moves everything to `frame`; `rgb()` is the
    picture as an (H, W, 3) uint8 array (PettingZoo's `render_mode="rgb_array"`, and the GIF's frames).

    With `blit` (the default) the map and the goals are drawn once and each `rgb()` draws only what moves over
    them: the map's image was most of a frame's drawing. Without it, every draw of `figure` (an animation
    writer's grab) draws the whole picture."""

    def __init__(self, occupancy: tuple[tuple[bool, ...], ...], goals: tuple[tuple[int, int], ...], *,
                 title: str = "", dpi: float = DPI, blit: bool = True):
        from matplotlib import colormaps
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.collections import LineCollection
        from matplotlib.figure import Figure
        from matplotlib.patches import Rectangle

        height, width = (len(occupancy) - 1) // 2, (len(occupancy[0]) - 1) // 2
        colours = colormaps["tab10"].colors
        self._colour = [colours[k % len(colours)] for k in range(len(goals))]
        self._title = title
        self.figure = fig = Figure(figsize=(max(3.0, width * CELL_INCHES), max(2.5, height * CELL_INCHES + 0.5)),
                                   dpi=dpi)
        self._canvas = FigureCanvasAgg(fig)
        ax = fig.add_axes((0.02, 0.02, 0.96, 0.86))
        ax.set_axis_off()
        ax.imshow([[0.25 if v else 1.0 for v in row] for row in occupancy], cmap="gray", vmin=0, vmax=1,
                  extent=(-0.25, width + 0.25, -(height + 0.25), 0.25), interpolation="nearest")
        for k, (row, col) in enumerate(goals):
            ax.add_patch(Rectangle((col + 0.05, -(row + 0.95)), 0.9, 0.9, color=self._colour[k], alpha=0.35, lw=0))
        ax.set_xlim(-0.25, width + 0.25)
        ax.set_ylim(-(height + 0.25), 0.25)
        self._lines = ax.add_collection(LineCollection([], linewidths=2.0, zorder=2))
        self._agvs = ax.scatter([0] * len(goals), [0] * len(goals), s=(72 * 0.6 * CELL_INCHES) ** 2, c=self._colour,
                                zorder=3, edgecolors="black", linewidths=0.8)
        self._labels = [ax.text(0, 0, str(k + 1), ha="center", va="center", fontsize=7, color="white", zorder=4,
                                fontweight="bold") for k in range(len(goals))]
        self._heading = fig.suptitle("", fontsize=9)
        self._moving = [self._lines, self._agvs, *self._labels, self._heading] if blit else []
        for artist in self._moving:
            artist.set_animated(True)  # left out of a whole draw: that draw is the background
        self._background = None

    def show(self, frame: Frame) -> None:
        xy = [(col + 0.5, -(row + 0.5)) for row, col in frame.cells]
        self._agvs.set_offsets(xy)
        for label, (x, y) in zip(self._labels, xy):
            label.set_position((x, y))
        looks = sorted(frame.looks.items())
        self._lines.set_segments([(xy[k - 1], (col + 0.5, -(row + 0.5))) for k, peers in looks
                                  for _, row, col in peers])
        self._lines.set_color([self._colour[k - 1] for k, peers in looks for _ in peers])
        self._heading.set_text(f"{self._title}  episode {frame.episode}, step {frame.step}".strip())

    def rgb(self) -> np.ndarray:
        canvas = self._canvas
        if not self._moving:
            canvas.draw()
        else:
            if self._background is None:
                canvas.draw()
                self._background = canvas.copy_from_bbox(self.figure.bbox)
            canvas.restore_region(self._background)
            for artist in self._moving:
                self.figure.draw_artist(artist)
        return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def write_animation(path: str | os.PathLike, occupancy: tuple[tuple[bool, ...], ...],
                    goals: tuple[tuple[int, int], ...], frames: list[Frame], *, title: str = "",
                    fps: float = 4.0, dpi: float = DPI, progress: Callable[[int], Any] | None = None) -> Path:
    """Write `frames` as an animation to `path` (.gif with Pillow, .mp4 with ffmpeg), drawn by a `Picture`;
    ValueError for another suffix, an empty episode or a missing ffmpeg. `progress(i)` is called after frame i
    is drawn."""
    from matplotlib import animation

    path = Path(path)
    writer_name = check_output(path)
    if not frames:
        raise ValueError("no frames to draw: the episode is empty")
    if writer_name == "pillow":
        return _write_gif(path, Picture(occupancy, goals, title=title, dpi=dpi), frames, fps, progress)
    picture = Picture(occupancy, goals, title=title, dpi=dpi, blit=False)
    writer = animation.writers[writer_name](fps=fps)
    with writer.saving(picture.figure, str(path), dpi=dpi):
        for i, frame in enumerate(frames):
            picture.show(frame)
            writer.grab_frame()
            if progress is not None:
                progress(i)
    return path


def _write_gif(path: Path, picture: Picture, frames: list[Frame], fps: float,
               progress: Callable[[int], Any] | None) -> Path:
    """The frames as a looping GIF, every frame in the first frame's palette. Left to Pillow, each frame got a
    palette of its own (quantized anew for every frame: half of a render's time); the first frame already holds every
    colour of the picture (the map, each AGV's colour, its goal's tint), so later ones only map onto it."""
    from PIL import Image

    images = []
    for i, frame in enumerate(frames):
        picture.show(frame)
        image = Image.fromarray(picture.rgb())
        # the octree keeps the picture's flat colours exact (a median cut turned its white into 252)
        images.append(image.quantize(256, Image.Quantize.FASTOCTREE) if not images
                      else image.quantize(palette=images[0], dither=Image.Dither.NONE))
        if progress is not None:
            progress(i)
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    return path

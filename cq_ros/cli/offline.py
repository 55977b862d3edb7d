"""The offline commands of `cq-ros`: the maps, the settings, generated and imported maps, experiments, the
paper's reproduction and episode animations; each reads its parsed arguments (offline_parser.py builds the parsers).
"""

from __future__ import annotations

import shlex
import sys
import textwrap
import time
from pathlib import Path

from ..gridmap import available_maps, load_map, parse_map
from ..lab.output import check_parent, removed_if_failing
from ..lab.results import MANIFEST
from ..mapgen.warehouse import warehouse_text
from ..settings import Settings, run_settings


def maps(args) -> int:
    names = available_maps()
    width = max(len(name) for name in names)
    print(f"{'map':<{width}} {'cells':>5} {'agents':>6}")
    for name in names:
        m = load_map(name)
        print(f"{name:<{width}} {m.n_cells:>5} {m.n_agents:>6}")
    return 0


def show(args) -> int:
    m = load_map(args.map)
    print(f"{m.name}: {m.n_cells} cells, {m.n_agents} agents (digits: starts, G: goals)")
    print(m.draw())
    if m.defaults:
        print("map defaults: " + ", ".join(f"{k}={v:g}" for k, v in m.defaults.items()))
    pairs = m.walled_in()
    print("walled in by an early arrival (agent: by the agent parked at its goal): "
          + ("; ".join(f"{i + 1}: by {k + 1} at {'%d,%d' % m.cells[m.goals[k]]}" for i, k in pairs) or "none"))
    return 0


def settings(args) -> int:
    for key, value in Settings().as_dict().items():
        print(f"{key} = {value}")
        print(textwrap.fill(Settings.describe(key), width=100, initial_indent="    ", subsequent_indent="    "))
    return 0


def experiment(args) -> int:
    from ..lab.experiment import experiment

    # The map is read first: a bad map fails before any work starts, and its defaults join the settings.
    settings = run_settings(load_map(args.map), args.overrides)
    # A run cut short before any finished leaves no folder; the runs finished when Ctrl-C came are kept.
    with removed_if_failing(args.out, unless=lambda: (args.out / MANIFEST).exists()):
        out = experiment(args.map, args.algo, args.runs, args.episodes, args.seed, args.out, settings,
                         workers=args.jobs, force=args.force, figures=False, cluster=args.cluster,
                         engine=args.engine)
    if args.figures:  # after the results, which no figure can cost
        from ..lab.plots import write_figures

        write_figures(out)
    print_summary(out)
    print(f"results: {out}")
    return 0


def reproduce(args) -> int:
    from ..lab.reproduce import reproduce

    # The paper's maps carry no defaults of their own.
    report = reproduce(args.out, args.runs, args.episodes, args.seeds or args.seed,
                       run_settings(None, args.overrides), workers=args.jobs, force=args.force,
                       sweep=args.sweep, cluster=args.cluster, engine=args.engine,
                       command=shlex.join(["cq-ros", *args.argv]))
    print(f"report: {report}")
    return 0


def print_summary(out: Path) -> None:
    """The table of a result directory's episodes and the greedy policy's line per algorithm (experiment and
    launch alike)."""
    from ..lab.results import EPISODES, GREEDY, load_episodes
    from ..lab.summary import format_console_table, greedy_lines

    print(format_console_table(load_episodes(out / EPISODES)))
    for line in greedy_lines(out / GREEDY):
        print(line)


def generate(args) -> int:
    if args.kind == "shelves":
        from ..mapgen.shelves import shelves_files

        stem = args.out.with_suffix("") if args.out.suffix in (".map", ".scen") else args.out
        outs = [stem.with_name(f"{stem.name}.map"), stem.with_name(f"{stem.name}.scen")]
        for out in outs:
            _check_writable(out, args.force)  # both, before either is written
        texts = shelves_files(args.agents, args.shelf_rows, args.shelf_cols, args.seed, stem.name)
        for text, out in zip(texts, outs):
            _write_map(text, out, args.force)
        return 0
    _write_map(warehouse_text(args.agents, args.aisles, args.aisle_length, args.seed, args.slip, args.start_hold,
                              args.blocks), args.out, args.force)
    return 0


def import_(args) -> int:
    from ..mapgen.movingai import map_text, read_map, read_scenario

    if (args.scen is None) != (args.agents is None):
        raise ValueError("--scen and --agents go together: the scenario and how many of its tasks to take")
    if args.out is not None:
        _check_writable(args.out, args.force)  # before the work: a large map takes seconds to read
    gridmap = read_map(args.map)
    tasks = read_scenario(args.scen, gridmap, args.agents) if args.scen is not None else []
    command = " ".join(["cq-ros", "import", "movingai", args.map.name]
                       + ([f"--scen {args.scen.name} --agents {args.agents}"] if tasks else []))
    text = map_text(gridmap, tasks, command, args.scen)
    if not tasks:
        print("cq-ros import: the map has no agents yet: add lines `agent K: start ROW,COL  goal ROW,COL`, or "
              "give --scen FILE --agents N", file=sys.stderr)
    else:
        parse_map(text, source=str(args.out or "<import>"))  # our own loader accepts what we write
    _write_map(text, args.out, args.force)
    return 0


def _check_writable(out: Path, force: bool) -> None:
    if out.exists() and not out.is_file():
        raise FileExistsError(f"{out} is not a file")
    if out.exists() and not force:
        raise FileExistsError(f"{out} exists; pass --force to overwrite it")


def _write_map(text: str, out: Path | None, force: bool) -> None:
    """`text` on stdout (out None) or into file `out`, which must be new unless `force`."""
    if out is None:
        sys.stdout.write(text)
        return
    _check_writable(out, force)
    try:
        out.write_text(text, encoding="utf-8")
    except OSError as e:
        raise ValueError(f"cannot write {out}: {e.strerror or e}") from None
    print(f"wrote {out}", file=sys.stderr)


def render(args) -> int:
    from ..gridmap import lattice
    from ..lab.render import (
        DPI,
        check_output,
        cut_by_bag,
        engine_frames,
        episode_to_draw,
        frames_from,
        write_animation,
    )

    check_output(args.out)
    check_parent(args.out, "--out")
    cut = None
    engine_only = [flag for flag, given in (
        ("--set", bool(args.overrides)), ("--greedy", args.greedy), ("--algo", args.algo is not None),
        ("--episodes", args.episodes is not None), ("--seed", args.seed is not None)) if given]
    if args.map is not None:
        args.algo = "cq" if args.algo is None else args.algo
        args.episodes = 100 if args.episodes is None else args.episodes
        args.seed = 0 if args.seed is None else args.seed
        gridmap = load_map(args.map)
        settings = run_settings(gridmap, args.overrides)
        occupancy, goals = lattice(gridmap), tuple(gridmap.cells[g] for g in gridmap.goals)
        title = f"{gridmap.name} {args.algo}"
        if args.greedy and args.episode is not None:
            raise ValueError("draw either a learning episode (--episode) or the greedy one after learning "
                             "(--greedy), not both")
        if args.episode is not None and args.episode >= args.episodes:
            raise ValueError(f"episode {args.episode} is not one of the {args.episodes} episodes "
                             f"(0..{args.episodes - 1})")
        _note(f"learning {args.episodes} episodes of {title} offline (seed {args.seed})")
        if args.greedy:
            title += " greedy"
        frames = engine_frames(gridmap, args.algo, settings, args.seed, args.episodes, args.episode,
                               _every_30_s("episode {} learnt"), greedy=args.greedy, engine=args.engine)
    else:
        from ros_tools import commands as tools

        if engine_only:
            raise ValueError(f"{engine_only[0]} applies to --map (the offline engine), not to a bag")
        def chosen(scenes: list) -> int:
            return episode_to_draw(scenes) if args.episode is None else args.episode

        try:
            occupancy, scenes, looks = tools.read_view_bag(args.bag, episode_of=chosen)
        except tools.ToolError as e:
            print(f"cq-ros render: error: {e}", file=sys.stderr)
            return 1
        if occupancy is None or not scenes:
            print(f"cq-ros render: error: {args.bag} holds no {'world/map' if occupancy is None else 'world/markers'}"
                  " message (record while the run starts, with markers on)", file=sys.stderr)
            return 1
        episodes = sorted({s.episode for s in scenes})
        episode = chosen(scenes)
        if episode not in episodes:
            whole = [e for e in episodes if cut_by_bag(scenes, e) is None]
            held = f"{whole[0]}..{whole[-1]}" if len(whole) > 1 else "".join(map(str, whole)) or "none"
            raise ValueError(f"episode {episode} is not in {args.bag}: it holds episodes {episodes[0]}..{episodes[-1]}"
                             f", whole: {held}")
        frames = frames_from([s for s in scenes if s.episode == episode], looks)
        occupancy, goals, title = occupancy.lattice, scenes[0].goals, args.bag.name
        cut = cut_by_bag(scenes, episode)
        if cut:
            _note(f"episode {episode} is cut by the bag: {cut}")
    _note(f"drawing {len(frames)} steps to {args.out}")
    out = write_animation(args.out, occupancy, goals, frames, title=title, fps=args.fps, dpi=args.dpi or DPI,
                          progress=_every_30_s(f"frame {{}}/{len(frames)} drawn"))
    cut_note = " (cut by the bag)" if args.bag and cut else ""
    print(f"{out}: episode {frames[0].episode}, {len(frames)} frames{cut_note}")
    return 0


def _every_30_s(line: str):
    """A progress callback for render's long loops: `line` (with the 1-based count) at most every 30 s."""
    shown = time.monotonic()

    def progress(i: int) -> None:
        nonlocal shown
        if time.monotonic() - shown >= 30:
            shown = time.monotonic()
            _note(line.format(i + 1))

    return progress


def _note(line: str) -> None:
    print(f"cq-ros render: {line}", file=sys.stderr, flush=True)


def study(args) -> int:
    from ..lab.held_out import study
    from ..lab.held_out_protocol import parse_configs

    configs = parse_configs(args.algos, args.variant)
    for agents in args.agents:  # a bad setting fails before any work starts
        for c in configs:
            run_settings(parse_map(warehouse_text(agents, slip=args.slip)), [*args.overrides, *c.sets])
    # Not removed if failing: the units played so far are kept, for a rerun to resume.
    print(study(args.out, args.agents, args.maps, args.runs, args.episodes, args.greedy_episodes, configs,
                args.seed, args.slip, args.overrides, args.jobs, args.cluster, args.force,
                shlex.join(["cq-ros", *args.argv]), args.curve_every, args.curve_episodes, args.tuning), end="")
    print(f"results: {args.out}", file=sys.stderr)
    return 0


COMMANDS = {"maps": maps, "show": show, "settings": settings, "generate": generate, "import": import_,
            "experiment": experiment, "reproduce": reproduce, "render": render, "study": study}

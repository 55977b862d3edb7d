"""`cq-ros reproduce`: the paper's grid (its four maps x five algorithms), its figures, the same grid with
exploration that stops, a settings sweep, and our CQ (`cq`) beside the paper's (`cq_paper`, the grid's) on the
four maps, and REPORT.md, in which every claim of the paper's section 4 is checked against the
numbers measured.

The verdicts are computed, not written: a claim that does not reproduce says so, with its figure. So is
the report's "In short" section, which docs/choices.md quotes word for word (tests/test_docs.py checks it).

When a 100-episode average settles below a threshold (claims 1 and 2, "collision-free from") moves with the
seed by thousands of episodes, so the report quotes it only as a range over at least MIN_SEEDS master seeds
(`--seeds`); with fewer it says so instead. Everything else is the first seed's (the sweep runs on it alone).
"""

from __future__ import annotations

import shlex
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

from .experiment import Job, keep_interrupted, run_jobs
from ..gridmap import load_map
from ..learners import ALGORITHMS
from ..settings import Settings
from .results import (EPISODES, GREEDY, OBSERVE, GreedyRun, load_episodes, load_greedy, load_observations,
                      engines_of, manifest_for, prepare_output, versions, write_results)
from .summary import Metrics, compute_metrics, settled_episode, summary_table

PAPER_MAPS = ("grid_game_2", "tunnel_to_goal", "tunnel_to_goal_3", "isr")
SWEEP_MAP = "tunnel_to_goal_3"
SETTLED = 0.05  # collisions per episode, moving average over 100 episodes
# What a reader of Fig. 3 could call collision-free: the 100-episode average below each of these.
THRESHOLDS = (0.05, 0.1)
# With exploration gone, a greedy policy that misses its goal loops until the step cap: 500 steps (for
# every algorithm alike) keeps such runs to seconds; those episodes count as truncated.
DECAY_STEP_CAP = 500
IN_SHORT = "## In short"
CQ = "cq_paper"  # the CQ of the paper's grid, whose claims are checked
OURS, OURS_DIR = "cq", "ours"  # our CQ beside it on the four maps, first seed, fixed exploration
MIN_SEEDS = 3  # a crossing episode is quoted only as a range over at least this many seeds


@dataclass(frozen=True)
class Variant:
    name: str
    why: str
    changes: dict


def sweep_variants(base: Settings) -> list[Variant]:
    """The settings the paper leaves open, each moved on its own from our defaults."""
    scaled = {k: getattr(base, k) * 0.1 for k in ("reward_step", "reward_wall", "reward_collision", "reward_goal")}
    return [
        Variant("defaults", "our defaults", {}),
        Variant("rewards_x0.1", "every reward scaled by 0.1", scaled),
        Variant("collision_-2", "a milder collision penalty (-2 instead of -10)", {"reward_collision": -2.0}),
        Variant("step_-1", "a cost of -1 per step", {"reward_step": -1.0}),
        Variant("significance_0.01", "stricter t-tests", {"significance": 0.01}),
        Variant("significance_0.10", "looser t-tests", {"significance": 0.10}),
        Variant("gamma_0.95", "a longer horizon", {"gamma": 0.95}),
        Variant("confidence_fading", "joint states fade fast (conf_up 0.1, conf_max 1)",
                {"conf_up": 0.1, "conf_max": 1.0}),
    ]


def decaying(settings: Settings, episodes: int) -> Settings:
    """Exploration that stops: epsilon falls linearly to 0 over the first half of the episodes."""
    return settings.with_overrides({"epsilon_decay_episodes": max(1, episodes // 2),
                                    "step_cap": min(settings.step_cap, DECAY_STEP_CAP)})


def seed_dir(out: Path, seeds: Sequence[int], seed: int) -> Path:
    """Where a seed's grid goes: the first seed's in `out` itself, the others' in out/seed_<seed>."""
    return out if seed == seeds[0] else out / f"seed_{seed}"


def reproduce(out: Path, runs: int = 10, episodes: int = 10_000, seed: int | Sequence[int] = 0,
              settings: Settings = Settings(), workers: int | None = None, force: bool = False, sweep: bool = True,
              figures: bool = True, cluster: str | None = None, command: str | None = None,
              engine: str = "compiled") -> Path:
    """Run the grid, again with exploration that stops (in decay/), for each master seed in `seed` (one or
    several), and the sweep (first seed), on `workers` local processes or on the Dask scheduler at `cluster`;
    write every map's results and figures (first seed) and REPORT.md; returns its path. REPORT.md names
    `command` as the command that made it (the CLI gives its own; default: this call as a `cq-ros reproduce`)."""
    seeds = (seed,) if isinstance(seed, int) else tuple(dict.fromkeys(seed))
    out = prepare_output(out, force)
    started = time.perf_counter()
    decay = decaying(settings, episodes)
    grids = {".": settings, "decay": decay}
    jobs = [Job(m, a, r, episodes, sd, s, engine) for sd in seeds for s in grids.values() for m in PAPER_MAPS
            for a in ALGORITHMS for r in range(runs)]
    variants = sweep_variants(settings) if sweep else []
    for v in variants:
        jobs += [Job(SWEEP_MAP, CQ, r, episodes, seeds[0], settings.with_overrides(v.changes), engine)
                 for r in range(runs)]
    jobs += [Job(m, OURS, r, episodes, seeds[0], settings, engine) for m in PAPER_MAPS for r in range(runs)]
    jobs = list(dict.fromkeys(jobs))  # the "defaults" variant is the grid's own CQ runs on the sweep map
    done: dict = {}

    def write(results: dict, executed_on: dict | None, **extra) -> None:
        _write_grid(out, results, jobs, seeds, grids, variants, runs, episodes, settings,
                    time.perf_counter() - started, executed_on, extra)

    try:
        results, executed_on = run_jobs(jobs, workers, label="reproduce", cluster=cluster, done=done)
    except KeyboardInterrupt:
        keep_interrupted(out, jobs, done, lambda missing: write(done, None, interrupted=missing))
        raise
    write(results, executed_on)
    if figures:
        from .plots import write_figures

        for where in grids:
            for m in PAPER_MAPS:
                write_figures(out / where / m)
    report = out / "REPORT.md"
    command = command or as_command(out, runs, episodes, seeds, settings, sweep, workers, cluster)
    report.write_text(render_report(out, runs, episodes, seeds, settings, variants, time.perf_counter() - started,
                                    executed_on, command))
    return report


def _write_grid(out: Path, results: dict, jobs: list, seeds: Sequence[int], grids: dict, variants: list,
                runs: int, episodes: int, settings: Settings, wall: float, executed_on: dict | None,
                extra: dict) -> None:
    """Every folder of the grid with the results it has (after Ctrl-C, those of the runs that finished: a folder
    none of whose runs did is not made); `extra` joins each manifest."""
    def put(folder: Path, map_name: str, algos, seed: int, grid_settings: Settings, **more) -> None:
        mine = [results[j] for j in jobs if j in results and (j.map_name, j.seed, j.settings) == (map_name, seed,
                                                                                                   grid_settings)
                and j.algo in algos]
        if mine:
            folder.mkdir(parents=True, exist_ok=True)
            gridmap = load_map(map_name)
            write_results(folder, gridmap, mine, manifest_for(gridmap, algos, runs, episodes, seed, grid_settings,
                                                              wall, executed_on, engine=engines_of(mine), **more,
                                                              **extra))

    for sd in seeds:
        for where, grid_settings in grids.items():
            for m in PAPER_MAPS:
                put(seed_dir(out, seeds, sd) / where / m, m, ALGORITHMS, sd, grid_settings)
    for v in variants:
        put(out / "sweep" / v.name, SWEEP_MAP, [CQ], seeds[0], settings.with_overrides(v.changes), variant=v.name)
    for m in PAPER_MAPS:
        put(out / OURS_DIR / m, m, [OURS], seeds[0], settings)


# --- the report ------------------------------------------------------------------------------------------


def exploration(settings: Settings) -> str:
    if settings.epsilon_decay_episodes:
        return f"epsilon falling to 0 by episode {settings.epsilon_decay_episodes}"
    return f"epsilon {settings.epsilon:g} fixed" + (" (the paper's)" if settings.epsilon == 0.1 else "")


def _grid_data(where: Path):
    data = {}
    for m in PAPER_MAPS:
        data.update(load_episodes(where / m / EPISODES))
    return data


def as_command(out: Path, runs: int, episodes: int, seeds: Sequence[int], settings: Settings, sweep: bool,
               workers: int | None, cluster: str | None) -> str:
    """The `cq-ros reproduce` command line that runs what a call of `reproduce` with these arguments runs."""
    seeding = f"--seed {seeds[0]}" if len(seeds) == 1 else "--seeds " + ",".join(map(str, seeds))
    base = Settings().as_dict()
    words = ["cq-ros", "reproduce", "--out", str(out), "--runs", str(runs), "--episodes", str(episodes),
             *seeding.split(), *([] if sweep else ["--no-sweep"]),
             *(["--jobs", str(workers)] if workers else []), *(["--cluster", cluster] if cluster else [])]
    for k, v in settings.as_dict().items():
        if base[k] != v:
            words += ["--set", f"{k}={v}"]
    return shlex.join(words)


def render_report(out: Path, runs: int, episodes: int, seeds: Sequence[int], settings: Settings,
                  variants: list[Variant], wall: float, executed_on: dict | None, command: str) -> str:
    seeds = tuple(seeds)
    data = _grid_data(out)
    decay = decaying(settings, episodes)
    # Each regime's grid, one per seed, the first seed's first.
    regimes = {name: [_grid_data(seed_dir(out, seeds, sd) / where) for sd in seeds]
               for name, where in ((exploration(settings), "."), (exploration(decay), "decay"))}
    metrics = {(x.map, x.algo): x for x in compute_metrics(data)}
    v = versions()
    lines = [
        "# CQ-learning: reproduction of the paper's experiments",
        "",
        f"Command: `{command}`"
        + (f" with settings changed from the defaults: {_changes(settings)}" if _changes(settings) else ""),
        f"Wall time: {wall:.0f} s on {_where(executed_on, v)} ({v['machine']}, Python {v['python']}, "
        f"cq_ros {v['cq_ros']}). Every parameter and seed is in each map's `manifest.json`. The greedy episodes "
        + ("go on learning" if settings.eval_learning else "are played frozen")
        + f" (eval_learning={settings.eval_learning}).",
        "",
        "Collisions are counted per episode as colliding pairs; \"collision-free from\" is the first episode after "
        f"which the 100-episode moving average of the mean over runs stays below {SETTLED} for good (claims 1 and "
        f"2 also at {', '.join(f'{t:g}' for t in THRESHOLDS if t != SETTLED)}). That episode moves with the seed, so "
        f"it is quoted only as a range over at least {MIN_SEEDS} master seeds: "
        + (f"here {_seed_list(seeds)}." if len(seeds) >= MIN_SEEDS else
           f"this report has {len(seeds)} ({_seed_list(seeds)}), so it is not quoted and claims 1 and 2 are not "
           f"judged (`--seeds`, e.g. `--seeds 0,1,2`).")
        + f" Everything else is seed {seeds[0]}'s. Exploration: {exploration(settings)}, "
        "so an exploratory move can still collide; the same grid is run again with exploration that stops "
        f"({exploration(decay)}, linearly; step cap {decay.step_cap}), in `decay/`.",
        "",
        IN_SHORT,
        "",
        *in_short(out, data, regimes, seeds, variants),
        "",
        "## Results",
        "",
        summary_table(data, settled=False),
    ]
    if len(seeds) >= MIN_SEEDS:
        lines += [f"## Collision-free from, over {_seed_list(seeds)}", "", *_settled_table(regimes, seeds), ""]
    lines += [
        "## The paper's claims, measured",
        "",
        *_claims(out, data, metrics, regimes, seeds),
        "",
        "## Figures",
        "",
    ]
    for where in (".", "decay"):
        for m in PAPER_MAPS:
            figures = sorted(p.name for p in (out / where / m).glob("*.png"))
            path = m if where == "." else f"{where}/{m}"
            lines.append(f"- {path}: " + (", ".join(f"[{f}]({path}/{f})" for f in figures) or "(not drawn)"))
    decay_name, decay_data = list(regimes.items())[1]
    lines += ["", f"## With exploration that stops ({decay_name})", "", summary_table(decay_data[0], settled=False)]
    lines += ["", *_papers_cq_section(out, data, seeds)]
    if variants:
        lines += ["", *_sweep_section(out, variants)]
    return "\n".join(lines) + "\n"


# --- when the averages settle, over seeds ------------------------------------------------------------------


def _seed_list(seeds: Sequence[int]) -> str:
    return ("seed " if len(seeds) == 1 else "seeds ") + ", ".join(map(str, seeds))


def over_seeds(episodes: Sequence[int | None], seeds: Sequence[int]) -> str:
    """The episodes at which an average settles, one per seed (None: never), as one range: "episodes 141-233",
    "never", or "episodes 141-233 (never at seed 2)"."""
    never = [sd for sd, e in zip(seeds, episodes) if e is None]
    return _span(episodes) + (f" (never at {_seed_list(never)})" if never and len(never) < len(seeds) else "")


def _span(episodes: Sequence[int | None]) -> str:
    got = [e for e in episodes if e is not None]
    if not got:
        return "never"
    lo, hi = min(got), max(got)
    return f"episode {lo}" if lo == hi else f"episodes {lo}-{hi}"


def _at_seeds(ok: Sequence[bool]) -> str:
    """A verdict over seeds: it holds only if it holds at every seed."""
    return _verdict(all(ok)) + ("" if all(ok) or not any(ok) else f" (holds at {sum(ok)} of {len(ok)} seeds)")


def _settled_table(regimes: dict, seeds: Sequence[int]) -> list[str]:
    heads = [f"{name}, below {t:g}" for name in regimes for t in THRESHOLDS]
    settled = [[settled_at(d, t) for d in per_seed] for per_seed in regimes.values() for t in THRESHOLDS]
    lines = ["| map | algo | " + " | ".join(heads) + " |", "| --- | --- | " + " | ".join("---:" for _ in heads) + " |"]
    for m in PAPER_MAPS:
        for a in ALGORITHMS:
            lines.append(f"| {m} | {a} | " + " | ".join(over_seeds([s[(m, a)] for s in col], seeds) for col in settled)
                         + " |")
    return lines


def settled_at(data, threshold: float) -> dict[tuple[str, str], int | None]:
    """(map, algo) -> the episode from which its 100-episode average stays below `threshold`, or None."""
    return {key: settled_episode(runs["collisions"], threshold=threshold) for key, runs in data.items()}


def claim_collision_free(settled: dict[tuple[str, str], int | None]) -> bool:
    """Claim 1: CQ's average settles on every paper map."""
    return all(settled[(m, CQ)] is not None for m in PAPER_MAPS)


def sooner_than_cq(settled: dict[tuple[str, str], int | None]) -> list[tuple[str, str, int, int | None]]:
    """Claim 2 fails for each (algo, map, its episode, CQ's) where a baseline settles before CQ does."""
    return [(algo, m, settled[(m, algo)], settled[(m, CQ)]) for m in PAPER_MAPS for algo in ALGORITHMS
            if algo != CQ and settled[(m, algo)] is not None
            and (settled[(m, CQ)] is None or settled[(m, algo)] < settled[(m, CQ)])]


def _changes(settings: Settings) -> str:
    base = Settings().as_dict()
    return ", ".join(f"{k}={v}" for k, v in settings.as_dict().items() if base[k] != v)


def _verdict(ok: bool) -> str:
    return "**holds**" if ok else "**does not hold**"


def _claims(out: Path, data, metrics: dict[tuple[str, str], Metrics], regimes: dict, seeds: Sequence[int]) -> list[str]:
    lines = []
    cq = {m: metrics[(m, CQ)] for m in PAPER_MAPS}
    # per (regime, threshold): one {(map, algo): episode} per seed
    settled = {(name, t): [settled_at(d, t) for d in per_seed]
               for name, per_seed in regimes.items() for t in THRESHOLDS}
    few = len(seeds) < MIN_SEEDS
    not_judged = (f"not judged: when an average settles moves with the seed, and this report has {len(seeds)} of "
                  f"the {MIN_SEEDS} seeds it takes (`--seeds`).")

    lines.append("1. *CQ-learning ends collision-free on all four maps* (its 100-episode average settles below the "
                 "threshold). Last 10% of episodes at fixed epsilon: "
                 + "; ".join(f"{m} {x.collisions_tail:.3f} collisions/episode" for m, x in cq.items()) + ".")
    for (name, t), per_seed in settled.items():
        lines.append(f"   - {name}, below {t:g}: " + (not_judged if few else
                     f"{_at_seeds([claim_collision_free(s) for s in per_seed])}. CQ from, over {_seed_list(seeds)}: "
                     + "; ".join(f"{m} {over_seeds([s[(m, CQ)] for s in per_seed], seeds)}"
                                 for m in PAPER_MAPS) + "."))
    greedy = {m: _greedy(out / m) for m in PAPER_MAPS}
    if all(CQ in g for g in greedy.values()):
        ok = all(g[CQ].collisions == 0 and g[CQ].stuck == 0 for g in greedy.values())
        lines.append("   - The policy CQ has learnt, played greedily (epsilon 0) at the end, collision-free and "
                     f"reaching the goals: {_verdict(ok)}. Collisions/episode (steps/episode, runs stuck until the "
                     "step cap), mean over runs: " + "; ".join(f"{m} {_g(g[CQ])}" for m, g in greedy.items())
                     + ". The other algorithms, greedy: "
                     + "; ".join(f"{m}: " + ", ".join(f"{a} {_g(v)}" for a, v in g.items() if a != CQ)
                                 for m, g in greedy.items()) + ".")

    lines.append("2. *CQ reaches that sooner than every baseline* (on every map, no baseline settles before CQ).")
    for (name, t), per_seed in settled.items():
        if few:
            lines.append(f"   - {name}, below {t:g}: {not_judged}")
            continue
        rows = [sooner_than_cq(s) for s in per_seed]
        sooner: dict[tuple[str, str], list[int]] = {}
        for sd, found in zip(seeds, rows):
            for a, m, _, _ in found:
                sooner.setdefault((a, m), []).append(sd)
        lines.append(f"   - {name}, below {t:g}: {_at_seeds([not r for r in rows])}."
                     + (" Sooner than CQ: " + "; ".join(f"{a} on {m} (at {_seed_list(sds)})"
                                                       for (a, m), sds in sooner.items()) + "." if sooner else ""))

    indep = {m: metrics[(m, "indep")].collisions_tail for m in PAPER_MAPS}
    others = [m for m in PAPER_MAPS if m != "tunnel_to_goal_3"]
    ok = all(indep[m] > indep["tunnel_to_goal_3"] for m in others) and all(indep[m] >= SETTLED for m in others)
    lines.append(f"3. *Independent learners keep colliding, except on TunnelToGoal_3*: {_verdict(ok)}. "
                 "Indep, last 10%: " + "; ".join(f"{m} {v:.3f}" for m, v in indep.items()) + ".")

    lines.append(_claim_joint_learners_slow(data))

    states = data[("tunnel_to_goal_3", CQ)]["states"] / 2  # two agents: per agent
    n_cells = load_map("tunnel_to_goal_3").n_cells
    peak = float(states.mean(axis=0).max())
    lines.append(f"5. *CQ's state space on TunnelToGoal_3 stays far below {n_cells ** 2}*: "
                 f"{_verdict(peak < 0.1 * n_cells ** 2)}. "
                 f"Per agent, mean over runs: at most {peak:.1f} states (local space {n_cells}), "
                 f"{float(states[:, -1].mean()):.1f} at the end.")

    lines.append(_claim_entrance(out))

    isr = cq["isr"]
    lines.append(f"7. *Where the agents can solve it alone (ISR), CQ (almost) never plays joint*: "
                 f"{_verdict(isr.joint_plays_tail < 1.0)}. CQ on isr: {isr.joint_plays_tail:.2f} joint plays per "
                 f"episode in the last 10% ({isr.joint_plays_all:.2f} over all episodes), against "
                 + "; ".join(f"{m} {cq[m].joint_plays_tail:.2f}" for m in PAPER_MAPS if m != "isr") + ".")
    return lines


# --- "In short": the findings docs/choices.md quotes --------------------------------------------------


def states_in_parts(states: float, n_cells: int) -> str:
    """'57 states (55 local + 2 joint)' for a mean of 56.5 states an agent over a local space of 55: the joint
    part rounded and the total its sum, so that the parts add up (each rounded alone read '56 (55 + 2)')."""
    joint = round(states - n_cells)
    return f"{n_cells + joint} states ({n_cells} local + {joint} joint)"



def in_short(out: Path, data, regimes: dict, seeds: Sequence[int], variants: list[Variant]) -> list[str]:
    """The findings, each sentence computed from the results (docs/choices.md quotes them word for word)."""
    metrics = {(x.map, x.algo): x for x in compute_metrics(data)}
    n_cells = load_map("tunnel_to_goal_3").n_cells
    share, _ = entrance_share(out)
    lines = [f"- **CQ's state space.** On tunnel_to_goal_3 each CQ "
             f"agent ends with {states_in_parts(metrics[('tunnel_to_goal_3', CQ)].final_states / 2, n_cells)}, "
             "against "
             f"{metrics[('tunnel_to_goal_3', 'js')].final_states / 2:,.0f} for each JS agent and "
             f"{metrics[('tunnel_to_goal_3', 'jsa')].final_states:,.0f} for JSA; {share:.0%} of the confidence of "
             "the joint states it keeps lies within two cells of the tunnel entrance (claims 5 and 6)."]
    indep = {m: metrics[(m, "indep")].collisions_tail for m in PAPER_MAPS}
    at = _at_2000(data)
    lines.append("- **Independent learners**, last 10% of episodes: "
                 + ", ".join(f"{m} {v:.2f}" for m, v in indep.items()) + " collisions per episode (claim 3)."
                 + ("" if at is None else " **After 2000 episodes on tunnel_to_goal_3** (episodes 1901-2000) JS "
                    f"collides {at['js'][0]:.3f} times per episode, JSA {at['jsa'][0]:.3f} and CQ {at[CQ][0]:.3f} "
                    f"(in {at['js'][1]:.1f}, {at['jsa'][1]:.1f} and {at[CQ][1]:.1f} steps): claim 4, judged on "
                    f"collisions as Fig. 3 plots them, {'holds' if joint_learners_slow(at) else 'does not hold'}."))
    for name, per_seed in regimes.items():
        lines.append(_regime_finding(name, per_seed, seeds))
    greedy = {m: _greedy_runs(out / m) for m in PAPER_MAPS}
    if all(CQ in g for g in greedy.values()):
        stuck = {m: sum(r.truncated > 0 for r in g[CQ]) for m, g in greedy.items()}
        ending = {m: {a: [r.steps for r in runs if not r.truncated] for a, runs in g.items()}
                  for m, g in greedy.items()}
        shortest = {m: min(((sum(v) / len(v), a) for a, v in e.items() if a != CQ and v), default=None)
                    for m, e in ending.items()}
        worst = {m: max(r.collisions for r in g[CQ]) for m, g in greedy.items()}
        lines.append(
            "- **CQ's learnt policy, played greedily** (epsilon 0) at the end, "
            + ("never collides, in any run on any of the four maps" if not any(worst.values()) else
               "collides at most " + ", ".join(f"{v:.2f} times per episode on {m}" for m, v in worst.items()))
            + "; "
            + (", ".join(f"{n} of its {len(greedy[m][CQ])} runs on {m}" for m, n in stuck.items() if n)
               + " loop until the step cap (exploration breaks such a loop)"
               if any(stuck.values()) else "no run loops until the step cap")
            + ". Over the runs that reach the goals, steps per episode: "
            + "; ".join(f"{m} CQ {sum(e[CQ]) / len(e[CQ]):.1f}"
                        + ("" if shortest[m] is None
                           else f", the shortest baseline {shortest[m][1]} {shortest[m][0]:.1f}")
                        for m, e in ending.items() if e[CQ]) + ".")
    isr = metrics[("isr", CQ)]
    lines.append(f"- **On isr CQ plays joint** {isr.joint_plays_tail:.1f} times per episode in the last 10% "
                 f"(claim 7): in our reconstruction of the map, the agents swap places through a one-lane corridor.")
    if variants:
        sweep = {v.name: compute_metrics(load_episodes(out / "sweep" / v.name / EPISODES))[0] for v in variants}
        (lo, low), (hi, high) = (f(((m.collisions_tail, n) for n, m in sweep.items())) for f in (min, max))
        lines.append(f"- **The settings sweep** (CQ on {SWEEP_MAP}, fixed epsilon, each setting the paper leaves "
                     f"open moved on its own, {_seed_list(seeds[:1])}): CQ collides from {lo:.3f} ({low}) to {hi:.3f} "
                     f"({high}) times per episode in the last 10% of episodes; "
                     + _same_when_scaled(out, variants) + ".")
    return lines


def _regime_finding(name: str, per_seed: list, seeds: Sequence[int]) -> str:
    """One exploration regime: CQ's collisions at the end and, over at least MIN_SEEDS seeds, when the averages
    settle and claims 1 and 2."""
    tails = [m.collisions_tail for d in per_seed for m in compute_metrics(d) if m.algo == CQ]
    text = (f"- **With {name}**, CQ collides {min(tails):.2f}-{max(tails):.2f} times per episode in the last 10% of "
            f"episodes (the four maps, {_seed_list(seeds)})")
    if len(seeds) < MIN_SEEDS:
        return (text + ". When its 100-episode average settles below a threshold moves with the seed, so it is quoted "
                f"only over at least {MIN_SEEDS} seeds (`--seeds`); claims 1 and 2 are not judged here.")
    settled = {t: [settled_at(d, t) for d in per_seed] for t in THRESHOLDS}
    first = settled[THRESHOLDS[0]]
    joint_never = sorted({(m, a) for s in first for m in PAPER_MAPS for a in ("js", "jsa") if s[(m, a)] is None},
                         key=lambda k: (PAPER_MAPS.index(k[0]), k[1]))  # a set's order varies by process
    joint = _span([s[(m, a)] for s in first for m in PAPER_MAPS for a in ("js", "jsa")])
    return (text + ". Its 100-episode average settles "
            + "; ".join(f"below {t:g}: " + ", ".join(f"{m} {over_seeds([s[(m, CQ)] for s in per], seeds)}"
                                                   for m in PAPER_MAPS) for t, per in settled.items())
            + f". JS and JSA settle below {THRESHOLDS[0]:g} "
            + ("on no map at any seed" if joint == "never" else f"at {joint}"
               + (" (never, at one seed or more: " + ", ".join(f"{a} on {m}" for m, a in joint_never) + ")"
                  if joint_never else ""))
            + ". Claim 1 (CQ collision-free on all four maps) "
            + " and ".join(f"{_plain(_at_seeds([claim_collision_free(s) for s in per]))} below {t:g}"
                           for t, per in settled.items())
            + "; claim 2 (CQ there before every baseline) "
            + " and ".join(f"{_plain(_at_seeds([not sooner_than_cq(s) for s in per]))} below {t:g}"
                           for t, per in settled.items()) + ".")


def _plain(verdict: str) -> str:
    return verdict.replace("**", "")


def _same_when_scaled(out: Path, variants: list[Variant]) -> str:
    names = {v.name for v in variants}
    if not {"defaults", "rewards_x0.1"} <= names:
        return "rewards were not scaled"
    a, b = (load_episodes(out / "sweep" / n / EPISODES) for n in ("defaults", "rewards_x0.1"))
    same = all((a[k][c] == b[k][c]).all() for k in a for c in ("steps", "collisions", "joint_plays", "states"))
    return ("scaling every reward by 0.1 gives " + ("the very same episodes" if same else "other episodes")
            + " (the t-tests and greedy choices are scale-invariant)" * same)


def _greedy_runs(result_dir: Path) -> dict[str, list[GreedyRun]]:
    """{algo: its runs' greedy policies at the end}, from greedy.csv."""
    per_algo: dict[str, list[GreedyRun]] = {}
    for g in load_greedy(result_dir / GREEDY):
        per_algo.setdefault(g.algo, []).append(g)
    return per_algo


class _GreedyMean(NamedTuple):
    collisions: float  # per episode, mean over runs
    steps: float  # per episode, mean over runs
    stuck: int  # runs with an episode ended by the step cap


def _greedy(result_dir: Path) -> dict[str, _GreedyMean]:
    """{algo: its final greedy policies, over runs}."""
    return {a: _GreedyMean(sum(g.collisions for g in runs) / len(runs), sum(g.steps for g in runs) / len(runs),
                           sum(g.truncated > 0 for g in runs))
            for a, runs in _greedy_runs(result_dir).items()}


def _g(v: _GreedyMean) -> str:
    return f"{v.collisions:.3f} ({v.steps:.1f}{f', {v.stuck} stuck' if v.stuck else ''})"


def _at_2000(data) -> dict[str, tuple[float, float]] | None:
    """{algo: (collisions, steps) per episode over episodes 1901-2000} on TunnelToGoal_3 for JS, JSA and CQ."""
    if data[("tunnel_to_goal_3", CQ)]["steps"].shape[1] < 2000:
        return None
    late = {algo: data[("tunnel_to_goal_3", algo)] for algo in ("js", "jsa", CQ)}
    return {algo: (float(d["collisions"][:, 1900:2000].mean()), float(d["steps"][:, 1900:2000].mean()))
            for algo, d in late.items()}


def joint_learners_slow(at: dict[str, tuple[float, float]]) -> bool:
    """Claim 4, judged as Fig. 3 plots it: JS and JSA both collide more than CQ in episodes 1901-2000."""
    return all(at[a][0] > at[CQ][0] for a in ("js", "jsa"))


def _claim_joint_learners_slow(data) -> str:
    """JS and JSA "still haven't learnt a good policy after 2000 episodes" on TunnelToGoal_3 (Fig. 3)."""
    at = _at_2000(data)
    if at is None:
        return ("4. *JS and JSA are still poor after 2000 episodes on TunnelToGoal_3*: not measured (fewer than 2000 "
                "episodes).")
    return ("4. *JS and JSA are still poor after 2000 episodes on TunnelToGoal_3*, judged on collisions as Fig. 3 "
            f"plots them (poor = more collisions than CQ): {_verdict(joint_learners_slow(at))}. Episodes 1901-2000, "
            "collisions per episode (steps per episode beside): "
            + "; ".join(f"{a} {c:.3f} ({s:.1f} steps)" for a, (c, s) in at.items()) + ".")


def _claim_entrance(out: Path) -> str:
    """Where CQ's agents keep joint states on TunnelToGoal_3, by summed confidence."""
    share, top = entrance_share(out)
    return (f"6. *CQ's joint states lie around the tunnel entrance*: {_verdict(share >= 0.5)}. "
            f"{share:.0%} of the confidence of the joint states kept at the end lies within 2 cells of the "
            f"entrance; the cells with most: " + ", ".join(f"{rc} ({w:.1f})" for rc, w in top) + ".")


def entrance_share(out: Path) -> tuple[float, list[tuple[tuple[int, int], float]]]:
    """The share of the confidence of CQ's joint states kept on TunnelToGoal_3 that lies within 2 cells of the
    tunnel entrance, and the five cells with most."""
    gridmap = load_map("tunnel_to_goal_3")
    kept = [o for o in load_observations(out / "tunnel_to_goal_3" / OBSERVE) if o.algo == CQ]
    weight: dict[tuple[int, int], float] = {}
    for o in kept:
        weight[(o.row, o.col)] = weight.get((o.row, o.col), 0.0) + o.confidence
    goal = gridmap.cells[gridmap.goals[0]]
    total = sum(weight.values())
    # The tunnel entrance: within 2 cells of the tunnel's open end, i.e. the goal's row, past its walls.
    near = sum(w for (r, c), w in weight.items() if _near_entrance(gridmap, (r, c), goal))
    top = sorted(weight.items(), key=lambda kv: -kv[1])[:5]
    return (near / total if total else 0.0), top


def _near_entrance(gridmap, cell: tuple[int, int], goal: tuple[int, int]) -> bool:
    """Within 2 cells (Manhattan) of the tunnel mouth: the first cell of the goal's row that has open
    cells above or below it."""
    row = goal[0]
    mouth = next(c for c in range(goal[1], gridmap.width)
                 if gridmap.neighbours[gridmap.index(row, c)][0] != gridmap.index(row, c)
                 or gridmap.neighbours[gridmap.index(row, c)][2] != gridmap.index(row, c))
    return abs(cell[0] - row) + abs(cell[1] - mouth) <= 2


def _sweep_section(out: Path, variants: list[Variant]) -> list[str]:
    lines = [f"## Sweep: CQ on {SWEEP_MAP} under the settings the paper leaves open", "",
             "| variant | change | collisions/ep (last 10%) | final states | joint plays/ep (last 10%) |",
             "|---|---|---:|---:|---:|"]
    for v in variants:
        (m,) = compute_metrics(load_episodes(out / "sweep" / v.name / EPISODES))
        lines.append(f"| {v.name} | {v.why} | {m.collisions_tail:.3f} ± {m.collisions_tail_std:.3f} | "
                     f"{m.final_states:.1f} | {m.joint_plays_tail:.2f} |")
    return lines


def _papers_cq_section(out: Path, data, seeds: Sequence[int]) -> list[str]:
    """Ours against the paper's CQ on the four maps, the first seed, fixed exploration."""
    theirs_of = {x.map: x for x in compute_metrics(data) if x.algo == CQ}
    lines = [f"## The paper's CQ beside ours ({_seed_list(seeds[:1])}, {exploration(Settings())})", "",
             f"`{OURS}` (our rules, docs/choices.md) / `{CQ}` (Algorithm 2 as the paper reads):", "",
             "| map | collisions/ep (last 10%) | final states | joint plays/ep (last 10%) | greedy collisions/ep "
             "(steps/ep) |", "|---|---:|---:|---:|---:|"]
    for m in PAPER_MAPS:
        (ours,) = compute_metrics(load_episodes(out / OURS_DIR / m / EPISODES))
        theirs = theirs_of[m]
        greedy = (_greedy(out / OURS_DIR / m).get(OURS), _greedy(out / m).get(CQ))
        lines.append(f"| {m} | {ours.collisions_tail:.3f} / {theirs.collisions_tail:.3f} "
                     f"| {ours.final_states:.1f} / {theirs.final_states:.1f} "
                     f"| {ours.joint_plays_tail:.2f} / {theirs.joint_plays_tail:.2f} | "
                     + (" / ".join(_g(g) for g in greedy) if all(greedy) else "not played") + " |")
    return lines


def _where(executed_on: dict | None, v: dict) -> str:
    if executed_on and executed_on.get("where") == "dask":
        return f"the Dask cluster at {executed_on['scheduler']} ({len(executed_on['workers'])} workers)"
    return f"{v['cores']} cores"

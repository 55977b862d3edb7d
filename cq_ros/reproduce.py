"""`cq-ros reproduce`: the paper's grid (its four maps x five algorithms), its figures, the same grid with
exploration that stops, a settings sweep and REPORT.md, in which every claim of the paper's section 4 is
checked against the numbers measured.

The verdicts are computed, not written: a claim that does not reproduce says so, with its figure. So is
the report's "In short" section, which docs/choices.md quotes word for word (tests/test_docs.py checks it).
"""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass
from pathlib import Path

from .experiment import Job, manifest_for, prepare_output, run_jobs, versions, write_results
from .gridmap import load_map
from .learners import ALGORITHMS
from .settings import Settings
from .summary import Metrics, compute_metrics, load_episodes, load_observations, settled_episode, summary_table

PAPER_MAPS = ("grid_game_2", "tunnel_to_goal", "tunnel_to_goal_3", "isr")
SWEEP_MAP = "tunnel_to_goal_3"
SETTLED = 0.05  # collisions per episode, moving average over 100 episodes
# What a reader of Fig. 3 could call collision-free: the 100-episode average below each of these.
THRESHOLDS = (0.05, 0.1)
# With exploration gone, a greedy policy that misses its goal loops until the step cap: 500 steps (for
# every algorithm alike) keeps such runs to seconds; those episodes count as truncated.
DECAY_STEP_CAP = 500
IN_SHORT = "## In short"


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


def reproduce(out: Path, runs: int = 10, episodes: int = 10_000, seed: int = 0, settings: Settings = Settings(),
              workers: int | None = None, force: bool = False, sweep: bool = True, figures: bool = True) -> Path:
    """Run the grid, again with exploration that stops (in decay/), and the sweep; write every map's results
    and figures and REPORT.md; returns its path."""
    out = prepare_output(out, force)
    started = time.perf_counter()
    decay = decaying(settings, episodes)
    grids = {".": settings, "decay": decay}
    jobs = [Job(m, a, r, episodes, seed, s) for s in grids.values() for m in PAPER_MAPS for a in ALGORITHMS
            for r in range(runs)]
    variants = sweep_variants(settings) if sweep else []
    for v in variants:
        jobs += [Job(SWEEP_MAP, "cq", r, episodes, seed, settings.with_overrides(v.changes)) for r in range(runs)]
    jobs = list(dict.fromkeys(jobs))  # the "defaults" variant is the grid's own CQ runs on the sweep map
    results = run_jobs(jobs, workers, label="reproduce")
    wall = time.perf_counter() - started

    for where, grid_settings in grids.items():
        for m in PAPER_MAPS:
            gridmap = load_map(m)
            mine = [results[j] for j in jobs if j.map_name == m and j.settings == grid_settings]
            (out / where / m).mkdir(parents=True, exist_ok=True)
            write_results(out / where / m, gridmap, mine,
                          manifest_for(gridmap, ALGORITHMS, runs, episodes, seed, grid_settings, wall))
    for v in variants:
        changed = settings.with_overrides(v.changes)
        mine = [results[j] for j in jobs if j.map_name == SWEEP_MAP and j.settings == changed and j.algo == "cq"]
        where = out / "sweep" / v.name
        where.mkdir(parents=True, exist_ok=True)
        write_results(where, load_map(SWEEP_MAP), mine,
                      manifest_for(load_map(SWEEP_MAP), ["cq"], runs, episodes, seed, changed, wall, variant=v.name))
    if figures:
        from .plots import write_figures

        for where in grids:
            for m in PAPER_MAPS:
                write_figures(out / where / m)
    report = out / "REPORT.md"
    report.write_text(render_report(out, runs, episodes, seed, settings, variants, time.perf_counter() - started))
    return report


# --- the report ------------------------------------------------------------------------------------------


def exploration(settings: Settings) -> str:
    if settings.epsilon_decay_episodes:
        return f"epsilon falling to 0 by episode {settings.epsilon_decay_episodes}"
    return f"epsilon {settings.epsilon:g} fixed" + (" (the paper's)" if settings.epsilon == 0.1 else "")


def _grid_data(where: Path):
    data = {}
    for m in PAPER_MAPS:
        data.update(load_episodes(where / m / "episodes.csv"))
    return data


def render_report(out: Path, runs: int, episodes: int, seed: int, settings: Settings, variants: list[Variant],
                  wall: float) -> str:
    data = _grid_data(out)
    decay = decaying(settings, episodes)
    regimes = {exploration(settings): data, exploration(decay): _grid_data(out / "decay")}
    metrics = {(x.map, x.algo): x for x in compute_metrics(data)}
    v = versions()
    lines = [
        "# CQ-learning: reproduction of the paper's experiments",
        "",
        f"Command: `cq-ros reproduce --out {out.name} --runs {runs} --episodes {episodes} --seed {seed}`"
        + (f" with settings changed from the defaults: {_changes(settings)}" if _changes(settings) else ""),
        f"Wall time: {wall:.0f} s on {v['cores']} cores ({v['machine']}, Python {v['python']}, "
        f"cq_ros {v['cq_ros']}). Every parameter and seed is in each map's `manifest.json`.",
        "",
        "Collisions are counted per episode as colliding pairs; \"collision-free from\" is the first episode after "
        f"which the 100-episode moving average of the mean over runs stays below {SETTLED} for good (claims 1 and "
        f"2 also at {', '.join(f'{t:g}' for t in THRESHOLDS if t != SETTLED)}). Exploration: {exploration(settings)}, "
        "so an exploratory move can still collide; the same grid is run again with exploration that stops "
        f"({exploration(decay)}, linearly; step cap {decay.step_cap}), in `decay/`.",
        "",
        IN_SHORT,
        "",
        *in_short(out, data, regimes, variants),
        "",
        "## Results",
        "",
        summary_table(data),
        "## The paper's claims, measured",
        "",
        *_claims(out, data, metrics, regimes),
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
    lines += ["", f"## With exploration that stops ({decay_name})", "", summary_table(decay_data)]
    if variants:
        lines += ["", *_sweep_section(out, variants)]
    return "\n".join(lines) + "\n"


def settled_at(data, threshold: float) -> dict[tuple[str, str], int | None]:
    """(map, algo) -> the episode from which its 100-episode average stays below `threshold`, or None."""
    return {key: settled_episode(runs["collisions"], threshold=threshold) for key, runs in data.items()}


def claim_collision_free(settled: dict[tuple[str, str], int | None]) -> bool:
    """Claim 1: CQ's average settles on every paper map."""
    return all(settled[(m, "cq")] is not None for m in PAPER_MAPS)


def sooner_than_cq(settled: dict[tuple[str, str], int | None]) -> list[tuple[str, str, int, int | None]]:
    """Claim 2 fails for each (algo, map, its episode, CQ's) where a baseline settles before CQ does."""
    return [(algo, m, settled[(m, algo)], settled[(m, "cq")]) for m in PAPER_MAPS for algo in ALGORITHMS
            if algo != "cq" and settled[(m, algo)] is not None
            and (settled[(m, "cq")] is None or settled[(m, algo)] < settled[(m, "cq")])]


def _changes(settings: Settings) -> str:
    base = Settings().as_dict()
    return ", ".join(f"{k}={v}" for k, v in settings.as_dict().items() if base[k] != v)


def _verdict(ok: bool) -> str:
    return "**holds**" if ok else "**does not hold**"


def _episode(settled: int | None) -> str:
    return "never" if settled is None else f"episode {settled}"


def _claims(out: Path, data, metrics: dict[tuple[str, str], Metrics], regimes: dict) -> list[str]:
    lines = []
    cq = {m: metrics[(m, "cq")] for m in PAPER_MAPS}
    settled = {(name, t): settled_at(d, t) for name, d in regimes.items() for t in THRESHOLDS}

    lines.append("1. *CQ-learning ends collision-free on all four maps* (its 100-episode average settles below the "
                 "threshold). Last 10% of episodes at fixed epsilon: "
                 + "; ".join(f"{m} {x.collisions_tail:.3f} collisions/episode" for m, x in cq.items()) + ".")
    for (name, t), s in settled.items():
        lines.append(f"   - {name}, below {t:g}: {_verdict(claim_collision_free(s))}. CQ from: "
                     + "; ".join(f"{m} {_episode(s[(m, 'cq')])}" for m in PAPER_MAPS) + ".")
    greedy = {m: _greedy(out / m) for m in PAPER_MAPS}
    if all("cq" in g for g in greedy.values()):
        ok = all(g["cq"][0] == 0 and g["cq"][2] == 0 for g in greedy.values())
        lines.append(f"   - The policy CQ has learnt, played greedily (epsilon 0) at the end, collision-free and reaching "
                     f"the goals: {_verdict(ok)}. Collisions/episode (steps/episode, runs stuck until the step cap), "
                     "mean over runs: " + "; ".join(f"{m} {_g(g['cq'])}" for m, g in greedy.items())
                     + ". The other algorithms, greedy: "
                     + "; ".join(f"{m}: " + ", ".join(f"{a} {_g(v)}" for a, v in g.items() if a != "cq")
                                 for m, g in greedy.items()) + ".")

    lines.append("2. *CQ reaches that sooner than every baseline* (on every map, no baseline settles before CQ).")
    for (name, t), s in settled.items():
        rows = sooner_than_cq(s)
        lines.append(f"   - {name}, below {t:g}: {_verdict(not rows)}."
                     + (" Sooner than CQ: " + "; ".join(f"{a} on {m} ({o} vs CQ's {_episode(c)})"
                                                       for a, m, o, c in rows) + "." if rows else ""))

    indep = {m: metrics[(m, "indep")].collisions_tail for m in PAPER_MAPS}
    others = [m for m in PAPER_MAPS if m != "tunnel_to_goal_3"]
    ok = all(indep[m] > indep["tunnel_to_goal_3"] for m in others) and all(indep[m] >= SETTLED for m in others)
    lines.append(f"3. *Independent learners keep colliding, except on TunnelToGoal_3*: {_verdict(ok)}. "
                 "Indep, last 10%: " + "; ".join(f"{m} {v:.3f}" for m, v in indep.items()) + ".")

    lines.append(_claim_joint_learners_slow(data))

    states = data[("tunnel_to_goal_3", "cq")]["states"] / 2  # two agents: per agent
    n_cells = load_map("tunnel_to_goal_3").n_cells
    peak = float(states.mean(axis=0).max())
    lines.append(f"5. *CQ's state space on TunnelToGoal_3 stays far below {n_cells ** 2}*: {_verdict(peak < 0.1 * n_cells ** 2)}. "
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


def in_short(out: Path, data, regimes: dict, variants: list[Variant]) -> list[str]:
    """The findings, each sentence computed from the results (docs/choices.md quotes them word for word)."""
    metrics = {(x.map, x.algo): x for x in compute_metrics(data)}
    tail = {m: metrics[(m, "cq")].collisions_tail for m in PAPER_MAPS}
    n_cells = load_map("tunnel_to_goal_3").n_cells
    cq_states = metrics[("tunnel_to_goal_3", "cq")].final_states / 2
    share, _ = entrance_share(out)
    lines = [f"- **CQ's state space.** On tunnel_to_goal_3 each CQ "
             f"agent ends with {cq_states:.0f} states ({n_cells} local + {cq_states - n_cells:.0f} joint), against "
             f"{metrics[('tunnel_to_goal_3', 'js')].final_states / 2:,.0f} for each JS agent and "
             f"{metrics[('tunnel_to_goal_3', 'jsa')].final_states:,.0f} for JSA; {share:.0%} of the confidence of "
             "the joint states it keeps lies within two cells of the tunnel entrance (claims 5 and 6)."]
    indep = {m: metrics[(m, "indep")].collisions_tail for m in PAPER_MAPS}
    at = _at_2000(data)
    lines.append("- **Independent learners**, last 10% of episodes: "
                 + ", ".join(f"{m} {v:.2f}" for m, v in indep.items()) + " collisions per episode (claim 3)."
                 + ("" if at is None else " **After 2000 episodes on tunnel_to_goal_3** (episodes 1901-2000) JS "
                    f"needs {at['js'][1]:.1f} steps per episode, JSA {at['jsa'][1]:.1f} and CQ {at['cq'][1]:.1f} "
                    "(claim 4)."))
    for name, d in regimes.items():
        settled = {t: settled_at(d, t) for t in THRESHOLDS}
        first = settled[THRESHOLDS[0]]
        joint = [first[(m, a)] for m in PAPER_MAPS for a in ("js", "jsa") if first[(m, a)] is not None]
        lines.append(
            f"- **With {name}**, CQ's 100-episode average of collisions per episode settles "
            + "; ".join(f"below {t:g} on {_maps([m for m in PAPER_MAPS if s[(m, 'cq')] is not None])}"
                        for t, s in settled.items())
            + (f" (last 10% of episodes: {min(tail.values()):.2f}-{max(tail.values()):.2f} collisions per episode)"
               if d is data else "")
            + f". JS and JSA settle below {THRESHOLDS[0]:g} " + (f"after {min(joint)}-{max(joint)} episodes on "
                                                                  f"{_maps(sorted({m for m in PAPER_MAPS for a in ('js', 'jsa') if first[(m, a)]}, key=PAPER_MAPS.index))}"
                                                                  if joint else "on no map")
            + ". Claim 1 (CQ collision-free on all four maps) "
            + " and ".join(f"{'holds' if claim_collision_free(s) else 'does not hold'} below {t:g}"
                           for t, s in settled.items())
            + "; claim 2 (CQ there before every baseline) "
            + " and ".join(f"{'holds' if not sooner_than_cq(s) else 'does not hold'} below {t:g}"
                           for t, s in settled.items()) + ".")
    greedy = {m: _greedy_runs(out / m) for m in PAPER_MAPS}
    if all("cq" in g for g in greedy.values()):
        stuck = {m: sum(r[2] for r in g["cq"]) for m, g in greedy.items()}
        ending = {m: {a: [r[1] for r in runs if not r[2]] for a, runs in g.items()} for m, g in greedy.items()}
        shortest = {m: min(((sum(v) / len(v), a) for a, v in e.items() if a != "cq" and v), default=None)
                    for m, e in ending.items()}
        worst = {m: max(r[0] for r in g["cq"]) for m, g in greedy.items()}
        lines.append(
            "- **CQ's learnt policy, played greedily** (epsilon 0) at the end, "
            + ("never collides, in any run on any of the four maps" if not any(worst.values()) else
               "collides at most " + ", ".join(f"{v:.2f} times per episode on {m}" for m, v in worst.items()))
            + "; "
            + (", ".join(f"{n} of its {len(greedy[m]['cq'])} runs on {m}" for m, n in stuck.items() if n)
               + " loop until the step cap (exploration breaks such a loop)"
               if any(stuck.values()) else "no run loops until the step cap")
            + ". Over the runs that reach the goals, steps per episode: "
            + "; ".join(f"{m} CQ {sum(e['cq']) / len(e['cq']):.1f}"
                        + ("" if shortest[m] is None else f", the shortest baseline {shortest[m][1]} {shortest[m][0]:.1f}")
                        for m, e in ending.items() if e["cq"]) + ".")
    isr = metrics[("isr", "cq")]
    lines.append(f"- **On isr CQ plays joint** {isr.joint_plays_tail:.1f} times per episode in the last 10% "
                 f"(claim 7): in our reconstruction of the map, the agents swap places through a one-lane corridor.")
    if variants:
        sweep = {v.name: compute_metrics(load_episodes(out / "sweep" / v.name / "episodes.csv"))[0] for v in variants}
        calm = [f"{name} (from episode {m.settled_episode})" for name, m in sweep.items() if m.settled_episode]
        lines.append(f"- **The settings sweep** (CQ on {SWEEP_MAP}, fixed epsilon, each setting the paper leaves "
                     f"open moved on its own): the 100-episode average settles below {SETTLED:g} under "
                     + (", ".join(calm) if calm else "none of them") + "; "
                     + _same_when_scaled(out, variants) + ".")
    return lines


def _maps(maps: list[str]) -> str:
    return ", ".join(maps) if maps else "no map"


def _same_when_scaled(out: Path, variants: list[Variant]) -> str:
    names = {v.name for v in variants}
    if not {"defaults", "rewards_x0.1"} <= names:
        return "rewards were not scaled"
    a, b = (load_episodes(out / "sweep" / n / "episodes.csv") for n in ("defaults", "rewards_x0.1"))
    same = all((a[k][c] == b[k][c]).all() for k in a for c in ("steps", "collisions", "joint_plays", "states"))
    return ("scaling every reward by 0.1 gives " + ("the very same episodes" if same else "other episodes")
            + " (the t-tests and greedy choices are scale-invariant)" * same)


def _greedy_runs(result_dir: Path) -> dict[str, list[tuple[float, float, bool]]]:
    """{algo: per run (collisions and steps per episode, stuck: an episode ran to the step cap)} of the final
    greedy policies, from greedy.csv."""
    per_algo: dict[str, list[tuple[float, float, bool]]] = {}
    with open(result_dir / "greedy.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row["collisions"]:
                per_algo.setdefault(row["algo"], []).append(
                    (float(row["collisions"]), float(row["steps"]), int(row["truncated"]) > 0))
    return per_algo


def _greedy(result_dir: Path) -> dict[str, tuple[float, float, int]]:
    """{algo: (collisions and steps per episode, mean over runs; runs stuck)} of the final greedy policies."""
    return {a: (sum(v[0] for v in runs) / len(runs), sum(v[1] for v in runs) / len(runs), sum(v[2] for v in runs))
            for a, runs in _greedy_runs(result_dir).items()}


def _g(v: tuple[float, float, int]) -> str:
    return f"{v[0]:.3f} ({v[1]:.1f}{f', {v[2]} stuck' if v[2] else ''})"


def _at_2000(data) -> dict[str, tuple[float, float]] | None:
    """{algo: (collisions, steps) per episode over episodes 1901-2000} on TunnelToGoal_3 for JS, JSA and CQ."""
    if data[("tunnel_to_goal_3", "cq")]["steps"].shape[1] < 2000:
        return None
    return {algo: (float(data[("tunnel_to_goal_3", algo)]["collisions"][:, 1900:2000].mean()),
                   float(data[("tunnel_to_goal_3", algo)]["steps"][:, 1900:2000].mean())) for algo in ("js", "jsa", "cq")}


def _claim_joint_learners_slow(data) -> str:
    """JS and JSA "still haven't learnt a good policy after 2000 episodes" on TunnelToGoal_3."""
    at = _at_2000(data)
    if at is None:
        return "4. *JS and JSA are still poor after 2000 episodes on TunnelToGoal_3*: not measured (fewer than 2000 episodes)."
    ok = all(at[a][0] > at["cq"][0] or at[a][1] > 1.2 * at["cq"][1] for a in ("js", "jsa"))
    return ("4. *JS and JSA are still poor after 2000 episodes on TunnelToGoal_3*: "
            f"{_verdict(ok)} (poor = more collisions than CQ or 20% more steps). Episodes 1901-2000: "
            + "; ".join(f"{a} {c:.3f} collisions and {s:.1f} steps per episode" for a, (c, s) in at.items()) + ".")


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
    kept = [o for o in load_observations(out / "tunnel_to_goal_3" / "observe.csv") if o.algo == "cq"]
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
             "| variant | change | collisions/ep (last 10%) | collision-free from | final states | joint plays/ep (last 10%) |",
             "|---|---|---:|---:|---:|---:|"]
    for v in variants:
        (m,) = compute_metrics(load_episodes(out / "sweep" / v.name / "episodes.csv"))
        lines.append(f"| {v.name} | {v.why} | {m.collisions_tail:.3f} ± {m.collisions_tail_std:.3f} | "
                     f"{m.settled_episode or 'never'} | {m.final_states:.1f} | {m.joint_plays_tail:.2f} |")
    return lines

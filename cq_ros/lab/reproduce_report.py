"""REPORT.md of `cq-ros reproduce`: how it ran, its "In short" section (which docs/choices.md quotes word for
word), the results' tables, the claims (reproduce_claims.py) and the figures, the grid with exploration that
stops, the paper's CQ beside ours and the settings sweep, every sentence computed from the results folder.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ..gridmap import load_map
from ..learners import ALGORITHMS
from ..settings import Settings
from .reproduce_claims import (MIN_SEEDS, SETTLED, THRESHOLDS, at_2000, at_seeds, claim_collision_free, claims,
                               entrance_share, greedy_means, greedy_runs, joint_learners_slow, over_seeds,
                               seed_list, settled_at, show_greedy, sooner_than_cq, span)
from .reproduce_grid import CQ, OURS, OURS_DIR, PAPER_MAPS, SWEEP_MAP, Variant, decaying, seed_dir
from .results import EPISODES, load_episodes, versions
from .summary import compute_metrics, summary_table

IN_SHORT = "## In short"


def exploration(settings: Settings) -> str:
    if settings.epsilon_decay_episodes:
        return f"epsilon falling to 0 by episode {settings.epsilon_decay_episodes}"
    return f"epsilon {settings.epsilon:g} fixed" + (" (the paper's)" if settings.epsilon == 0.1 else "")


def _grid_data(where: Path) -> dict:
    """{(map, algo): its runs' episodes} over the four maps of the grid in `where`."""
    return {key: runs for m in PAPER_MAPS for key, runs in load_episodes(where / m / EPISODES).items()}


def render_report(out: Path, episodes: int, seeds: Sequence[int], settings: Settings,
                  variants: list[Variant], wall: float, executed_on: dict | None, command: str) -> str:
    """REPORT.md, from the results the run wrote in `out`; `command` is the command line it names."""
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
        + (f"here {seed_list(seeds)}." if len(seeds) >= MIN_SEEDS else
           f"this report has {len(seeds)} ({seed_list(seeds)}), so it is not quoted and claims 1 and 2 are not "
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
        lines += [f"## Collision-free from, over {seed_list(seeds)}", "", *_settled_table(regimes, seeds), ""]
    lines += [
        "## The paper's claims, measured",
        "",
        *claims(out, data, metrics, regimes, seeds),
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


def _settled_table(regimes: dict, seeds: Sequence[int]) -> list[str]:
    heads = [f"{name}, below {t:g}" for name in regimes for t in THRESHOLDS]
    settled = [[settled_at(d, t) for d in per_seed] for per_seed in regimes.values() for t in THRESHOLDS]
    lines = ["| map | algo | " + " | ".join(heads) + " |", "| --- | --- | " + " | ".join("---:" for _ in heads) + " |"]
    for m in PAPER_MAPS:
        for a in ALGORITHMS:
            lines.append(f"| {m} | {a} | " + " | ".join(over_seeds([s[(m, a)] for s in col], seeds) for col in settled)
                         + " |")
    return lines


def _changes(settings: Settings) -> str:
    base = Settings().as_dict()
    return ", ".join(f"{k}={v}" for k, v in settings.as_dict().items() if base[k] != v)


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
    at = at_2000(data)
    lines.append("- **Independent learners**, last 10% of episodes: "
                 + ", ".join(f"{m} {v:.2f}" for m, v in indep.items()) + " collisions per episode (claim 3)."
                 + ("" if at is None else " **After 2000 episodes on tunnel_to_goal_3** (episodes 1901-2000) JS "
                    f"collides {at['js'][0]:.3f} times per episode, JSA {at['jsa'][0]:.3f} and CQ {at[CQ][0]:.3f} "
                    f"(in {at['js'][1]:.1f}, {at['jsa'][1]:.1f} and {at[CQ][1]:.1f} steps): claim 4, judged on "
                    f"collisions as Fig. 3 plots them, {'holds' if joint_learners_slow(at) else 'does not hold'}."))
    for name, per_seed in regimes.items():
        lines.append(_regime_finding(name, per_seed, seeds))
    greedy = {m: greedy_runs(out / m) for m in PAPER_MAPS}
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
                     f"open moved on its own, {seed_list(seeds[:1])}): CQ collides from {lo:.3f} ({low}) to {hi:.3f} "
                     f"({high}) times per episode in the last 10% of episodes; "
                     + _same_when_scaled(out, variants) + ".")
    return lines


def _regime_finding(name: str, per_seed: list, seeds: Sequence[int]) -> str:
    """One exploration regime: CQ's collisions at the end and, over at least MIN_SEEDS seeds, when the averages
    settle and claims 1 and 2."""
    tails = [m.collisions_tail for d in per_seed for m in compute_metrics(d) if m.algo == CQ]
    text = (f"- **With {name}**, CQ collides {min(tails):.2f}-{max(tails):.2f} times per episode in the last 10% of "
            f"episodes (the four maps, {seed_list(seeds)})")
    if len(seeds) < MIN_SEEDS:
        return (text + ". When its 100-episode average settles below a threshold moves with the seed, so it is quoted "
                f"only over at least {MIN_SEEDS} seeds (`--seeds`); claims 1 and 2 are not judged here.")
    settled = {t: [settled_at(d, t) for d in per_seed] for t in THRESHOLDS}
    first = settled[THRESHOLDS[0]]
    joint_never = sorted({(m, a) for s in first for m in PAPER_MAPS for a in ("js", "jsa") if s[(m, a)] is None},
                         key=lambda k: (PAPER_MAPS.index(k[0]), k[1]))  # a set's order varies by process
    joint = span([s[(m, a)] for s in first for m in PAPER_MAPS for a in ("js", "jsa")])
    return (text + ". Its 100-episode average settles "
            + "; ".join(f"below {t:g}: " + ", ".join(f"{m} {over_seeds([s[(m, CQ)] for s in per], seeds)}"
                                                   for m in PAPER_MAPS) for t, per in settled.items())
            + f". JS and JSA settle below {THRESHOLDS[0]:g} "
            + ("on no map at any seed" if joint == "never" else f"at {joint}"
               + (" (never, at one seed or more: " + ", ".join(f"{a} on {m}" for m, a in joint_never) + ")"
                  if joint_never else ""))
            + ". Claim 1 (CQ collision-free on all four maps) "
            + " and ".join(f"{_plain(at_seeds([claim_collision_free(s) for s in per]))} below {t:g}"
                           for t, per in settled.items())
            + "; claim 2 (CQ there before every baseline) "
            + " and ".join(f"{_plain(at_seeds([not sooner_than_cq(s) for s in per]))} below {t:g}"
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
    lines = [f"## The paper's CQ beside ours ({seed_list(seeds[:1])}, {exploration(Settings())})", "",
             f"`{OURS}` (our rules, docs/choices.md) / `{CQ}` (Algorithm 2 as the paper reads):", "",
             "| map | collisions/ep (last 10%) | final states | joint plays/ep (last 10%) | greedy collisions/ep "
             "(steps/ep) |", "|---|---:|---:|---:|---:|"]
    for m in PAPER_MAPS:
        (ours,) = compute_metrics(load_episodes(out / OURS_DIR / m / EPISODES))
        theirs = theirs_of[m]
        greedy = (greedy_means(out / OURS_DIR / m).get(OURS), greedy_means(out / m).get(CQ))
        lines.append(f"| {m} | {ours.collisions_tail:.3f} / {theirs.collisions_tail:.3f} "
                     f"| {ours.final_states:.1f} / {theirs.final_states:.1f} "
                     f"| {ours.joint_plays_tail:.2f} / {theirs.joint_plays_tail:.2f} | "
                     + (" / ".join(show_greedy(g) for g in greedy) if all(greedy) else "not played") + " |")
    return lines


def _where(executed_on: dict | None, v: dict) -> str:
    if executed_on and executed_on.get("where") == "dask":
        return f"the Dask cluster at {executed_on['scheduler']} ({len(executed_on['workers'])} workers)"
    return f"{v['cores']} cores"

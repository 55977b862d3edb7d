"""The claims of the paper's section 4, each checked against the numbers `cq-ros reproduce` measured: the
verdicts are computed, not written, so a claim that does not reproduce says so, with its figure.

When a 100-episode average settles below a threshold (claims 1 and 2, "collision-free from") moves with the
seed by thousands of episodes, so it is quoted only as a range over at least MIN_SEEDS master seeds
(`--seeds`); with fewer the claim says so instead. Everything else is the first seed's.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

from ..gridmap import load_map
from ..learners import ALGORITHMS
from .reproduce_grid import CQ, PAPER_MAPS
from .results import GREEDY, OBSERVE, GreedyRun, load_greedy, load_observations
from .summary import Metrics, settled_episode

SETTLED = 0.05  # collisions per episode, moving average over 100 episodes
# What a reader of Fig. 3 could call collision-free: the 100-episode average below each of these.
THRESHOLDS = (0.05, 0.1)
MIN_SEEDS = 3  # a crossing episode is quoted only as a range over at least this many seeds


def seed_list(seeds: Sequence[int]) -> str:
    return ("seed " if len(seeds) == 1 else "seeds ") + ", ".join(map(str, seeds))


def over_seeds(episodes: Sequence[int | None], seeds: Sequence[int]) -> str:
    """The episodes at which an average settles, one per seed (None: never), as one range: "episodes 141-233",
    "never", or "episodes 141-233 (never at seed 2)"."""
    never = [sd for sd, e in zip(seeds, episodes) if e is None]
    return span(episodes) + (f" (never at {seed_list(never)})" if never and len(never) < len(seeds) else "")


def span(episodes: Sequence[int | None]) -> str:
    got = [e for e in episodes if e is not None]
    if not got:
        return "never"
    lo, hi = min(got), max(got)
    return f"episode {lo}" if lo == hi else f"episodes {lo}-{hi}"


def at_seeds(ok: Sequence[bool]) -> str:
    """A verdict over seeds: it holds only if it holds at every seed."""
    return verdict(all(ok)) + ("" if all(ok) or not any(ok) else f" (holds at {sum(ok)} of {len(ok)} seeds)")


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


def verdict(ok: bool) -> str:
    return "**holds**" if ok else "**does not hold**"


def claims(out: Path, data, metrics: dict[tuple[str, str], Metrics], regimes: dict, seeds: Sequence[int]) -> list[str]:
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
                     f"{at_seeds([claim_collision_free(s) for s in per_seed])}. CQ from, over {seed_list(seeds)}: "
                     + "; ".join(f"{m} {over_seeds([s[(m, CQ)] for s in per_seed], seeds)}"
                                 for m in PAPER_MAPS) + "."))
    greedy = {m: greedy_means(out / m) for m in PAPER_MAPS}
    if all(CQ in g for g in greedy.values()):
        ok = all(g[CQ].collisions == 0 and g[CQ].stuck == 0 for g in greedy.values())
        lines.append("   - The policy CQ has learnt, played greedily (epsilon 0) at the end, collision-free and "
                     f"reaching the goals: {verdict(ok)}. Collisions/episode (steps/episode, runs stuck until the "
                     "step cap), mean over runs: " + "; ".join(f"{m} {show_greedy(g[CQ])}" for m, g in greedy.items())
                     + ". The other algorithms, greedy: "
                     + "; ".join(f"{m}: " + ", ".join(f"{a} {show_greedy(v)}" for a, v in g.items() if a != CQ)
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
        lines.append(f"   - {name}, below {t:g}: {at_seeds([not r for r in rows])}."
                     + (" Sooner than CQ: " + "; ".join(f"{a} on {m} (at {seed_list(sds)})"
                                                       for (a, m), sds in sooner.items()) + "." if sooner else ""))

    indep = {m: metrics[(m, "indep")].collisions_tail for m in PAPER_MAPS}
    others = [m for m in PAPER_MAPS if m != "tunnel_to_goal_3"]
    ok = all(indep[m] > indep["tunnel_to_goal_3"] for m in others) and all(indep[m] >= SETTLED for m in others)
    lines.append(f"3. *Independent learners keep colliding, except on TunnelToGoal_3*: {verdict(ok)}. "
                 "Indep, last 10%: " + "; ".join(f"{m} {v:.3f}" for m, v in indep.items()) + ".")

    lines.append(_claim_joint_learners_slow(data))

    states = data[("tunnel_to_goal_3", CQ)]["states"] / 2  # two agents: per agent
    n_cells = load_map("tunnel_to_goal_3").n_cells
    peak = float(states.mean(axis=0).max())
    lines.append(f"5. *CQ's state space on TunnelToGoal_3 stays far below {n_cells ** 2}*: "
                 f"{verdict(peak < 0.1 * n_cells ** 2)}. "
                 f"Per agent, mean over runs: at most {peak:.1f} states (local space {n_cells}), "
                 f"{float(states[:, -1].mean()):.1f} at the end.")

    lines.append(_claim_entrance(out))

    isr = cq["isr"]
    lines.append(f"7. *Where the agents can solve it alone (ISR), CQ (almost) never plays joint*: "
                 f"{verdict(isr.joint_plays_tail < 1.0)}. CQ on isr: {isr.joint_plays_tail:.2f} joint plays per "
                 f"episode in the last 10% ({isr.joint_plays_all:.2f} over all episodes), against "
                 + "; ".join(f"{m} {cq[m].joint_plays_tail:.2f}" for m in PAPER_MAPS if m != "isr") + ".")
    return lines


def greedy_runs(result_dir: Path) -> dict[str, list[GreedyRun]]:
    """{algo: its runs' greedy policies at the end}, from greedy.csv."""
    per_algo: dict[str, list[GreedyRun]] = {}
    for g in load_greedy(result_dir / GREEDY):
        per_algo.setdefault(g.algo, []).append(g)
    return per_algo


class GreedyMean(NamedTuple):
    collisions: float  # per episode, mean over runs
    steps: float  # per episode, mean over runs
    stuck: int  # runs with an episode ended by the step cap


def greedy_means(result_dir: Path) -> dict[str, GreedyMean]:
    """{algo: its final greedy policies, over runs}."""
    return {a: GreedyMean(sum(g.collisions for g in runs) / len(runs), sum(g.steps for g in runs) / len(runs),
                           sum(g.truncated > 0 for g in runs))
            for a, runs in greedy_runs(result_dir).items()}


def show_greedy(v: GreedyMean) -> str:
    return f"{v.collisions:.3f} ({v.steps:.1f}{f', {v.stuck} stuck' if v.stuck else ''})"


def at_2000(data) -> dict[str, tuple[float, float]] | None:
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
    at = at_2000(data)
    if at is None:
        return ("4. *JS and JSA are still poor after 2000 episodes on TunnelToGoal_3*: not measured (fewer than 2000 "
                "episodes).")
    return ("4. *JS and JSA are still poor after 2000 episodes on TunnelToGoal_3*, judged on collisions as Fig. 3 "
            f"plots them (poor = more collisions than CQ): {verdict(joint_learners_slow(at))}. Episodes 1901-2000, "
            "collisions per episode (steps per episode beside): "
            + "; ".join(f"{a} {c:.3f} ({s:.1f} steps)" for a, (c, s) in at.items()) + ".")


def _claim_entrance(out: Path) -> str:
    """Where CQ's agents keep joint states on TunnelToGoal_3, by summed confidence."""
    share, top = entrance_share(out)
    return (f"6. *CQ's joint states lie around the tunnel entrance*: {verdict(share >= 0.5)}. "
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

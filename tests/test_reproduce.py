"""The verdicts of `cq-ros reproduce`, computed on synthetic results where each claim is known to hold and
known not to hold: claims 1 and 2 at both thresholds and over seeds (judged only over at least 3), claim 4
on collisions, and where CQ keeps its joint states (claim 6)."""

import csv
import re
from pathlib import Path

import numpy as np

from cq_ros.lab.results import OBSERVE_COLUMNS
from cq_ros.learners import ALGORITHMS
from cq_ros.lab.reproduce import as_command
from cq_ros.lab.reproduce_claims import (
    _claim_entrance,
    _claim_joint_learners_slow,
    claim_collision_free,
    entrance_share,
    over_seeds,
    settled_at,
    sooner_than_cq,
)
from cq_ros.lab.reproduce_grid import CQ, PAPER_MAPS
from cq_ros.lab.reproduce_report import _regime_finding, states_in_parts
from cq_ros.cli.main import main
from cq_ros.settings import Settings

EPISODES = 1000


def collisions_until(episode: int | None, after: float = 0.0, runs: int = 3) -> dict:
    """Runs that collide twice per episode, then `after` per episode from `episode` on (None: never calm); the
    other columns constant."""
    values = np.full((runs, EPISODES), 2.0)
    if episode is not None:
        values[:, episode - 1:] = after
    return {"collisions": values, **{c: np.full((runs, EPISODES), 1.0) for c in ("steps", "joint_plays", "states")},
            "truncated": np.zeros((runs, EPISODES))}


def grid(cq: int | None, others: dict[str, int | None], cq_after: float = 0.0) -> dict:
    """Every paper map alike: CQ calm from `cq`, each baseline from its episode in `others` (default never)."""
    return {(m, a): collisions_until(cq, cq_after) if a == CQ else collisions_until(others.get(a))
            for m in PAPER_MAPS for a in ALGORITHMS}


def test_claims_1_and_2_hold_when_cq_is_calm_first_on_every_map():
    settled = settled_at(grid(200, {"js": 400, "jsa": 600}), 0.05)
    assert claim_collision_free(settled)
    assert sooner_than_cq(settled) == []


def test_claim_2_fails_naming_each_baseline_calm_before_cq():
    settled = settled_at(grid(400, {"js": 150, "jsa": 600}), 0.05)
    assert claim_collision_free(settled)
    rows = sooner_than_cq(settled)
    assert [(algo, m) for algo, m, _, _ in rows] == [("js", m) for m in PAPER_MAPS]
    assert all(other < mine for _, _, other, mine in rows)


def test_claim_2_fails_when_a_baseline_is_calm_and_cq_never_is():
    data = grid(200, {"js": 300})
    data[("isr", CQ)] = collisions_until(None)
    settled = settled_at(data, 0.05)
    assert not claim_collision_free(settled)
    assert [(algo, m, mine) for algo, m, _, mine in sooner_than_cq(settled)] == [("js", "isr", None)]


def test_claim_1_depends_on_the_threshold_a_reader_of_fig_3_means():
    data = grid(300, {}, cq_after=0.07)  # CQ settles at 0.07 collisions per episode
    assert not claim_collision_free(settled_at(data, 0.05))
    assert claim_collision_free(settled_at(data, 0.1))


def write_observations(out, cells_and_confidence):
    where = out / "tunnel_to_goal_3"
    where.mkdir(parents=True)
    with open(where / "observe.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(OBSERVE_COLUMNS)
        for (row, col), conf in cells_and_confidence:
            w.writerow(("tunnel_to_goal_3", CQ, 0, 1, row, col, 2, row + 1, col, conf))


def test_claim_6_share_of_joint_states_at_the_tunnel_entrance(tmp_path):
    # the tunnel of tunnel_to_goal_3 opens at row 2, column 4
    write_observations(tmp_path / "near", [((2, 4), 5.0), ((1, 4), 3.0), ((2, 5), 2.0)])
    assert entrance_share(tmp_path / "near")[0] == 1.0
    assert "**holds**. 100% " in _claim_entrance(tmp_path / "near")
    write_observations(tmp_path / "far", [((0, 10), 5.0), ((4, 9), 4.0), ((2, 4), 1.0)])
    assert entrance_share(tmp_path / "far")[0] == 0.1
    assert "**does not hold**. 10% " in _claim_entrance(tmp_path / "far")


def at_2000(collisions: dict[str, float], steps: dict[str, float]) -> dict:
    """tunnel_to_goal_3 runs of 2000 episodes with these collisions and steps per episode throughout."""
    return {("tunnel_to_goal_3", a): {"collisions": np.full((2, 2000), collisions[a]),
                                      "steps": np.full((2, 2000), steps[a])}
            for a in ("js", "jsa", CQ)}


def test_claim_4_is_judged_on_collisions_as_fig_3_plots_them_with_steps_beside():
    long_routes = {"js": 21.3, "jsa": 23.2, CQ: 15.3}
    # Far longer routes but fewer collisions than CQ: not poor on Fig. 3's measure.
    fewer = _claim_joint_learners_slow(at_2000({"js": 0.01, "jsa": 0.02, CQ: 0.1}, long_routes))
    assert "**does not hold**" in fewer and "js 0.010 (21.3 steps)" in fewer
    # One of the two colliding less than CQ is enough for the claim to fail.
    assert "**does not hold**" in _claim_joint_learners_slow(at_2000({"js": 0.3, "jsa": 0.05, CQ: 0.1}, long_routes))
    more = _claim_joint_learners_slow(at_2000({"js": 0.3, "jsa": 0.2, CQ: 0.1}, {a: 15.0 for a in long_routes}))
    assert "**holds**" in more and f"{CQ} 0.100 (15.0 steps)" in more


def test_a_crossing_is_quoted_as_a_range_over_seeds_naming_those_where_it_never_comes():
    assert over_seeds([141, 233, None], (0, 1, 2)) == "episodes 141-233 (never at seed 2)"
    assert over_seeds([None, 90, None], (4, 5, 6)) == "episode 90 (never at seeds 4, 6)"
    assert over_seeds([None, None, None], (0, 1, 2)) == "never"
    assert over_seeds([7, 7, 7], (0, 1, 2)) == "episode 7"


def test_claims_1_and_2_are_judged_over_three_seeds_and_not_on_one():
    seeds = [grid(200, {"js": 400}), grid(400, {"js": 150}), grid(300, {"js": 500})]  # js first at the second
    one = _regime_finding("fixed", seeds[:1], (0,))
    assert "not judged" in one and not any(f"episode {n}" in one for n in (200, 400, 150))  # no crossing quoted
    three = _regime_finding("fixed", seeds, (0, 1, 2))
    # calm from episode 200-400, the 100-episode average 96 later
    assert "below 0.05: grid_game_2 episodes 296-496" in three
    assert "Claim 1 (CQ collision-free on all four maps) holds below 0.05" in three
    assert "claim 2 (CQ there before every baseline) does not hold (holds at 2 of 3 seeds) below 0.05" in three


def test_the_state_space_sentence_adds_up():
    assert states_in_parts(56.5, 55) == "57 states (55 local + 2 joint)"  # each part rounded alone: 56 = 55 + 2
    assert states_in_parts(62.2, 55) == "62 states (55 local + 7 joint)"
    for tenths in range(550, 700):
        total, local, joint = map(int, re.findall(r"\d+", states_in_parts(tenths / 10, 55)))
        assert total == local + joint and abs(total - tenths / 10) <= 0.5


def test_the_report_names_the_command_as_run(monkeypatch, tmp_path):
    """The CLI hands reproduce its own command line (REPORT.md's "Command:"), --no-sweep and --out as given."""
    import cq_ros.lab.reproduce as lab

    called = {}
    monkeypatch.setattr(lab, "reproduce", lambda *a, **kw: called.update(kw) or tmp_path / "REPORT.md")
    argv = ["reproduce", "--out", str(tmp_path / "my results"), "--runs", "2", "--episodes", "50", "--no-sweep",
            "--set", "step_cap=300"]
    assert main(argv) == 0
    assert called["command"] == f"cq-ros reproduce --out '{tmp_path / 'my results'}' --runs 2 --episodes 50 " \
                                "--no-sweep --set step_cap=300"
    assert called["sweep"] is False


def test_a_library_call_is_named_as_the_command_that_runs_it():
    settings = Settings().with_overrides(["step_cap=300"])
    assert as_command(Path("out/r"), 2, 50, (0, 1, 2), settings, False, 1, None) == \
        "cq-ros reproduce --out out/r --runs 2 --episodes 50 --seeds 0,1,2 --no-sweep --jobs 1 --set step_cap=300"
    assert as_command(Path("r"), 10, 10000, (0,), Settings(), True, None, None) == \
        "cq-ros reproduce --out r --runs 10 --episodes 10000 --seed 0"

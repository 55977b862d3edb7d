"""CQ-learning brings a small generated warehouse home: after a short run, its greedy policy gets
every AGV to its goal with no collision and no truncation, for consecutive seeds (map and learners alike),
none chosen to pass. The 8- to 32-AGV figures are benchmarks (benchmarks/bench_warehouse.py), not tests."""

import pytest

from cq_ros import engine
from cq_ros.settings import run_settings
from cq_ros.mapgen.warehouse import warehouse_map


@pytest.mark.parametrize("seed", range(4))
def test_cq_greedy_policy_brings_every_agv_of_a_small_warehouse_home(seed):
    gridmap = warehouse_map(4, aisle_length=4, seed=seed)
    settings = run_settings(gridmap, {"eval_episodes": 3, "step_cap": 1000})
    result = engine.run("cq", gridmap, settings, seed=seed, run_index=0, episodes=600)
    steps, collisions, truncated = (result.greedy[c] for c in ("steps", "collisions", "truncated"))
    assert not truncated.any(), f"greedy policy stuck at the step cap (seed {seed})"
    assert not collisions.any()
    # home by a route, not by a walk: within twice the longest shortest path of any AGV
    longest = max(gridmap.distance(s, g) for s, g in zip(gridmap.starts, gridmap.goals))
    assert steps.max() <= 2 * longest + 4


@pytest.mark.slow
def test_on_a_small_delayed_warehouse_cq_collides_less_than_independent_learners_and_hears_less_than_near():
    """Where AGVs are delayed (slip 0.1, the generator's delayed defaults), looking pays, and CQ pays less for it
    than the learner that watches every peer in range: summed over six consecutive seeds (map and learners alike),
    none chosen to pass, with CQ's defaults under delays, CQ's greedy policy collides less than the independent
    learners' and takes in fewer peer positions than near's (22 against 43 greedy collisions, 2,772 against
    6,291 positions heard, when first run on 2026-12-03)."""
    collisions = {"cq": 0.0, "indep": 0.0, "near": 0.0}
    heard = dict.fromkeys(collisions, 0.0)
    for seed in range(6):
        gridmap = warehouse_map(6, aisles=2, aisle_length=4, seed=seed, slip=0.1)
        settings = run_settings(gridmap, {"eval_episodes": 20, "step_cap": 1000, "epsilon_decay_episodes": 750})
        for algo in collisions:
            result = engine.run(algo, gridmap, settings, seed=seed, run_index=0, episodes=1000)
            collisions[algo] += result.greedy["collisions"].sum()
            heard[algo] += result.greedy["heard"].sum()
    assert collisions["cq"] < collisions["indep"], collisions
    assert 0 < heard["cq"] < heard["near"], heard

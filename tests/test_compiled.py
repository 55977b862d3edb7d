"""The compiled engine (cq_ros.compiled) is the reference engine's twin: for the same seed, `run` returns the same
RunResult (tables equal byte for byte, same dtypes, same joint states) and so the lab writes the same result files,
on the paper's maps, generated warehouses with and without delays, and small random maps with seeds and settings
drawn by hypothesis; its Mersenne Twister and fsum are CPython's."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_world import random_maps

from cq_ros import engine
from cq_ros.compiled import engine as compiled
from cq_ros.compiled.algorithms import KERNEL_ALGORITHMS
from cq_ros.compiled import mt
from cq_ros.compiled.windows import fsum, kinds_of
from cq_ros.gridmap import load_map
from cq_ros.lab.results import EPISODES, GREEDY, OBSERVE, write_results
from cq_ros.mapgen.warehouse import warehouse_map
from cq_ros.settings import Settings, run_settings


def assert_twins(a, b):
    assert (a.algo, a.run) == (b.algo, b.run)
    for table in ("episodes", "greedy"):
        x, y = getattr(a, table), getattr(b, table)
        assert x.dtype == y.dtype and x.shape == y.shape
        assert x.tobytes() == y.tobytes(), f"{table} differ"
    assert a.joint_states == b.joint_states
    assert [type(v) for js in a.joint_states for v in js] == [type(v) for js in b.joint_states for v in js]


def both(algo, gridmap, s, seed=3, run_index=1, episodes=50):
    return (compiled.run(algo, gridmap, s, seed, run_index, episodes),
            engine.run(algo, gridmap, s, seed, run_index, episodes))


@given(st.integers(0, 2**64), st.integers(1, 2**32 - 1))
@settings(max_examples=30, deadline=None)
def test_mersenne_twister_draws_as_cpython(seed, n):
    rng = random.Random(seed)
    words = mt.state_of(rng)[None]
    ours = [mt.random(words, 0) for _ in range(700)] + [mt.randbelow(words, 0, n) for _ in range(50)]
    theirs = [rng.random() for _ in range(700)] + [rng.randrange(n) for _ in range(50)]
    assert ours == theirs
    # one word drawn between pairs: random() also meets a generator with a single word left before its twist
    ours = [mt.random(words, 0) if k % 3 else mt.randbelow(words, 0, n) for k in range(2000)]
    theirs = [rng.random() if k % 3 else rng.randrange(n) for k in range(2000)]
    assert ours == theirs
    assert tuple(words[0]) == rng.getstate()[1]


@given(st.lists(st.floats(-1e6, 1e6, allow_nan=False) | st.sampled_from([-10.0, -1.0, 0.1, 10.0, -0.0]),
                max_size=80))
@settings(max_examples=200, deadline=None)
def test_fsum_is_math_fsum(values):
    array, partials = np.array([values], dtype=float), np.empty(len(values) + 1)
    assert fsum(array, 0, len(values), False, partials) == math.fsum(values)
    assert fsum(array, 0, len(values), True, partials) == math.fsum(v * v for v in values)


@pytest.mark.parametrize("algo", KERNEL_ALGORITHMS)
@pytest.mark.parametrize("map_name,episodes", [("tunnel_to_goal", 400), ("tunnel_to_goal_3", 200)])
@pytest.mark.parametrize("eval_learning", [0, 1])
def test_paper_maps_byte_identical_result_files(algo, map_name, episodes, eval_learning, tmp_path):
    gm = load_map(map_name)
    s = run_settings(gm, {"eval_learning": eval_learning})
    ours, theirs = both(algo, gm, s, episodes=episodes)
    assert_twins(ours, theirs)
    written = {}
    for name, result in (("compiled", ours), ("reference", theirs)):
        (tmp_path / name).mkdir()
        write_results(tmp_path / name, gm, [result], {})
        written[name] = [(tmp_path / name / f).read_bytes() for f in (EPISODES, GREEDY, OBSERVE)]
    assert written["compiled"] == written["reference"]
    if algo in compiled.CQS and map_name == "tunnel_to_goal_3":
        assert ours.joint_states, "a CQ run that marks nothing compares too little"


@pytest.mark.parametrize("algo", KERNEL_ALGORITHMS)
@pytest.mark.parametrize("delays", [{}, {"slip": 0.1, "start_hold": 3}])
def test_generated_warehouse(algo, delays):
    gm = warehouse_map(4 if algo == "jsa" else 6, seed=2, **delays)  # JSA: at most 5 agents (4^n joint actions)
    s = run_settings(gm, {"eval_episodes": 3, "step_cap": 400})
    assert_twins(*both(algo, gm, s, episodes=6))


def test_jsa_past_its_agents_is_refused_by_both_engines():
    gm = warehouse_map(6, seed=2)
    for run in (compiled.run, engine.run):
        with pytest.raises(ValueError, match="jsa supports at most 5 agents"):
            run("jsa", gm, Settings(), 0, 0, 1)


ALGOS = st.sampled_from(KERNEL_ALGORITHMS)


@st.composite
def drawn_settings(draw):
    flag = st.integers(0, 1)
    step_cap = draw(st.sampled_from([1, 7, 60]))
    hold = draw(st.sampled_from([0, 0, 2]))
    hold = hold if hold < step_cap else 0  # a hold as long as an episode is refused
    return Settings(
        alpha=draw(st.sampled_from([0.1, 0.3, 1.0])), epsilon=draw(st.sampled_from([0.0, 0.1, 0.5])),
        epsilon_decay_episodes=draw(st.sampled_from([0, 10])), window=draw(st.integers(2, 8)),
        gamma=draw(st.sampled_from([0.0, 0.9])), reward_step=draw(st.sampled_from([0.0, -1.0, -0.1])),
        conf_down=draw(st.sampled_from([0.02, 0.3, 0.6])), conf_up=draw(st.sampled_from([0.0, 0.5])),
        conf_max=draw(st.sampled_from([1.0, 10.0])),
        loc_cost=draw(st.sampled_from([0.0, 0.1, 1.0])), step_cap=step_cap, eval_episodes=draw(st.integers(0, 4)),
        eval_learning=draw(flag), slip=draw(st.sampled_from([0.0, 0.0, 0.2, 0.9])), start_hold=hold)


@given(random_maps(), drawn_settings(), ALGOS, st.integers(0, 2**32), st.integers(0, 3))
@settings(max_examples=90, deadline=None)  # some 15 a learner
def test_random_maps_seeds_and_settings(gm, s, algo, seed, run_index):
    assert_twins(*both(algo, gm, s, seed, run_index, episodes=25))


@given(drawn_settings(), st.sampled_from(compiled.CQS), st.integers(0, 2**32))
@settings(max_examples=12, deadline=None)
def test_three_agents_in_the_tunnel_with_drawn_settings(s, algo, seed):
    """Either CQ's settings drawn at random, where three agents meet often enough to mark, meet and forget."""
    import dataclasses

    s = dataclasses.replace(s, step_cap=200, window=max(s.window, 4))
    assert_twins(*both(algo, load_map("tunnel_to_goal_3"), s, seed, 0, episodes=60))


def reference_team(algo, gm, s, seed, run_index):
    return engine.Team(engine.GridWorld(gm, s, seed=engine.world_seed(seed, run_index)),
                       engine.make_learners(algo, gm, s, seed, run_index))


def assert_same_tables(ours, theirs):
    """Two learners hold the same Q_k, generator state and (in creation order) states with peers."""
    assert getattr(ours, "q_local", None) == getattr(theirs, "q_local", None)
    assert ours.rng.getstate() == theirs.rng.getstate()
    for table in compiled.TABLES.values():
        assert list(getattr(ours, table, {}).items()) == list(getattr(theirs, table, {}).items())
    if theirs.name in compiled.TABLES:
        assert getattr(theirs, compiled.TABLES[theirs.name]), "a run that met no peer compares too little"


@pytest.mark.parametrize("algo,map_name,overrides", [
    ("indep", "tunnel_to_goal", {}), ("cq", "tunnel_to_goal_3", {}),
    ("cq_paper", "tunnel_to_goal_3", {"slip": 0.1, "start_hold": 2, "conf_down": 0.3}),
    ("cq_paper", "tunnel_to_goal", {"epsilon_decay_episodes": 150}),
    ("near", "tunnel_to_goal_3", {}), ("loc", "tunnel_to_goal_3", {"slip": 0.1, "start_hold": 2}),
    ("js", "tunnel_to_goal_3", {"eval_learning": 1}), ("jsa", "tunnel_to_goal_3", {"slip": 0.1})])
def test_a_run_learnt_compiled_goes_on_as_reference_learners(algo, map_name, overrides):
    """K episodes compiled, handed over to reference learners, M more on the reference engine (and its greedy
    episodes) = K + M on the reference engine; the learners hold what the reference's hold."""
    gm = load_map(map_name)
    s = run_settings(gm, overrides)
    kernel = compiled.Kernel(algo, gm, s, 5, 2)
    first = kernel.play(150)
    team = compiled.team_of(kernel)
    reference = reference_team(algo, gm, s, 5, 2)
    assert first.tobytes() == engine.record.table(reference.episode() for _ in range(150)).tobytes()
    for ours, theirs in zip(team.learners, reference.learners):
        assert_same_tables(ours, theirs)
        if algo in compiled.CQS:
            assert list(ours.q_joint.items()) == list(theirs.q_joint.items())
            assert (ours.confidence, ours.marked, ours.watch) == (theirs.confidence, theirs.marked, theirs.watch)
            for a, b in zip(ours.windows, theirs.windows):
                assert [getattr(a, f) for f in a.__slots__] == [getattr(b, f) for f in b.__slots__]
    assert team.world._rng.getstate() == reference.world._rng.getstate()
    then = engine.record.table(team.episode() for _ in range(50))
    assert then.tobytes() == engine.record.table(reference.episode() for _ in range(50)).tobytes()
    assert engine.greedy_episodes(team, 3).tobytes() == engine.greedy_episodes(reference, 3).tobytes()


@pytest.mark.parametrize("algo,map_name,overrides", [
    ("indep", "tunnel_to_goal", {}), ("cq", "tunnel_to_goal_3", {}),
    ("cq", "tunnel_to_goal_3", {"slip": 0.1, "start_hold": 2, "conf_down": 0.3}),
    ("cq_paper", "tunnel_to_goal", {"epsilon_decay_episodes": 150}),
    ("near", "tunnel_to_goal_3", {"slip": 0.1}), ("loc", "tunnel_to_goal_3", {"epsilon_decay_episodes": 150}),
    ("js", "tunnel_to_goal", {"start_hold": 2}), ("jsa", "tunnel_to_goal_3", {"epsilon_decay_episodes": 150})])
def test_a_run_learnt_by_the_reference_goes_on_in_the_kernel(algo, map_name, overrides, tmp_path):
    """K episodes on the reference engine, its learners saved as agent checkpoints and loaded back into a team
    turned into the kernel's arrays, M more in the kernel (and its greedy episodes) = K + M on the reference
    engine; handed back, the learners are the reference's. The team itself, not loaded, turns into the same."""
    import copy

    from agent_node.checkpoint import load_checkpoint, save_checkpoint

    gm = load_map(map_name)
    s = run_settings(gm, overrides)
    team = reference_team(algo, gm, s, 7, 1)
    engine.record.table(team.episode() for _ in range(150))
    for k, learner in enumerate(team.learners):
        save_checkpoint(tmp_path / f"agv{k}.npz", learner, 149)
    loaded = [load_checkpoint(tmp_path / f"agv{k}.npz", algo, gm, k, s)[0] for k in range(len(team.learners))]
    kernel = compiled.kernel_of(engine.Team(copy.deepcopy(team.world), loaded))
    direct = compiled.kernel_of(copy.deepcopy(team))
    if algo in compiled.CQS:
        theirs = [(k, *js) for k, learner in enumerate(team.learners) for js in learner.joint_states()]
        assert theirs, "a CQ run that marks nothing compares too little"
        assert kernel.joint_states() == theirs
    greedy = kernel.greedy().play(3)
    assert greedy.tobytes() == engine.greedy_episodes(team, 3).tobytes()
    played = kernel.play(60)
    assert played.tobytes() == engine.record.table(team.episode() for _ in range(60)).tobytes()
    assert direct.play(60).tobytes() == played.tobytes()
    for ours, theirs in zip(compiled.team_of(kernel).learners, team.learners):
        assert_same_tables(ours, theirs)
        if algo in compiled.CQS:
            assert list(ours.q_joint.items()) == list(theirs.q_joint.items())
            assert (ours.confidence, ours.marked, ours.watch) == (theirs.confidence, theirs.marked, theirs.watch)


def test_windows_keep_rewards_the_world_does_not_pay_bit_for_bit():
    """The kernel stores a window's samples as kinds (indices into the rewards it knows): a learner handed over
    holding rewards the world here does not pay (a checkpoint of other settings) comes back with the very same
    floats, -0.0 apart from 0.0, and its windows' sums as they were."""
    values = np.array([-1.0, 0.0, -0.0, 0.0, 0.1, 100.0, -1.0])
    kinds, vals = kinds_of(np.array([-1.0, -1.0, -10.0, 100.0]), values)
    assert vals[kinds].view(np.uint64).tolist() == values.view(np.uint64).tolist()
    assert kinds[0] == 0 and kinds[5] == 3 and len(vals) == 7
    gm = load_map("tunnel_to_goal_3")
    team = reference_team("cq", gm, run_settings(gm, {"window": 3}), 7, 1)
    odd = [0.1, -0.0, 0.0, -1.0, 1e300, -0.0, 7.5]
    for w, windows in enumerate(team.learners[0].windows[:len(odd)]):
        for r in odd[w:]:
            windows.add(r)
    before = [repr([getattr(w, f) for f in w.__slots__]) for w in team.learners[0].windows]
    back = compiled.team_of(compiled.kernel_of(team)).learners[0].windows
    assert [repr([getattr(w, f) for f in w.__slots__]) for w in back] == before


@pytest.mark.parametrize("algo", KERNEL_ALGORITHMS)
@pytest.mark.parametrize("eval_learning", [0, 1])
def test_greedy_copies_leave_the_run_as_it_was_and_a_frozen_one_shares_what_was_learnt(algo, eval_learning,
                                                                                      monkeypatch):
    """A greedy copy plays what the reference's (a deep copy) plays and leaves the kernel as it was: it plays on
    as the reference's team. A frozen copy shares the learnt arrays instead of copying them (only a learning step
    writes them); run, done with its kernel, plays the greedy episodes on it and gives what a copy gives."""
    gm = load_map("tunnel_to_goal_3")
    s = run_settings(gm, {"eval_learning": eval_learning, "eval_episodes": 3})
    kernel, team = compiled.Kernel(algo, gm, s, 5, 1), reference_team(algo, gm, s, 5, 1)
    assert kernel.play(100).tobytes() == engine.record.table(team.episode() for _ in range(100)).tobytes()
    learnt = [a.copy() for a in kernel.learnt()]
    greedy = kernel.greedy()
    assert {np.shares_memory(a, b) for a, b in zip(kernel.learnt(), greedy.learnt())} == {not eval_learning}
    assert greedy.play(3).tobytes() == engine.greedy_episodes(team, 3).tobytes()
    assert all(np.array_equal(a, b) for a, b in zip(learnt, kernel.learnt()))
    assert kernel.play(20).tobytes() == engine.record.table(team.episode() for _ in range(20)).tobytes()

    def refused(*_):
        raise AssertionError("compiled.run copied its kernel")

    copied = engine.greedy_episodes(team, 3)
    with monkeypatch.context() as patch:
        patch.setattr(compiled.copy, "deepcopy", refused)
        played = compiled.run(algo, gm, s, 5, 1, 120)
    assert played.greedy.tobytes() == copied.tobytes()


def test_experiment_plays_compiled_by_default_and_says_which_engine(tmp_path):
    """The lab's experiment: the kernel plays every learner (the manifest says so), and --engine reference
    writes the same files."""
    import json

    from cq_ros.lab.experiment import experiment
    from cq_ros.lab.results import MANIFEST

    written = {}
    for engine_name in ("compiled", "reference"):
        out = experiment("tunnel_to_goal", ["indep", "jsa", "cq"], 2, 60, 4, tmp_path / engine_name, workers=1,
                         figures=False, engine=engine_name)
        manifest = json.loads((out / MANIFEST).read_text())
        written[engine_name] = [(out / f).read_bytes() for f in (EPISODES, GREEDY, OBSERVE)]
        assert manifest["engine"] == {"indep": engine_name, "jsa": engine_name, "cq": engine_name}
    assert written["compiled"] == written["reference"]


@pytest.mark.parametrize("algo", KERNEL_ALGORITHMS)
@pytest.mark.parametrize("greedy,episode", [(False, 40), (True, None)])
def test_render_films_what_the_reference_films(algo, greedy, episode):
    from cq_ros.lab.render import engine_frames

    gm, s = load_map("tunnel_to_goal_3"), Settings()
    ours = engine_frames(gm, algo, s, 1, 60, episode, greedy=greedy)
    assert ours == engine_frames(gm, algo, s, 1, 60, episode, greedy=greedy, engine="reference")


def test_without_numba_the_reference_plays_with_one_line_saying_so():
    import subprocess
    import sys

    probe = ("import sys; sys.modules['numba'] = None\n"  # `import numba` now raises ImportError
             "from cq_ros import compiled\nfrom cq_ros.gridmap import load_map\nfrom cq_ros.settings import Settings\n"
             "r = compiled.play('cq', load_map('tunnel_to_goal'), Settings(eval_episodes=2), 0, 0, 5)\n"
             "print(r.engine, r.episodes.shape[0], r.greedy.shape[0])")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["reference", "5", "2"]
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1
    assert "the compiled engine cannot load" in lines[0] and "the reference engine plays" in lines[0]


"""Tests of cq_ros.student_t: the t quantile CQ's tests use, computed without scipy, against scipy; and that
a process playing CQ never loads scipy."""

import functools
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.stats

from cq_ros.student_t import upper_quantile

ROOT = Path(__file__).resolve().parents[1]
SIGNIFICANCES = [float(p) for p in np.geomspace(1e-4, 0.49, 25)] + [0.001, 0.01, 0.05, 0.1, 0.25]
DEGREES = [*range(1, 41), 59, 77, 99, 118, 199, 238, 500, 999, 1000]


@pytest.mark.parametrize("df", DEGREES)
def test_agrees_with_scipy_over_the_grid(df):
    for p in SIGNIFICANCES:
        ours = upper_quantile(p, df)
        assert math.isclose(ours, -scipy.stats.t.ppf(p, df), rel_tol=1e-12), (p, df)
        assert math.isclose(scipy.stats.t.sf(ours, df), p, rel_tol=1e-12), (p, df)


@pytest.mark.parametrize("p", [0.49, 0.499, 0.4999, 0.49999999])
def test_next_to_the_centre(p):
    """Within 0.01 of p = 1/2 scipy's own ppf loses digits (df = 4 at p = 0.4999: 1.6e-9 relative) and so does
    its sf (8e-14 for the Cauchy at 0.4999), so the checks there are the closed forms of df = 1 and 2 and
    the round trip through sf to scipy's precision."""
    assert math.isclose(upper_quantile(p, 1), math.tan(math.pi * (0.5 - p)), rel_tol=1e-14)
    assert math.isclose(upper_quantile(p, 2), (1 - 2 * p) / math.sqrt(2 * p * (1 - p)), rel_tol=1e-14)
    for df in (3, 4, 5, 60, 1000):
        ours = upper_quantile(p, df)
        assert math.isclose(scipy.stats.t.sf(ours, df), p, rel_tol=1e-12), df
        # near t = 0 the tail falls at the density's rate: (1/2 - p) / t is the density at 0, to first order
        assert math.isclose((0.5 - p) / ours, scipy.stats.t.pdf(0.0, df), rel_tol=1e-3), df


def test_the_centre_and_the_lower_half():
    assert upper_quantile(0.5, 7) == 0.0
    for df in (1, 7, 300):
        for p in (2 ** -14, 0.0625, 0.25):  # 1 - p is exact
            assert upper_quantile(1 - p, df) == -upper_quantile(p, df)
    assert math.isclose(upper_quantile(0.05, 1), math.tan(math.pi * 0.45), rel_tol=1e-14)  # Cauchy, exactly


def test_far_tails_and_many_degrees():
    for p, df in [(1e-12, 1), (1e-12, 3), (1e-9, 1000), (0.05, 100_000)]:
        assert math.isclose(upper_quantile(p, df), -scipy.stats.t.ppf(p, df), rel_tol=1e-11), (p, df)


@pytest.mark.parametrize("p, df", [(0.0, 5), (1.0, 5), (-0.2, 5), (0.05, 0), (0.05, 2.5)])
def test_bad_arguments(p, df):
    with pytest.raises(ValueError):
        upper_quantile(p, df)


def test_playing_cq_loads_no_scipy():
    """A CQ worker imports the learner, builds one per agent and plays: none of that needs scipy (about a
    second of CPU per process when it did)."""
    probe = ("import sys\n"
             "import cq_ros.learners.cq\n"
             "from cq_ros.engine import run\n"
             "from cq_ros.gridmap import load_map\n"
             "from cq_ros.settings import Settings\n"
             "result = run('cq', load_map('tunnel_to_goal'), Settings(eval_episodes=1), 7, 0, 2)\n"
             "assert len(result.episodes) == 2\n"
             "print(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy'))\n")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_cq_plays_the_same_with_scipys_critical_values(monkeypatch):
    """The decisions rest on t < -critical value: CQ's runs are the same, record for record, whether the critical
    values are ours or scipy's (by hand, `cq-ros experiment` before and after wrote byte-identical files)."""
    from cq_ros import stats
    from cq_ros.engine import run
    from cq_ros.gridmap import load_map
    from cq_ros.settings import Settings

    # Eight seeds that each mark joint states within 300 episodes (one to three, at confidences from 3 to 10)
    settings = Settings(window=10, significance=0.01, eval_episodes=3, step_cap=500)
    tunnel, seeds = load_map("tunnel_to_goal"), range(8)
    ours = [run("cq", tunnel, settings, seed, 0, 300) for seed in seeds]
    monkeypatch.setattr(stats, "critical_t", functools.cache(lambda sig, df: float(-scipy.stats.t.ppf(sig, df))))
    theirs = [run("cq", tunnel, settings, seed, 0, 300) for seed in seeds]
    for a, b in zip(ours, theirs):
        assert a.joint_states  # conflicts were found: the tests decided something
        assert a.joint_states == b.joint_states
        assert np.array_equal(a.episodes, b.episodes) and np.array_equal(a.greedy, b.greedy)

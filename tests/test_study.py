"""The study's arithmetic (cq_ros.lab.study) on data whose answers are known: t intervals computed by hand
from printed t tables, pairing that removes a shared unit effect, bootstrap intervals of ratios that contain
the true ratio."""

import math

import numpy as np
import pytest

from cq_ros.lab.study import home_rate, makespan_ratio, mean_interval, paired_difference, ratio_interval

# Student t, two-sided 95% (the 0.975 quantile), from a printed table.
T_975 = {1: 12.7062047, 3: 3.1824463, 4: 2.7764451}


def test_mean_interval_is_the_hand_computed_t_interval():
    got = mean_interval([1, 2, 3, 4, 5])
    # sd = sqrt(2.5), n = 5: half = t(4) * sqrt(2.5 / 5)
    assert got.mean == 3
    assert got.half == pytest.approx(T_975[4] * math.sqrt(0.5), rel=1e-7)
    assert (got.low, got.high) == pytest.approx((3 - got.half, 3 + got.half))
    two = mean_interval([0, 2])  # sd = sqrt(2), n = 2: half = t(1) * sqrt(2) / sqrt(2)
    assert (two.mean, two.half) == pytest.approx((1, T_975[1]), rel=1e-7)
    assert two.show(2) == "1.00 ± 12.71"


def test_one_unit_has_a_mean_and_no_interval():
    got = mean_interval([0.5])
    assert got.mean == 0.5 and math.isnan(got.half)
    assert got.show(3) == "0.500"
    with pytest.raises(ValueError, match="at least one unit"):
        mean_interval([])


def test_pairing_removes_the_shared_unit_effect():
    units = np.array([0.0, 100.0, 200.0, 300.0])  # each map and run's own difficulty, shared by both learners
    a, b = units + [1.0, 1.2, 0.8, 1.0], units
    got = paired_difference(a, b)
    # differences 1, 1.2, 0.8, 1: mean 1, sd sqrt(0.08 / 3), n = 4
    assert got.mean == pytest.approx(1.0)
    assert got.half == pytest.approx(T_975[3] * math.sqrt(0.08 / 3) / 2, rel=1e-6)
    unpaired = mean_interval(a).half + mean_interval(b).half
    assert unpaired > 100 * got.half  # unpaired, the unit effect drowns the difference
    with pytest.raises(ValueError, match="same units"):
        paired_difference([1, 2], [1])


def test_a_ratio_without_noise_has_a_point_interval():
    den = [1.0, 2.0, 5.0, 0.5]
    got = ratio_interval([3 * d for d in den], den, seed=0)
    assert (got.mean, got.low, got.high) == pytest.approx((3, 3, 3))


def test_the_bootstrap_interval_contains_the_true_ratio():
    rng = np.random.default_rng(7)
    den, num = rng.exponential(1.0, 200), rng.exponential(3.0, 200)  # true ratio of means: 3
    got = ratio_interval(num, den, seed=1)
    assert got.low < 3 < got.high
    assert got.low < got.mean < got.high and got.high - got.low < 1.5
    assert ratio_interval(num, den, seed=1) == got  # seeded


def test_the_bootstrap_interval_covers_the_true_ratio_about_95_times_in_100():
    rng = np.random.default_rng(11)
    intervals = [ratio_interval(rng.poisson(2.0, 40), rng.poisson(1.0, 40), seed=s, resamples=2000)
                 for s in range(100)]  # true ratio of means: 2
    covered = sum(i.low <= 2 <= i.high for i in intervals)
    assert 85 <= covered <= 100


def test_a_zero_denominator_gives_an_infinite_ratio():
    got = ratio_interval([1, 2, 3], [0, 0, 0], seed=0)
    assert got.mean == got.low == got.high == math.inf


def test_home_rate_and_makespan_ratio():
    assert home_rate([0, 0, 1, 0]) == 0.75
    got = makespan_ratio([20, 30, 45], [10, 15, 15])  # ratios 2, 2, 3: mean 7/3, sd 1/sqrt(3)
    assert got.mean == pytest.approx(7 / 3)
    assert got.half == pytest.approx(4.3026527 * (1 / math.sqrt(3)) / math.sqrt(3), rel=1e-6)
    with pytest.raises(ValueError, match="same units"):
        makespan_ratio([1], [1, 2])

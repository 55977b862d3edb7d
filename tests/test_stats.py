"""Tests of cq_ros.stats: RewardWindows' running sums and ConflictTest's decisions against scipy.stats.

The reference is scipy: `ttest_ind(w2, w1, equal_var=True)` for the drop test and `ttest_1samp(w2, r)`
for the "last reward above W2" test, with alternative="less" for the decisions. Where scipy itself warns
of "catastrophic cancellation" (nearly identical data: its two-pass variance is then rounding noise, and
so is its decision), the reference is the same test in exact rational arithmetic instead; everywhere else
the exact test and scipy agree, which the degenerate-window test checks as well.
"""

import math
import random
import warnings
from fractions import Fraction

import numpy as np
import pytest
import scipy.special
import scipy.stats

from cq_ros.stats import ConflictTest, RewardWindows, critical_t

SIGNIFICANCES = (0.05, 0.01)
GAME_REWARDS = (0.0, -1.0, -10.0, 10.0)


def feed(seq, n):
    w = RewardWindows(n)
    flags = [w.add(float(x)) for x in seq]
    return w, flags


def scipy_drop(w1, w2):
    """(statistic, p-value of alternative 'less', scipy warned of precision loss)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = scipy.stats.ttest_ind(w2, w1, equal_var=True, alternative="less")
    return float(res.statistic), float(res.pvalue), _noisy(caught)


def scipy_above(w2, r):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = scipy.stats.ttest_1samp(w2, r, alternative="less")
    return float(res.statistic), float(res.pvalue), _noisy(caught)


def _noisy(caught):
    return any("catastrophic cancellation" in str(c.message) for c in caught)


def same_statistic(ours, ref, rel=1e-9, abs_tol=1e-12):
    if math.isnan(ref) or math.isnan(ours):
        return math.isnan(ref) and math.isnan(ours)
    if math.isinf(ref) or math.isinf(ours):
        return ours == ref
    return math.isclose(ours, ref, rel_tol=rel, abs_tol=abs_tol)


def exact_rejects(diff: Fraction, ss: Fraction, n: int, crit: float) -> bool:
    """t = diff / sqrt(ss / ((n - 1) n)) < -crit, in exact arithmetic (0/0 is nan: not significant)."""
    if ss == 0:
        return diff < 0  # -inf rejects; +inf and nan do not
    se2 = ss / ((n - 1) * n)
    return diff < 0 and diff * diff > Fraction(crit) ** 2 * se2


# --- random windows ----------------------------------------------------------------------------------


def random_stream(rng: np.random.Generator, n: int, kind: str, length: int) -> list[float]:
    """W1 from one distribution and everything after from another, often shifted down (a 'drop')."""
    shift = rng.choice([0.0, rng.uniform(0.0, 3.0)])
    if kind == "normal":
        loc, scale = rng.uniform(-10, 10), rng.uniform(0.1, 5)
        first = rng.normal(loc, scale, n)
        rest = rng.normal(loc - shift * scale, scale * rng.uniform(0.5, 2), length - n)
    elif kind == "integer":
        p1 = rng.dirichlet(np.ones(4))
        p2 = rng.dirichlet(np.ones(4))
        first = rng.choice(GAME_REWARDS, n, p=p1)
        rest = rng.choice(GAME_REWARDS, length - n, p=p2)
    else:  # mixed: game rewards, some with noise, some non-representable constants
        values = np.array(GAME_REWARDS + (-0.1, 0.3))

        def draw(k, p):
            out = rng.choice(values, k, p=p)
            noisy = rng.random(k) < 0.3
            out[noisy] += rng.normal(0, rng.uniform(0.01, 2), noisy.sum())
            return out

        first = draw(n, rng.dirichlet(np.ones(6)))
        rest = draw(length - n, rng.dirichlet(np.ones(6)))
    return [float(x) for x in np.concatenate([first, rest])]


@pytest.mark.parametrize("n", [5, 20, 60])
def test_random_windows_agree_with_scipy(n):
    rng = np.random.default_rng(1000 + n)
    tests = {sig: ConflictTest(n, sig) for sig in SIGNIFICANCES}
    crit2 = {sig: critical_t(sig, 2 * n - 2) for sig in SIGNIFICANCES}
    crit1 = {sig: critical_t(sig, n - 1) for sig in SIGNIFICANCES}
    outcomes = {("drop", True): 0, ("drop", False): 0, ("above", True): 0, ("above", False): 0}
    checks = 0
    trials = {5: 220, 20: 130, 60: 70}[n]
    for trial in range(trials):
        kind = ("normal", "integer", "mixed")[trial % 3]
        length = 2 * n + int(rng.integers(0, 6 * n))  # up to 6 slides past the first full W2
        seq = random_stream(rng, n, kind, length)
        w = RewardWindows(n)
        checkpoints = set(rng.integers(2 * n, length + 1, 4)) | {length}
        for t, x in enumerate(seq, start=1):
            full = w.add(x)
            assert full == (t >= 2 * n)
            if t not in checkpoints:
                continue
            w1, w2 = seq[:n], seq[t - n : t]
            stat, p, _ = scipy_drop(w1, w2)
            assert same_statistic(w.drop_t(), stat), (kind, n, t, w.drop_t(), stat)
            for r in (x, float(np.mean(w2) + rng.normal(0, 2) * (np.std(w2) + 0.1) / math.sqrt(n))):
                stat1, p1, _ = scipy_above(w2, r)
                assert same_statistic(w.above_t(r), stat1), (kind, n, t, r, w.above_t(r), stat1)
                for sig, ct in tests.items():
                    if abs(stat1 + crit1[sig]) > 1e-9 * crit1[sig]:  # skip exact-boundary ties
                        assert ct.reward_above_recent(w, r) == (p1 < sig), (kind, n, t, r, sig, stat1, p1)
                        outcomes[("above", p1 < sig)] += 1
            for sig, ct in tests.items():
                if abs(stat + crit2[sig]) > 1e-9 * crit2[sig]:
                    assert ct.rewards_dropped(w) == (p < sig), (kind, n, t, sig, stat, p)
                    outcomes[("drop", p < sig)] += 1
            checks += 1
    assert checks >= 4 * trials * 0.8
    # the sample exercises both decisions of both tests
    assert min(outcomes.values()) >= 20, outcomes


def test_many_slides_keep_the_running_sums_exact_enough():
    """Thousands of slides of one W2: the statistic still equals a fresh two-pass computation."""
    rng = np.random.default_rng(7)
    n = 20
    seq = [float(x) for x in rng.normal(3.0, 2.0, 2 * n + 5000)]
    w = RewardWindows(n)
    for t, x in enumerate(seq, start=1):
        w.add(x)
        if t >= 2 * n and t % 97 == 0:
            stat, _, _ = scipy_drop(seq[:n], seq[t - n : t])
            assert same_statistic(w.drop_t(), stat)
            stat1, _, _ = scipy_above(seq[t - n : t], x)
            assert same_statistic(w.above_t(x), stat1)


# --- degenerate windows ----------------------------------------------------------------------------


def _exact_parts(values):
    b = [Fraction(x) for x in values]
    mean = sum(b) / len(b)
    return mean, sum((x - mean) ** 2 for x in b)


def _constant_cases(n, rng):
    """Both windows one constant (a single distinct value; all zeros for c = 0), after various rewards
    passed through W2: none, integer game rewards, non-integer ones, an exact extra wrap of 0.1s."""
    fillers = [("none", []), ("one int", [rng.choice(GAME_REWARDS)]), ("wrap 0.1", [0.1] * n)]
    fillers += [(f"ints {i}", [rng.choice(GAME_REWARDS) for _ in range(rng.randrange(1, 4 * n))]) for i in range(2)]
    fillers += [(f"floats {i}", [rng.gauss(0, 3) for _ in range(rng.randrange(1, 4 * n))]) for i in range(4)]
    fillers += [(f"game+0.1 {i}", [rng.choice(GAME_REWARDS + (-0.1,)) for _ in range(rng.randrange(1, 4 * n))])
                for i in range(3)]
    for c in (0.0, 1.0, -1.0, -10.0, 10.0, 0.1, -0.1, 0.3, 0.7, 1 / 3, 1e-3):
        for fname, filler in fillers:
            yield f"const {c} both, filler {fname}", [c] * n, filler, [c] * n


def _other_cases(n, rng):
    floats = [rng.gauss(0, 3) for _ in range(2 * n + 3)]
    ints = [rng.choice(GAME_REWARDS) for _ in range(3 * n + 2)]
    fillers = (("none", []), ("ints", ints), ("floats", floats))
    for a, b in [(0.0, -10.0), (-10.0, 0.0), (0.0, -1.0), (10.0, 0.0), (0.1, -0.1), (-0.1, 0.1), (0.1, 0.2)]:
        for fname, filler in fillers:
            yield f"const {a} vs const {b}, filler {fname}", [a] * n, filler, [b] * n
    for c in (0.0, -1.0, 0.1):
        varied = [rng.choice(GAME_REWARDS) for _ in range(n)]
        varied[0] = 10.0 if varied[1] != 10.0 else 0.0  # not constant
        for fname, filler in fillers:
            yield f"W1 const {c}, W2 varied, filler {fname}", [c] * n, filler, varied
            yield f"W1 varied, W2 const {c}, filler {fname}", varied, filler, [c] * n
    for c, d in [(0.0, -10.0), (0.0, -1.0), (-0.1, -10.0), (0.1, 10.0), (-1.0, 0.0)]:
        for pos in (0, n // 2, n - 1):
            outlier = [c] * n
            outlier[pos] = d
            for fname, filler in fillers:
                yield f"W1 const {c}, W2 the same but one {d} at {pos}, filler {fname}", [c] * n, filler, outlier
    for i in range(6):  # integer game rewards with heavy repeats
        w1 = [rng.choice((0.0, 0.0, 0.0, -1.0)) for _ in range(n)]
        w2 = [rng.choice((0.0, -10.0, -10.0, -1.0)) for _ in range(n)]
        yield f"game rewards {i}", w1, ints, w2


def check_degenerate(n, cases):
    """Every case's decisions, both tests, both significance levels; returns the disagreements."""
    tests = {sig: ConflictTest(n, sig) for sig in SIGNIFICANCES}
    failures, count = [], 0
    for label, w1, filler, w2 in cases:
        w, flags = feed(w1 + filler + w2, n)
        assert flags[-1]
        count += 1
        _, p, noisy = scipy_drop(w1, w2)
        m1, ss1 = _exact_parts(w1)
        m2, ss2 = _exact_parts(w2)
        for sig, ct in tests.items():
            exact = exact_rejects(m2 - m1, ss1 + ss2, n, ct.t_two)
            if not noisy:
                assert exact == (p < sig), f"{label}: the exact reference disagrees with scipy"  # guards the oracle
            want = exact if noisy else p < sig
            if ct.rewards_dropped(w) != want:
                failures.append(f"N={n} {label}: rewards_dropped={not want} (drop_t={w.drop_t()}), "
                                f"scipy p={p}{' [scipy warned of precision loss: exact reference]' if noisy else ''}")
        for r in sorted(set(w2) | {0.0, -10.0, 10.0, w2[-1] + 0.1}):
            _, p1, noisy1 = scipy_above(w2, r)
            for sig, ct in tests.items():
                exact1 = exact_rejects(m2 - Fraction(r), ss2, n, ct.t_one)
                if not noisy1:
                    assert exact1 == (p1 < sig), f"{label}: the exact reference disagrees with scipy"
                want1 = exact1 if noisy1 else p1 < sig
                if ct.reward_above_recent(w, r) != want1:
                    failures.append(f"N={n} {label}: reward_above_recent({r})={not want1} (above_t={w.above_t(r)}), "
                                    f"scipy p={p1}{' [scipy warned: exact reference]' if noisy1 else ''}")
    assert count > 0
    return failures


@pytest.mark.parametrize("n", [5, 20, 60])
def test_constant_windows_same_decision_as_scipy(n):
    failures = check_degenerate(n, _constant_cases(n, random.Random(n)))
    assert not failures, f"{len(failures)} wrong decisions, e.g.:\n" + "\n".join(failures[:8])


@pytest.mark.parametrize("n", [5, 20, 60])
def test_other_degenerate_windows_same_decision_as_scipy(n):
    failures = check_degenerate(n, _other_cases(n, random.Random(100 + n)))
    assert not failures, f"{len(failures)} wrong decisions, e.g.:\n" + "\n".join(failures[:8])


def test_zero_spread_statistics_follow_scipys_conventions():
    n = 5
    w, _ = feed([0.0] * n + [-10.0] * n, n)
    assert w.drop_t() == -math.inf == scipy_drop([0.0] * n, [-10.0] * n)[0]
    assert w.above_t(0.0) == -math.inf and w.above_t(-20.0) == math.inf
    assert math.isnan(w.above_t(-10.0))
    w, _ = feed([-10.0] * n + [0.0] * n, n)
    assert w.drop_t() == math.inf
    w, _ = feed([0.0] * (2 * n), n)
    assert math.isnan(w.drop_t()) and math.isnan(scipy_drop([0.0] * n, [0.0] * n)[0])
    ct = ConflictTest(n, 0.05)
    assert not ct.rewards_dropped(w) and not ct.reward_above_recent(w, 0.0)  # nan: not significant
    assert ct.reward_above_recent(w, 1.0) and not ct.reward_above_recent(w, -1.0)


def test_constant_non_representable_reward_is_never_a_drop():
    """A (state, action) that always pays -0.1 (a step cost) must never look like a drop, however long."""
    for c in (-0.1, 0.1, 0.3, -0.7):
        for n in (5, 20, 60):
            ct = ConflictTest(n, 0.05)
            w = RewardWindows(n)
            for t in range(1, 8 * n):
                if w.add(c):
                    assert not ct.rewards_dropped(w), (c, n, t, w.drop_t())
                    assert not ct.reward_above_recent(w, c), (c, n, t, w.above_t(c))


def test_all_zeros_after_other_rewards_passed_through_w2():
    """W1 all 0; W2 saw non-integer rewards, then only 0s again: W2 equals W1, so no drop (scipy: nan)
    and a reward of 0 is not above W2's mean (scipy: nan)."""
    rng = random.Random(0)
    fillers = [(5, [0.7, 0.2])]  # the smallest case: W2 is 0, 0, 0, 0, 0 again after 0.7 and 0.2 went through
    fillers += [(n, [rng.gauss(0, 3) for _ in range(rng.randrange(1, 4 * n))]) for n in (5, 20, 60) for _ in range(30)]
    failures = []
    for n, filler in fillers:
        ct = ConflictTest(n, 0.05)
        w, _ = feed([0.0] * n + filler + [0.0] * n, n)
        if ct.rewards_dropped(w) or ct.reward_above_recent(w, 0.0):
            failures.append((n, len(filler), w.drop_t(), w.above_t(0.0), w.sum2, w.sq2))
    assert math.isnan(scipy_drop([0.0] * 5, [0.0] * 5)[1]) and math.isnan(scipy_above([0.0] * 5, 0.0)[1])
    assert not failures, (
        f"{len(failures)}/{len(fillers)} windows of zeros judged significant; "
        f"(N, len(filler), drop_t, above_t, sum2, sq2) = {failures[:4]}"
    )


# --- window bookkeeping ----------------------------------------------------------------------------


@pytest.mark.parametrize("n", [2, 5, 60])
def test_add_is_false_until_both_windows_are_full(n):
    rng = random.Random(n)
    seq = [rng.choice(GAME_REWARDS) + rng.random() for _ in range(5 * n + 3)]
    w = RewardWindows(n)
    for t, x in enumerate(seq, start=1):
        assert w.add(x) == (t >= 2 * n)
        if t >= n:
            # W1 is the first n rewards, for ever
            assert w.n1 == n
            assert math.isclose(w.sum1, math.fsum(seq[:n]), rel_tol=1e-12, abs_tol=1e-12)
            assert math.isclose(w.sq1, math.fsum(x * x for x in seq[:n]), rel_tol=1e-12, abs_tol=1e-12)
        if t > n:
            # W2 is the last min(n, t - n) rewards after those
            last = seq[max(n, t - n) : t]
            assert sorted(w.w2) == sorted(last)
            assert math.isclose(w.sum2, math.fsum(last), rel_tol=1e-9, abs_tol=1e-9)
            assert math.isclose(w.sq2, math.fsum(x * x for x in last), rel_tol=1e-9, abs_tol=1e-9)
        else:
            assert w.w2 == []


def test_w1_never_changes_after_it_is_full():
    w = RewardWindows(4)
    for x in (1.0, 2.0, 3.0, 4.0):
        w.add(x)
    frozen = (w.n1, w.sum1, w.sq1)
    for x in range(1000):
        w.add(float(x % 17) - 8.0)
        assert (w.n1, w.sum1, w.sq1) == frozen


def test_window_needs_two_samples():
    with pytest.raises(ValueError):
        RewardWindows(1)
    RewardWindows(2)


# --- critical values and the per-step path ------------------------------------------------------


@pytest.mark.parametrize("sig", [0.001, 0.01, 0.05, 0.1, 0.25])
@pytest.mark.parametrize("df", [1, 2, 4, 8, 19, 38, 59, 118, 1000])
def test_critical_t_agrees_with_scipy(sig, df):
    c = critical_t(sig, df)
    assert c > 0
    assert math.isclose(c, -scipy.stats.t.ppf(sig, df), rel_tol=1e-12)
    assert math.isclose(scipy.stats.t.cdf(-c, df), sig, rel_tol=1e-9)


def test_conflict_test_uses_the_right_degrees_of_freedom():
    for n in (2, 5, 60):
        for sig in SIGNIFICANCES:
            ct = ConflictTest(n, sig)
            assert math.isclose(ct.t_two, -scipy.stats.t.ppf(sig, 2 * n - 2), rel_tol=1e-12)
            assert math.isclose(ct.t_one, -scipy.stats.t.ppf(sig, n - 1), rel_tol=1e-12)


@pytest.mark.parametrize("sig, df", [(0.0, 5), (1.0, 5), (-0.1, 5), (0.05, 0), (0.05, -3)])
def test_critical_t_rejects_bad_arguments(sig, df):
    with pytest.raises(ValueError):
        critical_t(sig, df)


def test_no_scipy_call_in_the_per_step_path(monkeypatch):
    n = 20
    ct = ConflictTest(n, 0.05)
    windows = [RewardWindows(n) for _ in range(8)]
    fresh = -scipy.stats.t.ppf(0.0123, 77)  # before the patch

    def boom(*args, **kwargs):
        raise AssertionError("scipy called in the per-step path")

    for name in ("ppf", "cdf", "sf", "isf"):
        monkeypatch.setattr(scipy.stats.t, name, boom)
    for name in ("ttest_ind", "ttest_1samp", "ttest_ind_from_stats"):
        monkeypatch.setattr(scipy.stats, name, boom)
    for name in ("stdtr", "stdtrit"):
        monkeypatch.setattr(scipy.special, name, boom)

    rng = random.Random(3)
    decisions = 0
    for step in range(10_000):
        w = windows[step % len(windows)]
        r = rng.choice(GAME_REWARDS) if step < 3000 else rng.choice((-10.0, -10.0, 0.0))
        if w.add(r):
            if ct.rewards_dropped(w) and not ct.reward_above_recent(w, r):
                decisions += 1
    assert decisions > 0  # the drop was detected, without scipy
    # nor does a fresh critical value (not cached) need scipy: it is cq_ros.student_t's
    assert math.isclose(critical_t(0.0123, 77), fresh, rel_tol=1e-12)


# Rewards spread by 1e-3..1e-5 of their size: a sum of squared deviations 1e-6..1e-10 of the sum of squares,
# far above the running sums' rounding noise (stats._ROUNDING) yet far below any game reward's spread.
@pytest.mark.parametrize("relative", [1e-3, 1e-4, 1e-5])
def test_near_constant_windows_are_not_taken_for_constant_ones(relative):
    """Rewards a tiny but real spread apart are windows with a spread: our decisions are scipy's, both ways,
    not those of a zero-spread window (where any difference of means is an infinite t)."""
    rng = np.random.default_rng(7)
    n, level = 60, -1.0
    decided = {True: 0, False: 0}
    for trial in range(24):
        w1 = level + relative * rng.normal(0, 1, n)
        # W2 a little lower than W1: by a tenth of the spread up to a few spreads, so both decisions occur
        w2 = level + relative * (rng.normal(0, 1, n) - rng.uniform(0.0, 3.0) / math.sqrt(n) * (trial % 2) * 5)
        w, _ = feed(np.concatenate([w1, w2]), n)
        _, p, _ = scipy_drop(w1, w2)
        r = float(w2.mean() + relative * rng.normal(0, 1) / math.sqrt(n))
        _, p1, _ = scipy_above(w2, r)
        for sig in SIGNIFICANCES:
            ct = ConflictTest(n, sig)
            assert ct.rewards_dropped(w) == (p < sig), (relative, trial, sig, p)
            assert ct.reward_above_recent(w, r) == (p1 < sig), (relative, trial, sig, p1)
            decided[p < sig] += 1
    assert min(decided.values()) >= 10, decided

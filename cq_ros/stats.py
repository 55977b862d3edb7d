"""CQ-learning's statistics: the reward windows W1 and W2 of one (state, action) pair and the two
Student t-tests the paper runs on them every step, with O(1) work per step.

W1 keeps the first N rewards for ever; W2 slides over the last N after those (the paper's Figure 1).
Both keep running sums, so a test costs a few float operations; the critical values of the fixed
degrees of freedom are computed once (cq_ros.student_t, no scipy) and cached. Decisions agree with
`scipy.stats.ttest_ind(w2, w1, equal_var=True, alternative="less")` and
`scipy.stats.ttest_1samp(w2, r, alternative="less")` (see tests/test_stats.py).
"""

from __future__ import annotations

import math
from functools import lru_cache

from .student_t import upper_quantile

# Running sums carry rounding noise: a sum of squared deviations this small relative to the sum of
# squares is no spread, and at zero spread two means this close relative to their size are equal (W1 of
# sixty -0.1 rewards and W2 of sixty -0.1 rewards, summed in another order, must not differ). Otherwise a
# constant but non-representable reward would look like a significant drop.
_ROUNDING = 1e-12


@lru_cache(maxsize=None)
def critical_t(significance: float, df: int) -> float:
    """The one-sided critical value: reject "mean not lower" when t < -critical_t(significance, df)."""
    if not 0.0 < significance < 1.0:
        raise ValueError(f"significance must lie in (0, 1), got {significance}")
    if df < 1:
        raise ValueError(f"degrees of freedom must be at least 1, got {df}")
    return upper_quantile(significance, df)


def _spread(total: float, squares: float, n: int) -> float:
    """Sum of squared deviations from the mean, from running sums; 0 where it is rounding noise."""
    ss = squares - total * total / n
    return 0.0 if ss <= _ROUNDING * squares else ss


def _sums(values: list[float]) -> tuple[float, float]:
    return math.fsum(values), math.fsum(v * v for v in values)


def _t_or_inf(a: float, b: float, se2: float) -> float:
    """(a - b) / sqrt(se2), with scipy's conventions at zero spread (+-inf, or nan for 0/0)."""
    if se2 > 0.0:
        return (a - b) / math.sqrt(se2)
    if abs(a - b) <= _ROUNDING * (abs(a) + abs(b)):
        return math.nan
    return math.copysign(math.inf, a - b)


class RewardWindows:
    """W1 and W2 of one (state, action) pair, as running sums, plus the ring buffer W2 slides over.

    Sums are exact (math.fsum) whenever they matter for equality: W1's once it is full, W2's when it
    fills, once per full slide, and whenever W2 looks constant after it changed, since an all-equal
    window must give exactly equal means however its rewards came and went. Integer rewards, the game's
    own, keep the running sums exact by themselves, so that re-add is rare.
    """

    __slots__ = ("size", "n1", "w1", "sum1", "sq1", "w2", "head", "sum2", "sq2", "exact2")

    def __init__(self, size: int):
        if size < 2:
            raise ValueError(f"a window needs at least 2 samples for a t-test, got {size}")
        self.size = size
        self.n1 = 0
        self.w1: list[float] = []  # only until W1 is full: then its sums are all that is kept
        self.sum1 = 0.0
        self.sq1 = 0.0
        self.w2: list[float] = []
        self.head = 0  # the oldest sample of a full W2, replaced next
        self.sum2 = 0.0
        self.sq2 = 0.0
        self.exact2 = True  # sum2 and sq2 are the exact sums of W2

    def add(self, reward: float) -> bool:
        """Store a reward; True once both windows are full, so the tests below may run."""
        if self.n1 < self.size:
            self.n1 += 1
            self.w1.append(reward)
            self.sum1 += reward
            self.sq1 += reward * reward
            if self.n1 == self.size:
                self.sum1, self.sq1 = _sums(self.w1)
                self.w1 = []
            return False
        w2 = self.w2
        if len(w2) < self.size:
            w2.append(reward)
            self.sum2 += reward
            self.sq2 += reward * reward
            if len(w2) < self.size:
                return False
            self._resum()
            return True
        old = w2[self.head]
        w2[self.head] = reward
        self.head += 1
        if self.head == self.size:  # once per full slide, so the running sums cannot drift
            self.head = 0
            self._resum()
        elif reward != old:
            self.sum2 += reward - old
            self.sq2 += reward * reward - old * old
            self.exact2 = False
        return True

    def _resum(self) -> None:
        self.sum2, self.sq2 = _sums(self.w2)
        self.exact2 = True

    def _spread2(self) -> float:
        ss = _spread(self.sum2, self.sq2, self.size)
        if ss == 0.0 and not self.exact2:
            self._resum()
            ss = _spread(self.sum2, self.sq2, self.size)
        return ss

    def drop_t(self) -> float:
        """Pooled two-sample t statistic of W2 against W1 (negative: rewards have dropped)."""
        n = self.size
        ss = _spread(self.sum1, self.sq1, n) + self._spread2()
        # Pooled variance (ss / (2n - 2)) times (1/n + 1/n).
        return _t_or_inf(self.sum2 / n, self.sum1 / n, ss / (n - 1) / n)

    def above_t(self, reward: float) -> float:
        """One-sample t statistic of W2 against `reward` (negative: the reward lies above W2's mean)."""
        n = self.size
        ss = self._spread2()
        return _t_or_inf(self.sum2 / n, reward, ss / (n - 1) / n)


class ConflictTest:
    """The paper's two tests at one significance level, for windows of one size."""

    __slots__ = ("t_two", "t_one")

    def __init__(self, window: int, significance: float):
        self.t_two = critical_t(significance, 2 * window - 2)
        self.t_one = critical_t(significance, window - 1)

    def rewards_dropped(self, w: RewardWindows) -> bool:
        """Is W2's mean significantly below W1's?"""
        return w.drop_t() < -self.t_two

    def reward_above_recent(self, w: RewardWindows, reward: float) -> bool:
        """Is `reward` significantly above W2's mean?"""
        return w.above_t(reward) < -self.t_one

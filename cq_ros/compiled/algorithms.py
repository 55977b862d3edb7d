"""The learners the compiled engine plays, by name (every one today; one not named here would play on the
reference engine); importable where numba is not, so the choice of a run's engine needs no compiler."""

KERNEL_ALGORITHMS = ("indep", "cq", "cq_paper", "near", "loc", "js", "jsa")

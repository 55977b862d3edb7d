"""The algorithms behind one interface (`base.Learner`): the one registry of their names, classes, labels,
colours and order, which the engine, the command line, the summary, the plots and the reproduction all read."""

from dataclasses import dataclass

from .base import Learner
from .cq import CQLearner
from .cq_paper import CQPaperLearner
from .indep import IndependentQ
from .js import JointStateQ
from .jsa import JointStateActionQ, decode_joint_action
from .loc import LearningOfCoordination
from .near import NearQ


@dataclass(frozen=True)
class Algorithm:
    name: str  # as the command line, the result files and the ROS parameters spell it
    learner: type[Learner]
    label: str  # in figures and tables
    colour: str  # in figures: a hex colour (matplotlib's tab10), so the science imports no plotting code
    paper: bool  # one of the paper's five: the reproduction's grid

    @property
    def central(self) -> bool:
        """One learner moves every agent (JSA)."""
        return self.learner.central


# In order: the paper's five in its order (baselines first, its CQ last), then ours and what goes beyond it.
REGISTRY: tuple[Algorithm, ...] = (
    Algorithm("indep", IndependentQ, "Indep", "#7f7f7f", paper=True),
    Algorithm("js", JointStateQ, "JS", "#ff7f0e", paper=True),
    Algorithm("jsa", JointStateActionQ, "JSA", "#9467bd", paper=True),
    Algorithm("loc", LearningOfCoordination, "LoC", "#2ca02c", paper=True),
    Algorithm("cq_paper", CQPaperLearner, "CQ (paper)", "#17becf", paper=True),
    Algorithm("cq", CQLearner, "CQ", "#1f77b4", paper=False),
    Algorithm("near", NearQ, "Near", "#8c564b", paper=False),
)
assert all(a.name == a.learner.name for a in REGISTRY), "an algorithm's name is its learner's"

ALGORITHMS = tuple(a.name for a in REGISTRY if a.paper)
# The CQ learners (the paper's and ours), whose joint states the plots, the checkpoints and the kernel keep alike
CQ_LEARNERS = tuple(a.name for a in REGISTRY if issubclass(a.learner, CQPaperLearner))
# `cq-ros experiment`'s default: the paper's five and our CQ
DEFAULT_ALGORITHMS = (*ALGORITHMS, "cq")
LEARNERS: dict[str, type[Learner]] = {a.name: a.learner for a in REGISTRY}
_BY_NAME = {a.name: a for a in REGISTRY}


def algorithm(name: str) -> Algorithm:
    """The registry's entry of `name`; ValueError naming the known ones for any other."""
    if name not in _BY_NAME:
        raise ValueError(f"unknown algorithm {name!r}; algorithms are: {', '.join(_BY_NAME)}")
    return _BY_NAME[name]


def algo_sort_key(name: str) -> tuple[int, str]:
    """The registry's order; a name it does not know (an old result's) follows, alphabetically."""
    order = list(_BY_NAME)
    return (order.index(name) if name in order else len(order), name)


__all__ = ["ALGORITHMS", "CQ_LEARNERS", "DEFAULT_ALGORITHMS", "Algorithm", "LEARNERS", "Learner", "REGISTRY",
           "algo_sort_key", "algorithm", "decode_joint_action"]

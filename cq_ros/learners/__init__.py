"""The paper's five algorithms behind one interface (`base.Learner`), by name."""

from .base import Learner
from .cq import CQLearner
from .fcq import FutureCQLearner
from .indep import IndependentQ
from .js import JointStateQ
from .jsa import JointStateActionQ, decode_joint_action
from .loc import LearningOfCoordination
from .near import NearQ

# The paper's five, in its order; then what goes beyond it.
ALGORITHMS = ("indep", "js", "jsa", "loc", "cq")
LEARNERS: dict[str, type[Learner]] = {
    cls.name: cls
    for cls in (IndependentQ, JointStateQ, JointStateActionQ, LearningOfCoordination, CQLearner, FutureCQLearner,
                NearQ)
}

__all__ = ["ALGORITHMS", "LEARNERS", "Learner", "decode_joint_action"]

"""The paper's five algorithms behind one interface (`base.Learner`), by name."""

from .base import Learner
from .cq import CQLearner
from .indep import IndependentQ
from .js import JointStateQ
from .jsa import JointStateActionQ, decode_joint_action
from .loc import LearningOfCoordination

LEARNERS: dict[str, type[Learner]] = {
    cls.name: cls for cls in (IndependentQ, JointStateQ, JointStateActionQ, LearningOfCoordination, CQLearner)
}
ALGORITHMS = tuple(LEARNERS)

__all__ = ["ALGORITHMS", "LEARNERS", "Learner", "decode_joint_action"]

"""The limit learner's runs (cq_ros.learners.limit) as the held-out study plays a unit: held_out.Learning on the
reference engine, with the world and learner seeds a registry learner's run has (cq_ros.engine.run)."""

from ..engine import Team, learner_seed, world_seed
from ..gridmap import GridMap
from ..learners.limit import LEARNERS
from ..settings import Settings
from ..world import GridWorld
from .held_out import Learning


class LimitLearning(Learning):
    """held_out.Learning with the learners LEARNERS names (the unit's algo)."""

    def __init__(self, algo: str, gridmap: GridMap, settings: Settings, seed: int, run: int):
        self.kernel = None
        learner = LEARNERS[algo]
        self.team = Team(GridWorld(gridmap, settings, seed=world_seed(seed, run)),
                         [learner(i, gridmap, settings, learner_seed(seed, run, i)) for i in range(gridmap.n_agents)])

"""EXPERIMENTAL. CQ-learning tested on sampled Q-values: the paper's closing proposal for coordination
problems whose penalty comes some steps after the state where the agents should have coordinated.

The windows keep r + gamma * max_a Q_k(s', a) instead of r, so a conflict that lowers the value of the
cells inside a tunnel also lowers the samples of the cells that lead into it, and can be detected at the
entrance. This is the simplest reading of that sentence, not the authors' later FCQ-learning (which
compares returns against single-agent estimates learnt beforehand). It is experimental until it beats
CQ somewhere it should; it is not part of the paper's grid.
"""

from .cq import CQLearner


class FutureCQLearner(CQLearner):
    name = "fcq"

    @staticmethod
    def sample(reward, target):
        return target

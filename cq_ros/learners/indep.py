"""Independent Q-learners (the paper's "Indep"): each agent learns in its own cell, blind to the others."""

from .base import Learner, N_MOVES, epsilon_greedy, q_update


class IndependentQ(Learner):
    name = "indep"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.q_local = [[0.0] * N_MOVES for _ in range(self.n_cells)]

    def observe(self, cell):
        self.s = cell
        return ()

    def act(self, peer_cells):
        self.a = epsilon_greedy(self.q_local[self.s], self.epsilon, self.rng)
        return self.a

    def learn(self, reward, next_cell, done):
        if not self.learning:
            return
        target = reward if done else reward + self.gamma * max(self.q_local[next_cell])
        q_update(self.q_local[self.s], self.a, target, self.alpha)

    def state_count(self):
        return self.n_cells

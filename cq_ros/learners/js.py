"""Joint-state learners (the paper's "JS"): each agent sees every agent's cell and chooses its own move.

Its next state includes the peers' next cells, which it sees only when it next observes, so the update
of a step is finished at the next `act` (or at once, without bootstrap, when the agent reaches its goal).
A step cut by the step cap has no next state to bootstrap from and is left out rather than guessed.
"""

from .base import Learner, N_MOVES, epsilon_greedy, q_update


class JointStateQ(Learner):
    name = "js"
    joint_state = True

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.q_joint: dict[tuple, list[float]] = {}
        self.pending = None  # (row, action, reward) waiting for the next joint state

    def observe(self, cell):
        self.s = cell
        return self.peers

    def act(self, peer_cells):
        js = (self.s,) + tuple(peer_cells[j] for j in self.peers)
        row = self.q_joint.get(js)
        if row is None:
            row = [0.0] * N_MOVES
            if self.learning:
                self.q_joint[js] = row
        if self.pending is not None:
            prev, a, reward = self.pending
            q_update(prev, a, reward + self.gamma * max(row), self.alpha)
            self.pending = None
        self.row = row
        self.a = epsilon_greedy(row, self.epsilon, self.rng)
        self.joint_plays += 1
        self.heard += len(peer_cells)
        return self.a

    def learn(self, reward, next_cell, done):
        if not self.learning:
            return
        if done:
            q_update(self.row, self.a, reward, self.alpha)
        else:
            self.pending = (self.row, self.a, reward)

    def end_episode(self):
        super().end_episode()
        self.pending = None

    def state_count(self):
        return self.n_cells ** self.n_agents

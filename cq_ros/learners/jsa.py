"""Joint-state-action learner (the paper's "JSA"): one superagent sees every cell and chooses the joint
action, one of 4^n, learning from the sum of the agents' rewards. It is the centralised baseline, so it
moves all agents; its "cell" is the tuple of all cells and its action encodes agent i's move as digit i
in base 4 (`decode_joint_action`).
"""

from .base import Learner, N_MOVES, epsilon_greedy, q_update

MAX_AGENTS = 5  # 4^5 = 1024 joint actions per state; beyond that a table per state is no longer small


def decode_joint_action(action: int, n_agents: int) -> list[int]:
    return [(action // N_MOVES ** i) % N_MOVES for i in range(n_agents)]


class JointStateActionQ(Learner):
    name = "jsa"
    joint_state = True
    central = True

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self.n_agents > MAX_AGENTS:
            raise ValueError(f"jsa supports at most {MAX_AGENTS} agents (4^n joint actions), "
                             f"the map has {self.n_agents}")
        self.n_joint = N_MOVES ** self.n_agents
        self.q_joint: dict[tuple, list[float]] = {}

    def _row(self, js):
        row = self.q_joint.get(js)
        if row is None:
            row = [0.0] * self.n_joint
            if self.learning:
                self.q_joint[js] = row
        return row

    def observe(self, cells):
        self.s = tuple(cells)
        return ()

    def act(self, peer_cells):
        self.row = self._row(self.s)
        self.a = epsilon_greedy(self.row, self.epsilon, self.rng)
        self.joint_plays += 1
        return self.a

    def learn(self, reward, next_cells, done):
        if not self.learning:
            return
        target = reward if done else reward + self.gamma * max(self._row(tuple(next_cells)))
        q_update(self.row, self.a, target, self.alpha)

    def state_count(self):
        return self.n_cells ** self.n_agents

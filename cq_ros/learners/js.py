"""Joint-state learners (the paper's "JS"): each agent sees every agent's cell and chooses its own move.

Its next state includes the peers' next cells, which it sees only when it next acts: the update is finished
there (`next_state.NextStateLearner`).
"""

from .base import N_MOVES
from .next_state import NextStateLearner


class JointStateQ(NextStateLearner):
    name = "js"
    joint_state = True

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.q_joint: dict[tuple, list[float]] = {}

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
        self.joint_plays += 1
        self.heard += len(peer_cells)
        return self.act_on(row)

    def state_count(self):
        return self.n_cells ** self.n_agents

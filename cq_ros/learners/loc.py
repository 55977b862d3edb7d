"""Learning of Coordination (Melo & Veloso 2009; the paper's Algorithm 1, "LoC").

Each agent has a fifth action, COORDINATE, which triggers active perception: the agent looks at its
peers and, if one is close enough to collide this step (Manhattan distance <= COLLISION_REACH, 2), acts greedily
on Q^C over the joint state it perceives; otherwise it acts greedily on Q*'s moves. Q* learns the move
executed (line 18 of Algorithm 1) and, when COORDINATE was chosen, also COORDINATE itself, at the price
`loc_cost` of active perception: without that second update COORDINATE would keep its initial value
and never learn what coordinating is worth. Q^C learns only when the perception was TRUE, and
bootstraps from Q* of the next local state, as in Melo & Veloso (a joint table cannot be indexed by a
local state). A new joint state's Q^C starts as a copy of Q*'s moves, as CQ's Q^j does.
"""

from ..world import COLLISION_REACH
from .base import Learner, N_MOVES, epsilon_greedy, greedy, q_update

COORDINATE = N_MOVES


class LearningOfCoordination(Learner):
    name = "loc"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.q_local = [[0.0] * (N_MOVES + 1) for _ in range(self.n_cells)]  # Q*, with COORDINATE
        self.q_coord: dict[tuple, list[float]] = {}  # Q^C over perceived joint states
        self.range = COLLISION_REACH
        self.cost = self.settings.loc_cost

    def observe(self, cell):
        self.s = cell
        self.choice = epsilon_greedy(self.q_local[cell], self.epsilon, self.rng)
        return self.peers if self.choice == COORDINATE else ()

    def act(self, peer_cells):
        self.x = None
        if self.choice != COORDINATE:
            self.move = self.choice
            return self.move
        self.joint_plays += 1
        self.heard += len(peer_cells)
        near = tuple((j, c) for j, c in sorted(peer_cells.items()) if self.map.distance(self.s, c) <= self.range)
        if near:  # ActivePercept = TRUE
            self.x = (self.s, near)
            row = self.q_coord.get(self.x)
            if row is None:
                row = self.q_local[self.s][:N_MOVES]
                if self.learning:
                    self.q_coord[self.x] = row
            self.move = greedy(row, self.rng)
        else:
            self.move = greedy(self.q_local[self.s][:N_MOVES], self.rng)
        return self.move

    def learn(self, reward, next_cell, done):
        if not self.learning:
            return
        future = 0.0 if done else self.gamma * max(self.q_local[next_cell])
        if self.x is not None:
            q_update(self.q_coord[self.x], self.move, reward + future, self.alpha)
        q_update(self.q_local[self.s], self.move, reward + future, self.alpha)
        if self.choice == COORDINATE:
            q_update(self.q_local[self.s], COORDINATE, reward - self.cost + future, self.alpha)

    def state_count(self):
        return self.n_cells + len(self.q_coord)

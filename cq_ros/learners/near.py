"""The learner that watches every peer within reach at every step ("near"): the baseline for CQ's economy.

Its state is its own cell and the cells of the peers at most COLLISION_REACH (2) cells away (Manhattan:
close enough to collide this step), looked at every step: what an AGV with a range-limited sensor, or a radio that
hears only its neighbours, would know. It is Q-learning on that state, so it can condition on a peer
wherever CQ might, but it looks everywhere, all the time. What it hears is the positions of the peers in
range, step by step (`heard`): the least that a learner watching every peer within that range must hear.

A state with no peer in range is the cell alone (`q_local`); a new state with peers (`q_near`) starts as a
copy of its cell's row. As in JS, the next state includes the peers in range then, seen only at the next
`act`, where a step's update is finished (`next_state.NextStateLearner`).
"""

from ..world import COLLISION_REACH
from .base import N_MOVES
from .next_state import NextStateLearner


class NearQ(NextStateLearner):
    name = "near"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.range = COLLISION_REACH
        self.q_local = [[0.0] * N_MOVES for _ in range(self.n_cells)]
        self.q_near: dict[tuple, list[float]] = {}

    def observe(self, cell):
        self.s = cell
        return self.peers  # to know who is in range (what it hears is only those: `heard`)

    def act(self, peer_cells):
        near = tuple((j, c) for j, c in sorted(peer_cells.items()) if self.map.distance(self.s, c) <= self.range)
        self.heard += len(near)
        if near:
            self.joint_plays += 1
            row = self.q_near.get((self.s, near))
            if row is None:
                row = list(self.q_local[self.s])
                if self.learning:
                    self.q_near[(self.s, near)] = row
        else:
            row = self.q_local[self.s]
        return self.act_on(row)

    def state_count(self):
        return self.n_cells + len(self.q_near)

"""The learner that watches every peer within reach at every step ("near"): the baseline for CQ's economy.

Its state is its own cell and the cells of the peers at most `near_range` cells away (Manhattan; 2 is close
enough to collide this step), looked at every step: what an AGV with a range-limited sensor, or a radio that
hears only its neighbours, would know. It is Q-learning on that state, so it can condition on a peer
wherever CQ might, but it looks everywhere, all the time. What it hears is the positions of the peers in
range, step by step (`heard`): the least that a learner watching every peer within that range must hear.

A state with no peer in range is the cell alone (`q_local`); a new state with peers (`q_near`) starts as a
copy of its cell's row. As in JS, the next state includes the peers in range then, seen only at the next
`act`, so a step's update is finished there (at once, without bootstrap, when the agent reaches its goal;
a step cut by the step cap is left out).
"""

from .base import Learner, N_MOVES, epsilon_greedy, q_update


class NearQ(Learner):
    name = "near"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.range = self.settings.near_range
        self.q_local = [[0.0] * N_MOVES for _ in range(self.n_cells)]
        self.q_near: dict[tuple, list[float]] = {}
        self.pending = None  # (row, action, reward) waiting for the next state

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
        if self.pending is not None:
            prev, a, reward = self.pending
            q_update(prev, a, reward + self.gamma * max(row), self.alpha)
            self.pending = None
        self.row = row
        self.a = epsilon_greedy(row, self.epsilon, self.rng)
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
        return self.n_cells + len(self.q_near)

"""Our CQ-learning, `cq`: the paper's Algorithm 2 (cq_paper.CQPaperLearner) with six rules of ours, the same
on every map. Each rule is one method below, in place of the paper's reading of it (which calls none of
super(), so that a test composes the paper's learner with any one of them); docs/choices.md gives why and what
each changes, measured.

- W1 starts full of what acting alone earns: under delays a conflict is there from the first episode on, and
  the first rewards are no measure of being alone (the earlier CQ-learning of De Hauwere et al. 2010 took W1
  from a single-agent phase).
- A greedy agent does not look where Q_k and every Q^j of the cell agree on one strictly best action:
  whatever it saw it would do the same, and a look it cannot act on is a message paid for nothing.
- Where several joint states are met at once, it acts on the elementwise minimum of their rows and updates
  each: the most confident alone is blind to the peers the others name.
- An update bootstraps from the row the agent acts on next (Q^j where a joint state is met), so that
  waiting in a joint state is valued as waiting, not as the free road Q_k of the same cell promises.
- A conflict marks only the peers that could have collided with the agent at the step: none if the agent
  moved (a collision leaves it where it was), else those now at most one cell from the cell it moved toward
  or from its own; a peer anywhere else cannot have caused the step's low reward, and each joint state is a
  peer asked about at every visit of its cell for as long as it is kept.
- A new Q^j values each wait (a move into a wall) at least at one step lost plus the free road: Q_k's waits
  hold what early exploration left, never tried again once it stops, and a Q^j copied from them would not
  wait where the joint state says it must.
"""

from ..world import rewards_alone
from .base import N_MOVES
from .cq_paper import CQPaperLearner


def unique_best(row):
    """The action of a row's largest value if no other action ties with it, else None."""
    best = max(row)
    return row.index(best) if row.count(best) == 1 else None


class CQLearner(CQPaperLearner):
    name = "cq"

    def _start_windows(self):
        """W1 full of what acting alone earns (the world's reward for each move with nobody else, a share slip
        of them delayed)."""
        st = self.settings
        for s in range(self.n_cells):
            for a in range(N_MOVES):
                for r in rewards_alone(self.map, st, self.agent, s, a, st.window):
                    self.windows[s * N_MOVES + a].add(r)

    def _looks(self, cell):
        """Not where looking cannot change the greedy action: epsilon is 0, Q_k and every Q^j of the cell have
        one and the same unique best action (so has the elementwise minimum of any of the Q^j), and no waiting
        update is about to land in one of them (the agent stayed in the cell), since that update's target
        depends on the row acted on, hence on looking."""
        if self.epsilon != 0:
            return True
        if self.waiting is not None and not self.waiting.learnt and self.waiting.cell == cell:
            return True
        rows = [self.q_local[cell], *(self.q_joint[js] for js in self.marked[cell])]
        a = unique_best(rows[0])
        return a is None or any(unique_best(row) != a for row in rows[1:])

    def _acted_on(self, met):
        return met  # acted on through the elementwise minimum of their rows (_acted_row)

    def _bootstraps_from_next_act(self):
        return True

    def _bootstrap(self, step, next_row):
        return next_row if next_row is not None else CQPaperLearner._bootstrap(self, step, next_row)

    def _marks(self, step, peer_cell):
        """A peer that can have collided with the agent at `step`: the agent stayed (agents in a collision
        stay), and the peer is at most one cell from where the agent moved toward (both moved into it, a swap,
        or the agent ran into the peer) or from the agent's own cell (the peer ran into it as it stayed)."""
        if step.next_cell != step.cell:
            return False
        toward = self.map.neighbours[step.cell][step.action]
        return min(self.map.distance(toward, peer_cell), self.map.distance(step.cell, peer_cell)) <= 1

    def _new_row(self, s):
        row = CQPaperLearner._new_row(self, s)
        floor = self.settings.reward_wall + self.gamma * max(row)
        for a, to in enumerate(self.map.neighbours[s]):
            if to == s:  # a wait: the move bumps into a wall and leaves the agent where it is
                row[a] = max(row[a], floor)
        return row

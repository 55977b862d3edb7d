"""The limit learner: an oracle that looks at the right peer at the right cell only, the yardstick of what a
looking learner could reach on the held-out study's units (benchmarks/limit_learner.py plays it there).

`LimitQ` is near (cq_ros/learners/near.py: Q-learning on its own cell and the cells of the peers it conditions
on, a new joint row a copy of its cell's) with near's "every peer within 2 cells" replaced by an oracle: at each
step it conditions its row on, and hears, exactly the peers that can collide with it this step under the
world's rules (cq_ros/world.py), whatever the two of them and everyone else do and whoever is delayed.
A colliding pair ends the step in one cell, or swaps; each of the two ends either where it stands or in the
cell its move leads to (agents in a collision go back), so agent i in cell s and peer j in cell c can collide
this step exactly when the cells i can end in, REACH(s) = {s} and the cells its four moves lead to (a wall bump
leads to s), and the cells j can end in, REACH(c) (only {c} for a peer at its goal, which never moves again and
stands there as an obstacle), share a cell x, other than a goal the two share (the one cell two agents may
share). Every such x is a collision under some joint move while slip is above 0: both move into x; or x = s and
j moves into s while i is delayed; or x = c and i moves into c while j is delayed; a swap (s -> c, c -> s) needs
s in REACH(c), so it is counted already. Those peers are all within 2 cells (Manhattan): a subset of near's.

It is an oracle, a yardstick, not a candidate algorithm: it reads every peer's cell and goal (ground truth a
deployed AGV does not have) to decide whom it hears, and hears (`heard`) only those. So it is not in the
algorithm registry (no `cq-ros experiment`, ROS node, checkpoint format or compiled twin for it); it plays on
the reference engine (cq_ros.lab.limit).
"""

from .base import epsilon_greedy, q_update
from .near import NearQ


class LimitQ(NearQ):
    """Near whose joint state holds only the peers that can collide with it this step (the module's docstring)."""

    name = "limit"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        nbr = self.map.neighbours
        self.reach = [frozenset((c, *nbr[c])) for c in range(self.n_cells)]  # REACH(c): c and where its moves lead
        # the cells c whose REACH(c) meets REACH(s): moves are open both ways (x in REACH(c) exactly when c is in
        # REACH(x)), so they are the cells reached from REACH(s)
        self.meet = [frozenset(c for x in self.reach[s] for c in self.reach[x]) for s in range(self.n_cells)]
        self.goals = self.map.goals

    def could_collide(self, cell: int, peer: int, peer_cell: int) -> bool:
        """Whether `peer`, in `peer_cell`, can collide with this agent, in `cell`, this step."""
        goal = self.goals[peer]
        if goal == self.goals[self.agent]:  # a shared goal, the one cell two agents may both end in
            there = (peer_cell,) if peer_cell == goal else self.reach[peer_cell]
            return any(x in self.reach[cell] and x != goal for x in there)
        # at its goal the peer stays for good: only a move into its cell can collide with it
        return peer_cell in (self.reach[cell] if peer_cell == goal else self.meet[cell])

    def act(self, peer_cells):
        s = self.s
        near = tuple((j, c) for j, c in sorted(peer_cells.items()) if self.could_collide(s, j, c))
        self.heard += len(near)
        if near:
            self.joint_plays += 1
            row = self.q_near.get((s, near))
            if row is None:
                row = list(self.q_local[s])
                if self.learning:
                    self.q_near[(s, near)] = row
        else:
            row = self.q_local[s]
        return self.act_on(row)


class LimitCQ(LimitQ):
    """The same oracle's peers, hears the same, but in CQ's tables: a row per (cell, peer, peer's cell), a copy of
    the cell's row when new, acted on through the elementwise minimum of the rows of the peers heard (our CQ's
    rule for several joint states met), the step's update made in each of them (Q_k where nobody can collide).
    What it learns is then what CQ with perfect marks, met everywhere they matter, could learn; near's joint
    rows need every combination of the peers heard."""

    name = "limit_cq"

    def act(self, peer_cells):
        s = self.s
        keys = [(s, j, c) for j, c in sorted(peer_cells.items()) if self.could_collide(s, j, c)]
        self.heard += len(keys)
        rows = [self.q_local[s]]
        if keys:
            self.joint_plays += 1
            rows = []
            for key in keys:
                row = self.q_near.get(key)
                if row is None:
                    row = list(self.q_local[s])
                    if self.learning:
                        self.q_near[key] = row
                rows.append(row)
        acted = rows[0] if len(rows) == 1 else [min(q) for q in zip(*rows)]
        last, self.waiting = self.waiting, None
        if last is not None:
            self._update(last, acted)
        self.row = rows
        self.a = epsilon_greedy(acted, self.epsilon, self.rng)
        return self.a

    def _update(self, step, next_row):
        rows, a, reward = step
        target = reward if next_row is None else reward + self.gamma * max(next_row)
        for row in rows:
            q_update(row, a, target, self.alpha)


LEARNERS = {learner.name: learner for learner in (LimitQ, LimitCQ)}

"""CQ-learning (De Hauwere, Vrancx & Nowé 2011, the paper's Algorithm 2).

Each agent learns Q_k over its own cell. For every (cell, action) it keeps the reward windows W1 (the
first N rewards) and W2 (the last N after those). When W2's mean falls significantly below W1's and
the last reward is not significantly above W2's mean, the rewards of that cell have turned worse than
when the agent was effectively alone: it marks the joint states (cell, peer, peer's cell) for every
peer, seen at that moment, each with Q^j copied from Q_k and a confidence value.

In a cell with marked joint states the agent looks at the peers they name (and only those): if one is
met, it acts on Q^j and that joint state gains confidence; those not met lose confidence and are
dropped below a threshold. Everywhere else it acts on Q_k, seeing no one. Q^j bootstraps from Q_k of
the next cell, since the agent cannot know it will need coordination at the next step.

"At that moment" is when the conflict is detected, i.e. once the step's rewards are in: the agent sees
its peers at the start of its next step, before acting. For a collision this is also the joint state
the agent acted in, since colliding agents stay where they were.

Under delays (cq_w1_alone, ours, off by default): W1 can be filled with what acting alone earns instead of
the first N rewards, since where AGVs are delayed a conflict is there from the first episode on and the
first rewards are no measure of being alone (the earlier CQ-learning of De Hauwere et al. 2010 took W1 from
a single-agent phase).

Three choices of ours, each a setting whose other value is the paper's reading (docs/choices.md): only
the peers within `cq_mark_range` cells are marked; an update waits one step and bootstraps from the row
the agent then acts on (`cq_bootstrap_acted`), so waiting in a joint state is not valued by Q_k's free
road; and where several joint states are met at once, the agent acts on the elementwise minimum of their
rows and updates each (`cq_all_met`).

Looking only where it can matter (`cq_look_if_decisive`, ours, off by default): a greedy agent skips looking at
a marked cell whose Q_k and every Q^j agree on one strictly best action, since whatever it saw it would do
the same; a look it cannot act on is a message paid for nothing (issue 18).
"""

from ..stats import ConflictTest, RewardWindows
from .base import Learner, N_MOVES, epsilon_greedy, q_update


def unique_best(row):
    """The action of a row's largest value if no other action ties with it, else None."""
    best = max(row)
    return row.index(best) if row.count(best) == 1 else None


class CQLearner(Learner):
    name = "cq"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        st = self.settings
        self.q_local = [[0.0] * N_MOVES for _ in range(self.n_cells)]  # Q_k
        self.q_joint: dict[tuple, list[float]] = {}  # Q^j, keyed by joint state (cell, peer, peer_cell)
        self.confidence: dict[tuple, float] = {}
        self.marked: dict[int, list[tuple]] = {}  # cell -> its joint states
        self.watch: dict[int, tuple[int, ...]] = {}  # cell -> the peers its joint states name
        self.windows = [RewardWindows(st.window) for _ in range(self.n_cells * N_MOVES)]  # W1, W2 per (s, a)
        if st.cq_w1_alone:
            self._fill_w1_alone()
        self.test = ConflictTest(st.window, st.significance)
        self.conflict_at = None  # a cell whose conflict is marked as soon as the peers are seen
        self.rows: list[list[float]] = []  # the rows acted on: Q_k of the cell, or Q^j of the joint states met
        self.pending = None  # (rows, action, reward, next_cell): an update waiting for the row acted on next
        self.looking = False  # whether observe asked for the peers of this step's cell

    def observe(self, cell):
        self.s = cell
        if self.conflict_at is not None:
            self.looking = True
            return self.peers
        self.looking = cell in self.watch and not (self.settings.cq_look_if_decisive and self._decisive(cell))
        return self.watch[cell] if self.looking else ()

    def _decisive(self, cell):
        """Looking cannot change the greedy action at a marked cell (cq_look_if_decisive): epsilon is 0, Q_k and
        every Q^j of the cell have one and the same unique best action (so has the elementwise minimum of any of
        the Q^j, cq_all_met), and no waiting update is about to land in one of them (the agent stayed in the
        cell), since that update's target depends on the row acted on, hence on looking."""
        if self.epsilon != 0:
            return False
        rows = [self.q_local[cell], *(self.q_joint[js] for js in self.marked[cell])]
        if self.pending is not None and any(w is row for w in self.pending[0] for row in rows):
            return False
        a = unique_best(rows[0])
        return a is not None and all(unique_best(row) == a for row in rows[1:])

    def act(self, peer_cells):
        self.heard += len(peer_cells)
        if self.conflict_at is not None:
            marked = self._mark(self.conflict_at, peer_cells)
            self.conflict_at = None
            if self.pending is not None:
                # The conflict step's own update is still waiting (cq_bootstrap_acted): it is the experience
                # of the joint states just marked too, as in the paper, whose Q^j copies a Q_k that has
                # already learnt it (without it the agent repeats the very move that collided).
                rows, a, reward, next_cell = self.pending
                self.pending = (rows + marked, a, reward, next_cell)
        met = self._meet(self.s, peer_cells) if self.looking and self.s in self.marked else []
        self.js = met[0] if met else None
        if not met:
            self.rows = [self.q_local[self.s]]
        else:
            self.rows = [self.q_joint[js] for js in (met if self.settings.cq_all_met else met[:1])]
        if self.pending is not None:
            self._bootstrap(self._acted_row())
        # after the update, which may have changed the rows acted on now
        self.a = epsilon_greedy(self._acted_row(), self.epsilon, self.rng)
        return self.a

    def _acted_row(self):
        """The row acted on: one table's, or where several joint states are met the elementwise minimum of
        theirs (an action is worth what the most wary of them says)."""
        return self.rows[0] if len(self.rows) == 1 else [min(q) for q in zip(*self.rows)]

    def learn(self, reward, next_cell, done):
        if not self.learning:
            return
        s, a = self.s, self.a
        target = reward if done else reward + self.gamma * max(self.q_local[next_cell])
        sample = self.sample(reward, target)
        w = self.windows[s * N_MOVES + a]
        if w.add(sample) and self.test.rewards_dropped(w) and not self.test.reward_above_recent(w, sample):
            self.conflict_at = None if done else s
        if self.settings.cq_bootstrap_acted and not done:
            self.pending = (self.rows, a, reward, next_cell)
        else:
            for row in self.rows:
                q_update(row, a, target, self.alpha)

    def _bootstrap(self, next_row=None):
        """The waiting update, from the row acted on now (Q_k of the next cell if the episode was cut)."""
        rows, a, reward, next_cell = self.pending
        self.pending = None
        best = max(self.q_local[next_cell] if next_row is None else next_row)
        for row in rows:
            q_update(row, a, reward + self.gamma * best, self.alpha)

    def _fill_w1_alone(self):
        """W1 of every (cell, action) holds what acting alone earns (cq_w1_alone): the world's reward for the
        move with nobody else there, a share `slip` of them delayed (reward_step), so that a conflict present
        from the first episodes on, as under delays, is a drop too, not the baseline it is measured from."""
        st, nbr, goal = self.settings, self.map.neighbours, self.map.goals[self.agent]
        delayed = round(st.window * st.slip)
        for s in range(self.n_cells):
            for a in range(N_MOVES):
                to = nbr[s][a]
                alone = st.reward_wall if to == s else st.reward_goal if to == goal else st.reward_step
                w = self.windows[s * N_MOVES + a]
                for k in range(st.window):
                    w.add(st.reward_step if k < delayed else alone)

    @staticmethod
    def sample(reward, target):
        """What the windows keep: CQ tests the immediate rewards."""
        return reward

    def end_episode(self):
        super().end_episode()
        self.conflict_at = None
        if self.pending is not None:
            self._bootstrap()

    def state_count(self):
        return self.n_cells + len(self.q_joint)

    def joint_states(self):
        return [(s, j, c, self.confidence[(s, j, c)]) for (s, j, c) in self.q_joint]

    # -- the joint states of a cell --------------------------------------------------------------------

    def _mark(self, s, peer_cells) -> list[list[float]]:
        """Mark the joint states of cell s with the peers near it; returns the Q^j rows made new."""
        st = self.settings
        near = st.cq_mark_range
        made = []
        for j in self.peers:
            if near and self.map.distance(s, peer_cells[j]) > near:
                continue
            js = (s, j, peer_cells[j])
            if js in self.confidence:
                self.confidence[js] = max(self.confidence[js], st.conf_init)
                continue
            self.q_joint[js] = list(self.q_local[s])
            made.append(self.q_joint[js])
            self.confidence[js] = st.conf_init
            self.marked.setdefault(s, []).append(js)
        self._rewatch(s)
        return made

    def _meet(self, s, peer_cells):
        """The joint states of cell s met now, the most confident first (the first marked among equals);
        their confidence rises, the others' falls, unless the learner is frozen."""
        st = self.settings
        met = []
        for js in list(self.marked[s]):
            _, j, c = js
            if peer_cells[j] == c:
                met.append(js)
                if self.learning:
                    self.confidence[js] = min(st.conf_max, self.confidence[js] + st.conf_up)
            elif self.learning:
                self.confidence[js] -= st.conf_down
                if self.confidence[js] < st.conf_drop:
                    self._forget(js)
        if met:
            self.joint_plays += 1
        return sorted(met, key=lambda js: -self.confidence[js])

    def _forget(self, js):
        s = js[0]
        del self.q_joint[js], self.confidence[js]
        self.marked[s].remove(js)
        if not self.marked[s]:
            del self.marked[s]
        self._rewatch(s)

    def _rewatch(self, s):
        peers = sorted({j for _, j, _ in self.marked.get(s, ())})
        if peers:
            self.watch[s] = tuple(peers)
        else:
            self.watch.pop(s, None)

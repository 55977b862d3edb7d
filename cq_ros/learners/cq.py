"""CQ-learning (De Hauwere, Vrancx & Nowé 2011, the paper's Algorithm 2).

Each agent learns Q_k (`q_local`) over its own cell. For every (cell, action) it keeps the reward windows W1
(the first N rewards) and W2 (the last N after those). When W2's mean falls significantly below W1's and the
last reward is not significantly above W2's mean, the rewards of that cell have turned worse than when the
agent was effectively alone: it marks the joint states (cell, peer, peer's cell), each with a Q^j
(`q_joint`) copied from Q_k and a confidence value.

In a cell with marked joint states the agent looks at the peers they name (and only those): if one is met,
it acts on Q^j and that joint state gains confidence; those not met lose confidence and are dropped below a
threshold. Everywhere else it acts on Q_k, seeing no one.

Algorithm 2, as the wire splits one step (the agent sees its peers only after asking for them, and its
reward only after acting):

    observe(s)      line 4      is s safe, or must the agent look at the peers its joint states name?
    act(peers)      line 14     (the last step's marking, now that the peers are seen)
                    lines 4-10  which table: the joint states met; their confidence rises, the others' falls
                    lines 17-21 (the last step's update, if it waited for this row)
                    lines 5, 8  choose a_k from Q_k or Q^j
    learn(r, s')    line 11     add r to W1, or else to W2
                    lines 12-13 the two t-tests: a conflict?
                    lines 17-21 the update, at once unless it waits (`_update`, the one place Q changes)

A step waits for the agent's next `act` when that act holds something it needs: the peers' cells, to mark
the joint states of a conflict found at the step, or under `cq_bootstrap_acted` the row acted on next, for
its update (which then lands in the joint states just marked too). An episode cut at the step cap ends the
wait: the update bootstraps from Q_k of the next cell and nothing is marked. Rows are named by key, never held: None for
Q_k of the step's cell, the joint state (cell, peer, peer's cell) for Q^j. A joint state forgotten while
its update waits has no row left, and its share of the update is dropped (counted in `dropped_updates`).

Our choices, each a setting whose other value is the paper's reading (docs/choices.md), each a named branch
below:
- `cq_mark_range`: only the peers within that many cells are marked (0: every peer, the paper's);
- `cq_mark_colliders`: only the peers that could have collided with the agent at the step are marked: none
  if the agent moved (a collision leaves it where it was), else those now at most one cell from the cell it
  moved toward or from its own (a collision there, a swap, or a peer that ran into it as it stood); a peer
  anywhere else cannot have caused the step's low reward, and each joint state marked is a peer the agent
  asks about at every visit to the cell for as long as it is kept (0: every peer the range allows);
- `cq_bootstrap_acted`: the update bootstraps from the row the agent then acts on, so that waiting in a
  joint state is not valued by Q_k's free road (0: Q_k of the next cell, the paper's: the agent cannot know
  at the update whether it will need coordination next);
- `cq_all_met`: where several joint states are met at once, the agent acts on the elementwise minimum of
  their rows and updates each (0: the most confident alone, our first reading);
- `cq_w1_alone`: W1 starts full of what acting alone earns, since under delays a conflict is there from the
  first episode on and the first rewards are no measure of being alone (the earlier CQ-learning of
  De Hauwere et al. 2010 took W1 from a single-agent phase);
- `cq_waits_fresh`: a new Q^j values each wait (a move into a wall) at least at one step lost plus the free
  road, since Q_k's waits hold what early exploration left, never tried again once it stops, and a Q^j copied
  from them would not wait where the joint state says it must;
- `cq_collision_conflict`: a reward as low as the collision penalty is a conflict without the t-tests, since
  the world pays it for a collision only, and a conflict met in fewer than about 1 in 20 visits of a (cell,
  action) never lowers W2's mean enough for the test to fire;
- `cq_look_if_decisive`: a greedy agent skips looking at a marked cell whose Q_k and every Q^j agree on one
  strictly best action, since whatever it saw it would do the same; a look it cannot act on is a message
  paid for nothing.
"""

from dataclasses import dataclass

from ..stats import ConflictTest, RewardWindows
from ..world import rewards_alone
from .base import Learner, N_MOVES, epsilon_greedy, q_update


def unique_best(row):
    """The action of a row's largest value if no other action ties with it, else None."""
    best = max(row)
    return row.index(best) if row.count(best) == 1 else None


@dataclass
class Step:
    """A step acted and rewarded whose update has not been made yet."""

    cell: int
    keys: list  # the rows it acted on, and the joint states marked for its conflict: None = Q_k, else Q^j's key
    action: int
    reward: float
    next_cell: int
    done: bool
    conflict: bool  # the t-tests found one; it is marked once the peers are seen
    learnt: bool = False  # its update is made (the paper's bootstrap): it waits only to be marked


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
            for s in range(self.n_cells):
                for a in range(N_MOVES):
                    for r in rewards_alone(self.map, st, self.agent, s, a, st.window):
                        self.windows[s * N_MOVES + a].add(r)
        self.test = ConflictTest(st.window, st.significance)
        self.keys: list = [None]  # the rows acted on this step
        self.waiting: Step | None = None  # the last step, until its update can be made
        self.looking = False  # whether observe asked for the peers of this step's cell
        self.dropped_updates = 0  # rows an update found forgotten (their joint state dropped while it waited)

    # -- Algorithm 2 -----------------------------------------------------------------------------------

    def observe(self, cell):
        self.s = cell
        if self.waiting is not None and self.waiting.conflict:
            self.looking = True  # marking names the peers where they are now
            return self.peers
        self.looking = cell in self.watch and not (self.settings.cq_look_if_decisive and self._decisive(cell))
        return self.watch[cell] if self.looking else ()

    def act(self, peer_cells):
        self.heard += len(peer_cells)
        last, self.waiting = self.waiting, None
        if last is not None and last.conflict:  # line 14, for the last step
            made = self._mark(last.cell, peer_cells, last)
            if not last.learnt:
                # its update, still waiting, lands in the new Q^j too, as in the paper, whose Q^j copies a Q_k
                # that has learnt that step (else the agent repeats the move that collided)
                last.keys += made
        # lines 4-10: the joint states met, whose confidence rises (the others' falls)
        met = self._meet(self.s, peer_cells) if self.looking and self.s in self.marked else []
        if not met:
            self.keys = [None]
        elif self.settings.cq_all_met:
            self.keys = met
        else:
            self.keys = met[:1]  # the most confident
        if last is not None and not last.learnt:  # lines 17-21, for the last step
            self._update(last, self._acted_row())
        # lines 5 and 8, after the update, which may have changed the rows acted on now
        self.a = epsilon_greedy(self._acted_row(), self.epsilon, self.rng)
        return self.a

    def learn(self, reward, next_cell, done):
        if not self.learning:
            return
        s, a = self.s, self.a
        w = self.windows[s * N_MOVES + a]  # line 11: W1 fills first, then W2 slides; lines 12-13 once both are full
        conflict = w.add(reward) and self.test.rewards_dropped(w) and not self.test.reward_above_recent(w, reward)
        if self.settings.cq_collision_conflict and reward <= self.settings.reward_collision:
            conflict = True  # ours: the world's collision penalty is a conflict, however rare
        step = Step(s, list(self.keys), a, reward, next_cell, done, conflict=conflict and not done)
        if done or not self.settings.cq_bootstrap_acted:
            self._update(step)  # the paper's bootstrap, Q_k of s', is known now
            step.learnt = True
        if step.conflict or not step.learnt:
            self.waiting = step  # the next act holds what it needs: the peers to mark, or the row acted on

    def _update(self, step, next_row=None):
        """Lines 17-21: Q(s, a) <- (1 - alpha) Q(s, a) + alpha [r + gamma max_a' Q(s', a')] in each row the step
        names that is still kept. `next_row` is the row acted on at s', None where there is none yet: the update
        is made at once, or the episode was cut."""
        if step.done:
            target = step.reward
        elif self.settings.cq_bootstrap_acted and next_row is not None:
            target = step.reward + self.gamma * max(next_row)  # ours: the row acted on at s'
        else:
            target = step.reward + self.gamma * max(self.q_local[step.next_cell])  # the paper's: Q_k of s'
        for key in step.keys:
            row = self.q_local[step.cell] if key is None else self.q_joint.get(key)
            if row is None:  # forgotten while the update waited: there is no Q^j left to learn it
                self.dropped_updates += 1
                continue
            q_update(row, step.action, target, self.alpha)

    def _acted_row(self):
        """The row acted on: one table's, or where several joint states are met the elementwise minimum of
        theirs (an action is worth what the most wary of them says)."""
        rows = [self.q_local[self.s] if key is None else self.q_joint[key] for key in self.keys]
        return rows[0] if len(rows) == 1 else [min(q) for q in zip(*rows)]

    def end_episode(self):
        super().end_episode()
        last, self.waiting = self.waiting, None
        if last is not None and not last.learnt:
            self._update(last)  # no row is acted on next, and a conflict found now has no peers to mark

    def state_count(self):
        return self.n_cells + len(self.q_joint)

    def joint_states(self):
        return [(s, j, c, self.confidence[(s, j, c)]) for (s, j, c) in self.q_joint]

    # -- the joint states of a cell --------------------------------------------------------------------

    def _decisive(self, cell):
        """Looking cannot change the greedy action at a marked cell (cq_look_if_decisive): epsilon is 0, Q_k and
        every Q^j of the cell have one and the same unique best action (so has the elementwise minimum of any of
        the Q^j, cq_all_met), and no waiting update is about to land in one of them (the agent stayed in the
        cell), since that update's target depends on the row acted on, hence on looking."""
        if self.epsilon != 0:
            return False
        if self.waiting is not None and not self.waiting.learnt and self.waiting.cell == cell:
            return False
        rows = [self.q_local[cell], *(self.q_joint[js] for js in self.marked[cell])]
        a = unique_best(rows[0])
        return a is not None and all(unique_best(row) == a for row in rows[1:])

    def _mark(self, s, peer_cells, step=None) -> list[tuple]:
        """Mark the joint states of cell s with the peers near it (under cq_mark_colliders, those that could
        have collided with the agent at `step`, the step of the conflict); returns the joint states made new."""
        st = self.settings
        near = st.cq_mark_range
        made = []
        for j in self.peers:
            if near and self.map.distance(s, peer_cells[j]) > near:
                continue
            if st.cq_mark_colliders and step is not None and not self._could_collide(step, peer_cells[j]):
                continue
            js = (s, j, peer_cells[j])
            if js in self.confidence:
                self.confidence[js] = max(self.confidence[js], st.conf_init)
                continue
            self.q_joint[js] = self._new_row(s)
            made.append(js)
            self.confidence[js] = st.conf_init
            self.marked.setdefault(s, []).append(js)
        self._rewatch(s)
        return made

    def _could_collide(self, step, cell):
        """Whether a peer now at `cell` can have collided with the agent at `step` (cq_mark_colliders): the agent
        stayed (agents in a collision stay), and the peer is at most one cell from where the agent moved toward
        (both moved into it, a swap, or the agent ran into the peer) or from the agent's own cell (the peer ran
        into it as it stayed)."""
        if step.next_cell != step.cell:
            return False
        toward = self.map.neighbours[step.cell][step.action]
        return min(self.map.distance(toward, cell), self.map.distance(step.cell, cell)) <= 1

    def _new_row(self, s):
        """A new Q^j of cell s: a copy of Q_k, whose waits, under cq_waits_fresh, are worth at least one step
        lost (a wall bump) plus the free road from s."""
        row = list(self.q_local[s])
        if self.settings.cq_waits_fresh:
            floor = self.settings.reward_wall + self.gamma * max(row)
            for a, to in enumerate(self.map.neighbours[s]):
                if to == s:  # a wait: the move bumps into a wall and leaves the agent where it is
                    row[a] = max(row[a], floor)
        return row

    def _meet(self, s, peer_cells):
        """Lines 6 and 9: the joint states of cell s met now, the most confident first (the first marked among
        equals); their confidence rises, the others' falls, unless the learner is frozen."""
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

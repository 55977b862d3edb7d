"""CQ-learning as the paper reads (De Hauwere, Vrancx & Nowé 2011, its Algorithm 2): `cq_paper`.

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
the joint states of a conflict found at the step, or (our CQ, cq.CQLearner) the row acted on next, for its
update (which then lands in the joint states just marked too). An episode cut at the step cap ends the wait:
the update bootstraps from Q_k of the next cell and nothing is marked. Rows are named by key, never held:
None for Q_k of the step's cell, the joint state (cell, peer, peer's cell) for Q^j. A joint state forgotten
while its update waits has no row left, and its share of the update is dropped (counted in `dropped_updates`).

Where the paper is silent (several joint states met at once, with three or more agents), the reading closest
to its one Q^j per step: the most confident met. The rules our CQ changes are the methods under "the rules
of CQ": each is the paper's reading here, and ours in cq.CQLearner.
"""

from dataclasses import dataclass

from ..settings import CONF_DROP, CONF_INIT
from ..stats import ConflictTest, RewardWindows
from .base import Learner, N_MOVES, epsilon_greedy, q_update


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


class CQPaperLearner(Learner):
    name = "cq_paper"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        st = self.settings
        self.q_local = [[0.0] * N_MOVES for _ in range(self.n_cells)]  # Q_k
        self.q_joint: dict[tuple, list[float]] = {}  # Q^j, keyed by joint state (cell, peer, peer_cell)
        self.confidence: dict[tuple, float] = {}
        self.marked: dict[int, list[tuple]] = {}  # cell -> its joint states
        self.watch: dict[int, tuple[int, ...]] = {}  # cell -> the peers its joint states name
        self.windows = [RewardWindows(st.window) for _ in range(self.n_cells * N_MOVES)]  # W1, W2 per (s, a)
        self._start_windows()
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
        self.looking = cell in self.watch and self._looks(cell)
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
        self.keys = self._acted_on(met) if met else [None]
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
        step = Step(s, list(self.keys), a, reward, next_cell, done, conflict=conflict and not done)
        if done or not self._bootstraps_from_next_act():
            self._update(step)  # its bootstrap is known now
            step.learnt = True
        if step.conflict or not step.learnt:
            self.waiting = step  # the next act holds what it needs: the peers to mark, or the row acted on

    def _update(self, step, next_row=None):
        """Lines 17-21: Q(s, a) <- (1 - alpha) Q(s, a) + alpha [r + gamma max_a' Q(s', a')] in each row the step
        names that is still kept. `next_row` is the row acted on at s', None where there is none yet: the update
        is made at once, or the episode was cut."""
        target = step.reward if step.done else step.reward + self.gamma * max(self._bootstrap(step, next_row))
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

    def _mark(self, s, peer_cells, step) -> list[tuple]:
        """Line 14: mark the joint states of cell s, the cell of `step` (the step of the conflict), with the
        peers `_marks` names; returns the joint states made new."""
        made = []
        for j in self.peers:
            if not self._marks(step, peer_cells[j]):
                continue
            js = (s, j, peer_cells[j])
            if js in self.confidence:
                self.confidence[js] = max(self.confidence[js], CONF_INIT)
                continue
            self.q_joint[js] = self._new_row(s)
            made.append(js)
            self.confidence[js] = CONF_INIT
            self.marked.setdefault(s, []).append(js)
        self._rewatch(s)
        return made

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
                if self.confidence[js] < CONF_DROP:
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

    # -- the rules of CQ: the paper's reading; ours in cq.CQLearner --------------------------------------

    def _start_windows(self):
        """W1 starts empty: it fills with the first N rewards of each (cell, action)."""

    def _looks(self, cell):
        """Whether the agent looks at a cell with marked joint states: always."""
        return True

    def _acted_on(self, met):
        """The rows acted on among the joint states met (most confident first): the most confident."""
        return met[:1]

    def _bootstraps_from_next_act(self):
        """Whether a step's update waits for the row acted on next: no, it bootstraps from Q_k of s'."""
        return False

    def _bootstrap(self, step, next_row):
        """The row an update bootstraps from: Q_k of s' (the agent cannot know yet whether it will need
        coordination there)."""
        return self.q_local[step.next_cell]

    def _marks(self, step, peer_cell):
        """Whether a conflict found at `step` marks a joint state with a peer now at `peer_cell`: every peer."""
        return True

    def _new_row(self, s):
        """A new Q^j of cell s: a copy of Q_k."""
        return list(self.q_local[s])

"""The learners the kernel plays (every one: algorithms.KERNEL_ALGORITHMS) and one episode of them
(cq_ros.engine.Team.episode), compiled.

Each function is the twin of a reference method (named in its docstring) and does its float operations in the
same order, so that a compiled run is the reference's byte for byte (tests/test_compiled.py holds them one).
A learner is a row of arrays (agent k): `ag[k]` its counters and step, `eps[k]`, `q[k]` (Q_k), `mt[k]` its
Mersenne Twister. CQ's joint states of every agent live in one pool (`jsi`, `jsf`: cell, peer, peer's cell,
creation order, the cell's list links; confidence and Q^j), each cell's list in marking order, so a cell's
joint states, their order and `joint_states()`'s order are the reference's dicts' and lists'. Its waiting
step is `wt[k]` (with `wtr`, `wtk`: reward, keys) and the keys it acts on `ck[k]`: -1 is Q_k, else a slot.
near's states with peers in range, LoC's perceived joint states and JS's and JSA's joint states live in one
hash table of every agent's (`tk`, `tq`, `th`, `tm`; its section says the layout); the waiting step of near
and JS (NextStateLearner) is CQ's `wt[k]`, its row `wtk[k, 0]`, and the row acted on `ck[k, 0]`, in the same
convention. Tables are indexed element by element, never sliced into rows: a view counts a reference (an
atomic operation) each time, which cost more than the learning itself; a row acted on is copied into a buffer.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import windows as W
from .jit import kernel
from .mt import randbelow, random
from .world import KIND, reset, step

# ag columns (CHOICE: LoC's epsilon-greedy choice among its five actions)
S, A, LOOKING, LOOK_N, DROPPED, PLAYED, PLAYS, HEARD, ACTIVE, NKEYS, CHOICE = range(11)
# jsi columns (jsf: CONF, then the row)
JS_S, JS_J, JS_C, JS_SEQ, JS_NEXT, JS_PREV, JS_AGENT = range(7)
CONF = 0
# wt columns: the waiting step
W_ON, W_CELL, W_ACTION, W_NEXT, W_DONE, W_CONFLICT, W_LEARNT, W_NKEYS = range(8)
# fp: the float settings
ALPHA, GAMMA, EPS0, SLIP, R_STEP, R_WALL, R_COLL, R_GOAL, CONF_INIT, CONF_UP, CONF_DOWN, CONF_MAX, CONF_DROP, \
    T_TWO, T_ONE, LOC_COST, JS_STATES = range(17)
# ip: the int settings (ALGO: which learner, one of ALGO_CODES; OURS: CQ plays our rules, cq.CQLearner's, else
# the paper's, cq_paper.CQPaperLearner's; RANGE: near_range, loc_range, or for JS beyond any distance)
N_CELLS, STEP_CAP, START_HOLD, DECAY, LEARNING, ALGO, OURS, RANGE = range(8)
INDEP, CQ, NEAR, LOC, JS, JSA = range(6)
ALGO_CODES = {"indep": INDEP, "cq": CQ, "cq_paper": CQ, "near": NEAR, "loc": LOC, "js": JS, "jsa": JSA}
COORDINATE = 4  # LoC's fifth action (cq_ros.learners.loc.COORDINATE)
# meta: the pool's free slots, the next creation number
FREE, SEQ = 0, 1


@njit(cache=True, inline="always")
def _max(row):
    """Python's max(row): the first of the largest."""
    best = row[0]
    for k in range(1, row.shape[0]):
        if row[k] > best:
            best = row[k]
    return best


@njit(cache=True, inline="always")
def _qmax(q, k, s):
    """max(Q_k[s]), as _max."""
    best = q[k, s, 0]
    for a in range(1, q.shape[2]):
        if q[k, s, a] > best:
            best = q[k, s, a]
    return best


@njit(cache=True, inline="always")
def greedy(row, mt, g):
    """base.greedy: the largest value's index, ties broken by rng.choice (generator g)."""
    best = _max(row)
    count = 0
    first = -1
    for a in range(row.shape[0]):
        if row[a] == best:
            count += 1
            if first < 0:
                first = a
    if count == 1:
        return first
    pick = randbelow(mt, g, count)
    for a in range(row.shape[0]):
        if row[a] == best:
            if pick == 0:
                return a
            pick -= 1
    return -1


@njit(cache=True, inline="always")
def epsilon_greedy(row, epsilon, mt, g):
    if random(mt, g) < epsilon:
        return int(random(mt, g) * row.shape[0])
    return greedy(row, mt, g)


@kernel
def choose(row, epsilon, mt, g):
    """epsilon_greedy, called: near, LoC, JS, JSA and CQ's act where it waits or looks (_act_cq) share one
    compilation of it (each inlining costs seconds of the first compilation)."""
    return epsilon_greedy(row, epsilon, mt, g)


@njit(cache=True, inline="always")
def _distance(rows, cols, a, b):
    return abs(rows[a] - rows[b]) + abs(cols[a] - cols[b])


@njit(cache=True, inline="always")
def end_episode(k, fp, ip, ag, eps):
    """Learner.end_episode: one more episode played; epsilon on its schedule."""
    ag[k, PLAYED] += 1
    decay = ip[DECAY]
    if decay:
        fall = 1.0 - ag[k, PLAYED] / decay
        scaled = fp[EPS0] * (fall if fall > 0.0 else 0.0)
        if scaled < eps[k]:
            eps[k] = scaled


# -- CQ ------------------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _get(q, jsf, k, key, cell, a):
    """Q_k[cell][a] (key -1) or Q^j[a] of the joint state in slot `key`."""
    return q[k, cell, a] if key < 0 else jsf[key, 1 + a]


@njit(cache=True, inline="always")
def _acted_row(k, ag, ck, q, jsf, out):
    """CQLearner._acted_row into `out`: one row, or the elementwise minimum of the rows met."""
    cell = ag[k, S]
    for a in range(out.shape[0]):
        out[a] = _get(q, jsf, k, ck[k, 0], cell, a)
        for m in range(1, ag[k, NKEYS]):
            v = _get(q, jsf, k, ck[k, m], cell, a)
            if v < out[a]:
                out[a] = v
    return out


@njit(cache=True, inline="always")
def _update(k, fp, ip, ag, q, jsi, jsf, wt, wtr, wtk, next_row, has_next):
    """CQLearner._update of the step in wt[k] (`next_row` the row acted on at s', if `has_next`)."""
    cell, action = wt[k, W_CELL], wt[k, W_ACTION]
    reward = wtr[k]
    if wt[k, W_DONE]:
        target = reward
    elif ip[OURS] and has_next:
        target = reward + fp[GAMMA] * _max(next_row)
    else:
        target = reward + fp[GAMMA] * _qmax(q, k, wt[k, W_NEXT])
    alpha = fp[ALPHA]
    for m in range(wt[k, W_NKEYS]):
        key = wtk[k, 2 * m]
        if key < 0:
            q[k, cell, action] += alpha * (target - q[k, cell, action])
        elif jsi[key, JS_SEQ] != wtk[k, 2 * m + 1]:  # forgotten while the update waited
            ag[k, DROPPED] += 1
        else:
            jsf[key, 1 + action] += alpha * (target - jsf[key, 1 + action])


@njit(cache=True, inline="always")
def _unique_best(q, jsf, k, key, cell):
    """unique_best of a row: its largest value's action if no other ties with it, else -1."""
    best = _get(q, jsf, k, key, cell, 0)
    for a in range(1, q.shape[2]):
        v = _get(q, jsf, k, key, cell, a)
        if v > best:
            best = v
    first, count = -1, 0
    for a in range(q.shape[2]):
        if _get(q, jsf, k, key, cell, a) == best:
            count += 1
            if first < 0:
                first = a
    return first if count == 1 else -1


@kernel
def _decisive(k, cell, eps, q, jsi, jsf, head, wt):
    """CQLearner._decisive."""
    if eps[k] != 0:
        return False
    if wt[k, W_ON] and not wt[k, W_LEARNT] and wt[k, W_CELL] == cell:
        return False
    a = _unique_best(q, jsf, k, -1, cell)
    if a < 0:
        return False
    slot = head[k, cell]
    while slot >= 0:
        if _unique_best(q, jsf, k, slot, cell) != a:
            return False
        slot = jsi[slot, JS_NEXT]
    return True


@njit(cache=True, inline="always")
def _peers_named(k, cell, jsi, head):
    """len(watch[cell]): the peers the cell's joint states name (a cell keeps few: each is checked against those
    before it, where clearing a mark per peer would cost the fleet's size at every look)."""
    count = 0
    slot = head[k, cell]
    while slot >= 0:
        j = jsi[slot, JS_J]
        earlier = head[k, cell]
        while earlier != slot and jsi[earlier, JS_J] != j:
            earlier = jsi[earlier, JS_NEXT]
        count += earlier == slot
        slot = jsi[slot, JS_NEXT]
    return count


@njit(cache=True, inline="always")
def observe_cq(k, cell, n, ip, ag, eps, q, jsi, jsf, head, wt):
    """CQLearner.observe: how many peers the agent looks at (LOOK_N)."""
    ag[k, S] = cell
    if wt[k, W_ON] and wt[k, W_CONFLICT]:
        ag[k, LOOKING] = 1
        ag[k, LOOK_N] = n - 1
        return
    looking = head[k, cell] >= 0 and not (ip[OURS] and _decisive(k, cell, eps, q, jsi, jsf, head, wt))
    ag[k, LOOKING] = looking
    ag[k, LOOK_N] = _peers_named(k, cell, jsi, head) if looking else 0


@njit(cache=True, inline="always")
def _forget(slot, jsi, head, tail, meta, free, n_js):
    k, s = jsi[slot, JS_AGENT], jsi[slot, JS_S]
    prev, nxt = jsi[slot, JS_PREV], jsi[slot, JS_NEXT]
    if prev >= 0:
        jsi[prev, JS_NEXT] = nxt
    else:
        head[k, s] = nxt
    if nxt >= 0:
        jsi[nxt, JS_PREV] = prev
    else:
        tail[k, s] = prev
    jsi[slot, JS_SEQ] = -1
    free[meta[FREE]] = slot
    meta[FREE] += 1
    n_js[k] -= 1


@kernel
def _mark(k, s, nbr, rows, cols, fp, ip, cells, q, jsi, jsf, head, tail, meta, free, n_js, wt, made):
    """CQLearner._mark of cell s for the step in wt[k]: the slots made new into `made`; how many. The pool has
    a free slot for each peer (grow_pool)."""
    n = cells.shape[0]
    count = 0
    for j in range(n):
        if j == k:
            continue
        pc = cells[j]
        if ip[OURS]:  # CQLearner._marks
            if wt[k, W_NEXT] != wt[k, W_CELL]:
                continue
            toward = nbr[wt[k, W_CELL], wt[k, W_ACTION]]
            d1, d2 = _distance(rows, cols, toward, pc), _distance(rows, cols, wt[k, W_CELL], pc)
            if (d2 if d2 < d1 else d1) > 1:
                continue
        slot = head[k, s]
        while slot >= 0 and not (jsi[slot, JS_J] == j and jsi[slot, JS_C] == pc):
            slot = jsi[slot, JS_NEXT]
        if slot >= 0:
            if fp[CONF_INIT] > jsf[slot, CONF]:
                jsf[slot, CONF] = fp[CONF_INIT]
            continue
        meta[FREE] -= 1
        slot = free[meta[FREE]]
        for a in range(q.shape[2]):
            jsf[slot, 1 + a] = q[k, s, a]
        if ip[OURS]:  # CQLearner._new_row
            floor = fp[R_WALL] + fp[GAMMA] * _qmax(q, k, s)
            for a in range(q.shape[2]):
                if nbr[s, a] == s and floor > jsf[slot, 1 + a]:
                    jsf[slot, 1 + a] = floor
        jsi[slot, JS_S], jsi[slot, JS_J], jsi[slot, JS_C], jsi[slot, JS_AGENT] = s, j, pc, k
        jsi[slot, JS_SEQ] = meta[SEQ]
        meta[SEQ] += 1
        jsf[slot, CONF] = fp[CONF_INIT]
        last = tail[k, s]
        jsi[slot, JS_PREV], jsi[slot, JS_NEXT] = last, -1
        if last >= 0:
            jsi[last, JS_NEXT] = slot
        else:
            head[k, s] = slot
        tail[k, s] = slot
        n_js[k] += 1
        made[count] = slot
        count += 1
    return count


@njit(cache=True, inline="always")
def _meet(k, s, fp, ip, ag, cells, jsi, jsf, head, tail, meta, free, n_js, met):
    """CQLearner._meet: the joint states of cell s met now into `met`, most confident first; how many."""
    learning = ip[LEARNING]
    count = 0
    slot = head[k, s]
    while slot >= 0:
        nxt = jsi[slot, JS_NEXT]
        if cells[jsi[slot, JS_J]] == jsi[slot, JS_C]:
            met[count] = slot
            count += 1
            if learning:
                up = jsf[slot, CONF] + fp[CONF_UP]
                jsf[slot, CONF] = up if up < fp[CONF_MAX] else fp[CONF_MAX]
        elif learning:
            jsf[slot, CONF] -= fp[CONF_DOWN]
            if jsf[slot, CONF] < fp[CONF_DROP]:
                _forget(slot, jsi, head, tail, meta, free, n_js)
        slot = nxt
    if count:
        ag[k, PLAYS] += 1
    for m in range(1, count):  # a stable sort by falling confidence
        x = met[m]
        p = m - 1
        while p >= 0 and jsf[met[p], CONF] < jsf[x, CONF]:
            met[p + 1] = met[p]
            p -= 1
        met[p + 1] = x
    return count


@njit(cache=True, inline="always")
def act_cq(k, nbr, rows, cols, fp, ip, ag, eps, q, mt, cells, jsi, jsf, free, meta, head, tail, n_js, wt, wtr, wtk,
           ck, made, row):
    """CQLearner.act: inline where no step waits and the agent looks at no one (then it heard no one, LOOK_N 0,
    and acts on Q_k of s), almost every step; else called (_act_cq), which keeps the kernel's loop small."""
    if wt[k, W_ON] or ag[k, LOOKING]:
        return _act_cq(k, nbr, rows, cols, fp, ip, ag, eps, q, mt, cells, jsi, jsf, free, meta, head, tail, n_js, wt,
                       wtr, wtk, ck, made, row)
    ck[k, 0] = -1
    ag[k, NKEYS] = 1
    s = ag[k, S]
    for a in range(row.shape[0]):
        row[a] = q[k, s, a]
    a = epsilon_greedy(row, eps[k], mt, k)
    ag[k, A] = a
    return a


@kernel
def _act_cq(k, nbr, rows, cols, fp, ip, ag, eps, q, mt, cells, jsi, jsf, free, meta, head, tail, n_js, wt, wtr, wtk,
            ck, made, row):
    """CQLearner.act, all of it."""
    ag[k, HEARD] += ag[k, LOOK_N]
    was_on = wt[k, W_ON]
    wt[k, W_ON] = 0
    if was_on and wt[k, W_CONFLICT]:
        count = _mark(k, wt[k, W_CELL], nbr, rows, cols, fp, ip, cells, q, jsi, jsf, head, tail, meta, free, n_js,
                      wt, made)
        if not wt[k, W_LEARNT]:
            for m in range(count):
                at = wt[k, W_NKEYS]
                wtk[k, 2 * at] = made[m]
                wtk[k, 2 * at + 1] = jsi[made[m], JS_SEQ]
                wt[k, W_NKEYS] += 1
    s = ag[k, S]
    count = 0
    if ag[k, LOOKING] and head[k, s] >= 0:
        count = _meet(k, s, fp, ip, ag, cells, jsi, jsf, head, tail, meta, free, n_js, made)
    if count == 0:
        ck[k, 0] = -1
        ag[k, NKEYS] = 1
    else:
        keep = count if ip[OURS] else 1
        for m in range(keep):
            ck[k, m] = made[m]
        ag[k, NKEYS] = keep
    _acted_row(k, ag, ck, q, jsf, row)
    if was_on and not wt[k, W_LEARNT]:
        _update(k, fp, ip, ag, q, jsi, jsf, wt, wtr, wtk, row, True)
        if wt[k, W_CELL] == s:  # only then may the update have changed the row acted on (Q_k[s], or Q^j of s)
            _acted_row(k, ag, ck, q, jsf, row)
    a = choose(row, eps[k], mt, k)
    ag[k, A] = a
    return a


@njit(cache=True, inline="always")
def learn_cq(k, reward, kind, next_cell, done, fp, ip, ag, q, jsi, jsf, head, wt, wtr, wtk, ck, wi, wf, pool, used,
             part, vals, wrow, row):
    """CQLearner.learn of `reward`, of its `kind` (windows.add; the pool has a row free: windows.room)."""
    if not ip[LEARNING]:
        return
    s, a = ag[k, S], ag[k, A]
    w = s * 4 + a
    conflict = False
    if W.add(wi, wf, k, w, pool, used, part, vals, wrow, reward, kind):
        conflict = (W.drop_t(wi, wf, k, w, pool, part, vals, wrow) < -fp[T_TWO]
                    and not W.above_t(wi, wf, k, w, pool, part, vals, wrow, reward) < -fp[T_ONE])
    if done or (not conflict and (not ip[OURS] or head[k, next_cell] < 0)):
        # Nothing waits for the next act: the update is made now as the reference's is (at the goal, or in the
        # paper's CQ), or, in ours, the row it bootstraps from is already known: s' has
        # no joint state and none can appear before the next act (only a waiting conflict marks), so that act
        # will act on Q_k of s', which nothing changes until then (Q_k is only this learner's); and the rows
        # acted on at s are the step's own, still kept (only a cell's own joint states are forgotten, when it is
        # met). So the target is the one the waiting update would have had: the same float operations, without
        # the waiting step's bookkeeping (wt, whose fields nothing reads while W_ON is 0). On warehouse_16 this
        # is almost every step: 2026-12-06, 20 episodes, ~10% of the compiled CQ's CPU.
        target = reward if done else reward + fp[GAMMA] * _qmax(q, k, next_cell)
        alpha = fp[ALPHA]
        for m in range(ag[k, NKEYS]):
            key = ck[k, m]
            if key < 0:
                q[k, s, a] += alpha * (target - q[k, s, a])
            else:
                jsf[key, 1 + a] += alpha * (target - jsf[key, 1 + a])
        wt[k, W_ON] = 0
        return
    _wait(k, s, a, reward, next_cell, done, conflict, fp, ip, ag, q, jsi, jsf, wt, wtr, wtk, ck, row)


@kernel
def _wait(k, s, a, reward, next_cell, done, conflict, fp, ip, ag, q, jsi, jsf, wt, wtr, wtk, ck, row):
    """The rest of CQLearner.learn, called (rare: learn_cq's loop stays small): the step waits in wt[k]."""
    wt[k, W_CELL], wt[k, W_ACTION], wt[k, W_NEXT] = s, a, next_cell
    wt[k, W_DONE] = done
    wt[k, W_CONFLICT] = conflict and not done
    wt[k, W_LEARNT] = 0
    wtr[k] = reward
    nkeys = ag[k, NKEYS]
    for m in range(nkeys):
        wtk[k, 2 * m] = ck[k, m]
        wtk[k, 2 * m + 1] = jsi[ck[k, m], JS_SEQ] if ck[k, m] >= 0 else -1
    wt[k, W_NKEYS] = nkeys
    if done or not ip[OURS]:
        _update(k, fp, ip, ag, q, jsi, jsf, wt, wtr, wtk, row, False)
        wt[k, W_LEARNT] = 1
    wt[k, W_ON] = wt[k, W_CONFLICT] or not wt[k, W_LEARNT]


@njit(cache=True, inline="always")
def end_cq(k, fp, ip, ag, eps, q, jsi, jsf, wt, wtr, wtk, row):
    """CQLearner.end_episode."""
    end_episode(k, fp, ip, ag, eps)
    if wt[k, W_ON] and not wt[k, W_LEARNT]:
        _update(k, fp, ip, ag, q, jsi, jsf, wt, wtr, wtk, row, False)
    wt[k, W_ON] = 0


# -- indep ---------------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def learn_indep(k, reward, next_cell, done, fp, ip, ag, q):
    """IndependentQ.learn."""
    if not ip[LEARNING]:
        return
    target = reward if done else reward + fp[GAMMA] * _qmax(q, k, next_cell)
    s, a = ag[k, S], ag[k, A]
    q[k, s, a] += fp[ALPHA] * (target - q[k, s, a])


# -- the tables of states seen with peers (near's q_near, LoC's q_coord, JS's and JSA's q_joint) ---------
#
# One table for every agent: a state's key (`tk` row: agent, then every agent's cell, a peer out of range -1,
# so (s, near) of the reference is the key's cells that are not -1), its row (`tq`), and an open-addressed
# hash index (`th`: slot or -1, twice the slots, a power of two); `tm[0]` the slots used. JSA's one learner
# (agent 0) keys every cell and its rows hold the 4^n joint actions. Slots are made in creation order and never
# dropped, so an agent's slots in order are its dict's order (team_of).

@njit(cache=True, inline="always")
def _hash(key):
    """A key's place in the index before probing: any mix that spreads keys will do, as probing finds them."""
    h = 0x345678
    for i in range(key.shape[0]):
        h = (h ^ key[i]) * 1000003  # wraps around, as int64 does in numba
    return h ^ (h >> 29)


@kernel
def _probe(tk, th, key):
    """Where `key` sits in the index `th`: its slot's place, or the empty place (-1) where it would go."""
    mask = th.shape[0] - 1
    p = _hash(key) & mask
    while th[p] >= 0:
        slot = th[p]
        i = 0
        while i < key.shape[0] and tk[slot, i] == key[i]:
            i += 1
        if i == key.shape[0]:
            return p
        p = (p + 1) & mask
    return p


@njit(cache=True)
def index_table(tk, th, used):
    """The hash index of the table's first `used` slots, into `th`."""
    th[:] = -1
    for slot in range(used):
        th[_probe(tk, th, tk[slot])] = slot


@njit(cache=True)
def _grown(ints, floats, size):
    """A pool's (or the table's) int and float rows copied into `size` rows, the new ones -1 and 0."""
    ints2 = np.full((size, ints.shape[1]), -1, np.int64)
    ints2[:ints.shape[0]] = ints
    floats2 = np.zeros((size, floats.shape[1]))
    floats2[:floats.shape[0]] = floats
    return ints2, floats2


@njit(cache=True)
def grow_table(tk, tq, th, tm, slots):
    """The table with `slots` slots free: the same arrays, or ones doubled as often as that needs."""
    size = tk.shape[0]
    while tm[0] + slots > size:
        size *= 2
    if size == tk.shape[0]:
        return tk, tq, th
    tk2, tq2 = _grown(tk, tq, size)
    th2 = np.empty(2 * size, np.int64)
    index_table(tk2, th2, tm[0])
    return tk2, tq2, th2


@kernel
def _near_key(k, s, reach, rows, cols, cells, key):
    """The state (s, near) as a key (the table's layout): the peers within `reach` of s; how many there are."""
    key[0] = k
    count = 0
    for j in range(cells.shape[0]):
        if j == k:
            key[1 + j] = s
        elif _distance(rows, cols, s, cells[j]) <= reach:
            key[1 + j] = cells[j]
            count += 1
        else:
            key[1 + j] = -1
    return count


@kernel
def _table_row(k, s, ip, q, n_js, tk, tq, th, tm, key):
    """The slot of the state `key` (agent k in cell s), made if new and learning: a copy of Q_k[s]'s first moves
    (near, LoC) or zeros (JS, JSA); -1 for a new state while frozen (a row kept nowhere, as nothing changes:
    Q_k[s] for near and LoC, zeros for JS, whose Q_k stays zeros, and JSA)."""
    p = _probe(tk, th, key)
    if th[p] >= 0 or not ip[LEARNING]:
        return th[p]
    slot = tm[0]
    tm[0] += 1
    th[p] = slot
    for i in range(key.shape[0]):
        tk[slot, i] = key[i]
    copy = ip[ALGO] == NEAR or ip[ALGO] == LOC
    for a in range(tq.shape[1]):
        tq[slot, a] = q[k, s, a] if copy else 0.0
    n_js[k] += 1
    return slot


@njit(cache=True, inline="always")
def _q_at(k, ref, cell, a, q, tq):
    """Q_k[cell][a] (ref -1) or the table's row `ref`'s a."""
    return q[k, cell, a] if ref < 0 else tq[ref, a]


@njit(cache=True, inline="always")
def _q_update(k, ref, cell, a, target, alpha, q, tq):
    """base.q_update of Q_k[cell] (ref -1) or of the table's row `ref`."""
    if ref < 0:
        q[k, cell, a] += alpha * (target - q[k, cell, a])
    else:
        tq[ref, a] += alpha * (target - tq[ref, a])


# -- near and JS ---------------------------------------------------------------------------------------

@kernel
def act_near(k, fp, ip, ag, eps, q, mt, cells, rows, cols, n_js, tk, tq, th, tm, wt, wtr, wtk, ck, key, row):
    """NearQ.act or JointStateQ.act (every peer in range, always on a joint state), then
    NextStateLearner.act_on: the step waiting in wt[k] (its row's ref in wtk[k, 0]) is finished from the row of
    the state seen now, which is chosen on. ck[k, 0]: the row acted on."""
    s = ag[k, S]
    count = _near_key(k, s, ip[RANGE], rows, cols, cells, key)
    ag[k, HEARD] += count
    ref = -1
    if count or ip[ALGO] == JS:
        ag[k, PLAYS] += 1
        ref = _table_row(k, s, ip, q, n_js, tk, tq, th, tm, key)
    if wt[k, W_ON]:  # only a learning learner leaves a step waiting: the new row above was made before this
        wt[k, W_ON] = 0  # update, as NearQ.act makes it before act_on
        best = _q_at(k, ref, s, 0, q, tq)
        for a in range(1, row.shape[0]):
            v = _q_at(k, ref, s, a, q, tq)
            if v > best:
                best = v
        _q_update(k, wtk[k, 0], wt[k, W_CELL], wt[k, W_ACTION], wtr[k] + fp[GAMMA] * best, fp[ALPHA], q, tq)
    for a in range(row.shape[0]):
        row[a] = _q_at(k, ref, s, a, q, tq)
    ck[k, 0] = ref
    a = choose(row, eps[k], mt, k)
    ag[k, A] = a
    return a


@kernel
def learn_near(k, reward, done, fp, ip, ag, q, tq, wt, wtr, wtk, ck):
    """NextStateLearner.learn: at the goal the update is made now, else it waits for the next state's row."""
    if not ip[LEARNING]:
        return
    if done:
        _q_update(k, ck[k, 0], ag[k, S], ag[k, A], reward, fp[ALPHA], q, tq)
        return
    wt[k, W_ON], wt[k, W_CELL], wt[k, W_ACTION] = 1, ag[k, S], ag[k, A]
    wtk[k, 0] = ck[k, 0]
    wtr[k] = reward


# -- LoC -----------------------------------------------------------------------------------------------

@kernel
def observe_loc(k, cell, ag, eps, q, mt, row):
    """LearningOfCoordination.observe: epsilon-greedy over Q*'s five actions (`row` holds five)."""
    ag[k, S] = cell
    for a in range(row.shape[0]):
        row[a] = q[k, cell, a]
    ag[k, CHOICE] = choose(row, eps[k], mt, k)


@kernel
def act_loc(k, ip, ag, q, mt, cells, rows, cols, n_js, tk, tq, th, tm, ck, key, moves):
    """LearningOfCoordination.act: COORDINATE looks at every peer and, with one in range, acts greedily on
    Q^C of the joint state perceived (ck[k, 0] its row, -1 none); else greedily on Q*'s moves (`moves`: a
    table row's size, 4)."""
    ck[k, 0] = -1
    if ag[k, CHOICE] != COORDINATE:
        ag[k, A] = ag[k, CHOICE]
        return ag[k, A]
    ag[k, PLAYS] += 1
    ag[k, HEARD] += cells.shape[0] - 1
    s = ag[k, S]
    ref = -1
    if _near_key(k, s, ip[RANGE], rows, cols, cells, key):
        ref = ck[k, 0] = _table_row(k, s, ip, q, n_js, tk, tq, th, tm, key)
    for a in range(moves.shape[0]):
        moves[a] = _q_at(k, ref, s, a, q, tq)
    ag[k, A] = greedy(moves, mt, k)
    return ag[k, A]


@kernel
def learn_loc(k, reward, next_cell, done, fp, ip, ag, q, tq, ck):
    """LearningOfCoordination.learn."""
    if not ip[LEARNING]:
        return
    future = 0.0 if done else fp[GAMMA] * _qmax(q, k, next_cell)
    s, move = ag[k, S], ag[k, A]
    if ck[k, 0] >= 0:
        _q_update(k, ck[k, 0], s, move, reward + future, fp[ALPHA], q, tq)
    _q_update(k, -1, s, move, reward + future, fp[ALPHA], q, tq)
    if ag[k, CHOICE] == COORDINATE:
        _q_update(k, -1, s, COORDINATE, reward - fp[LOC_COST] + future, fp[ALPHA], q, tq)


# -- JSA -----------------------------------------------------------------------------------------------

@kernel
def act_jsa(ip, ag, eps, q, mt, cells, rows, cols, n_js, tk, tq, th, tm, ck, key, joint):
    """JointStateActionQ.act (its one learner is agent 0): epsilon-greedy over the joint actions of the joint
    state (ck[0, 0] its row; `joint` holds the row, 4^n values)."""
    _near_key(0, cells[0], ip[RANGE], rows, cols, cells, key)
    ref = ck[0, 0] = _table_row(0, cells[0], ip, q, n_js, tk, tq, th, tm, key)
    for a in range(joint.shape[0]):
        joint[a] = tq[ref, a] if ref >= 0 else 0.0
    a = choose(joint, eps[0], mt, 0)
    ag[0, A] = a
    ag[0, PLAYS] += 1
    return a


@kernel
def learn_jsa(reward, done, fp, ip, ag, q, cells, rows, cols, n_js, tk, tq, th, tm, ck, key):
    """JointStateActionQ.learn: the next joint state's row is made (if new) before the update."""
    if not ip[LEARNING]:
        return
    target = reward
    if not done:
        _near_key(0, cells[0], ip[RANGE], rows, cols, cells, key)
        nxt = _table_row(0, cells[0], ip, q, n_js, tk, tq, th, tm, key)
        best = tq[nxt, 0]
        for a in range(1, tq.shape[1]):
            if tq[nxt, a] > best:
                best = tq[nxt, a]
        target = reward + fp[GAMMA] * best
    _q_update(0, ck[0, 0], 0, ag[0, A], target, fp[ALPHA], q, tq)


# -- the episode ---------------------------------------------------------------------------------------

@njit(cache=True)
def grow_pool(jsi, jsf, free, meta, slots):
    """The joint-state pool with `slots` slots free: the same arrays, or ones doubled as often as that needs."""
    cap = jsi.shape[0]
    size = cap
    while meta[FREE] + size - cap < slots:
        size *= 2
    if size == cap:
        return jsi, jsf, free
    jsi2, jsf2 = _grown(jsi, jsf, size)
    free2 = np.empty(size, np.int64)
    free2[:meta[FREE]] = free[:meta[FREE]]
    for slot in range(size - 1, cap - 1, -1):
        free2[meta[FREE]] = slot
        meta[FREE] += 1
    return jsi2, jsf2, free2


@njit(cache=True, inline="always")
def _step_outcome(k, cell, over, fp, ip, ag, eps, q, mt, jsi, jsf, head, wt, wtr, wtk, row):
    """engine.step_outcome once the learner learnt: end its episode if it is `over` for it, else observe `cell`."""
    ag[k, ACTIVE] = not over
    algo = ip[ALGO]
    if over and algo == CQ:
        end_cq(k, fp, ip, ag, eps, q, jsi, jsf, wt, wtr, wtk, row)
    elif over:
        end_episode(k, fp, ip, ag, eps)
        wt[k, W_ON] = 0  # NextStateLearner.end_episode: a step cut by the step cap is left out
    elif algo == CQ:
        observe_cq(k, cell, ag.shape[0], ip, ag, eps, q, jsi, jsf, head, wt)
    elif algo == LOC:
        observe_loc(k, cell, ag, eps, q, mt, row)
    else:
        ag[k, S] = cell


# ep: the episode's state between the calls of `play` (a float table: exact for these counts)
STARTED, T, COLLISIONS, RETURN, PLAYS0, HEARD0 = range(6)


@kernel
def play(geo, fp, ip, world, ag, eps, q, mt, js, cq, win, tab, tmp, out):
    """Team.episode: one episode; its record into `out` (cq_ros.episode's columns); True once it is over. It
    stops between joint steps (False) where a pool or table might fill in the next one: call it again once
    they have grown (`play_many`); `tmp` holds its scratch and where it stopped."""
    nbr, starts, goals, rows, cols = geo
    cells, done, hold, wmt, scratch = world
    ai, rewards, ci, clock, pair, listed = scratch
    jsi, jsf, free, meta, head, tail, n_js = js
    wt, wtr, wtk, ck, made = cq
    wi, wf, pool, used, part, vals, wrow = win
    tk, tq, th, tm = tab
    rw, row, actions, ep, key, trow = tmp
    n = starts.shape[0]
    algo = ip[ALGO]
    is_cq = algo == CQ
    tables = algo != INDEP and algo != CQ
    if not ep[STARTED]:
        reset(starts, goals, cells, done, hold, wmt, ip[START_HOLD])
        ep[STARTED], ep[T], ep[COLLISIONS], ep[RETURN] = 1, 0, 0, 0.0
        ep[PLAYS0], ep[HEARD0] = ag[:, PLAYS].sum(), ag[:, HEARD].sum()
        over = done.all() or ip[STEP_CAP] <= 0
        if algo == JSA and over:  # Team.start, central: its state is the cells, observed where it acts
            end_episode(0, fp, ip, ag, eps)
        for k in range(n if algo != JSA else 0):  # Team.start
            _step_outcome(k, cells[k], over or done[k], fp, ip, ag, eps, q, mt, jsi, jsf, head, wt, wtr, wtk, row)
    t, collisions, ret = int(ep[T]), int(ep[COLLISIONS]), ep[RETURN]
    # GridWorld.over's numba twin (it cannot call the world), here and below: tests/test_compiled.py's
    # byte-identical result files hold the two to one rule.
    over = done.all() or t >= ip[STEP_CAP]
    while not over:
        if is_cq and (meta[FREE] < n * (n - 1) or used[0] + n > pool.shape[0]):  # each agent may mark n - 1
            ep[T], ep[COLLISIONS], ep[RETURN] = t, collisions, ret                 # joint states, open a window
            return False
        if tables and tm[0] + 2 * n > tk.shape[0]:  # each agent may make a state (JSA's one learner, two)
            ep[T], ep[COLLISIONS], ep[RETURN] = t, collisions, ret
            return False
        if algo == JSA:  # central_act: agent i's move is digit i in base 4; those at their goals ignore it
            joint = act_jsa(ip, ag, eps, q, mt, cells, rows, cols, n_js, tk, tq, th, tm, ck, key, trow)
            for k in range(n):
                actions[k] = -1 if done[k] else joint % 4
                joint //= 4
        for k in range(n if algo != JSA else 0):  # Team.choose
            actions[k] = -1
            if not ag[k, ACTIVE]:
                continue
            if is_cq:
                actions[k] = act_cq(k, nbr, rows, cols, fp, ip, ag, eps, q, mt, cells, jsi, jsf, free, meta, head,
                                    tail, n_js, wt, wtr, wtk, ck, made, row)
            elif algo == NEAR or algo == JS:
                actions[k] = act_near(k, fp, ip, ag, eps, q, mt, cells, rows, cols, n_js, tk, tq, th, tm, wt, wtr,
                                      wtk, ck, key, row)
            elif algo == LOC:
                actions[k] = act_loc(k, ip, ag, q, mt, cells, rows, cols, n_js, tk, tq, th, tm, ck, key, trow)
            else:
                s = ag[k, S]
                for a in range(4):
                    row[a] = q[k, s, a]
                actions[k] = epsilon_greedy(row, eps[k], mt, k)
                ag[k, A] = actions[k]
        collisions += step(nbr, goals, cells, done, hold, wmt, actions, fp[SLIP], ip[START_HOLD], rw, ai, rewards,
                           ci, clock, pair, listed)
        t += 1
        over = done.all() or t >= ip[STEP_CAP]
        total = 0.0
        for k in range(n):
            total += rewards[k]
        if algo == JSA:  # central_outcome: the sum of the rewards, done once every agent is
            learn_jsa(total, done.all(), fp, ip, ag, q, cells, rows, cols, n_js, tk, tq, th, tm, ck, key)
            if over:
                end_episode(0, fp, ip, ag, eps)
        for k in range(n if algo != JSA else 0):  # Team.learn
            if actions[k] < 0:
                continue
            if is_cq:
                learn_cq(k, rewards[k], ai[KIND, k], cells[k], done[k], fp, ip, ag, q, jsi, jsf, head, wt, wtr, wtk,
                         ck, wi, wf, pool, used, part, vals, wrow, row)
            elif algo == NEAR or algo == JS:
                learn_near(k, rewards[k], done[k], fp, ip, ag, q, tq, wt, wtr, wtk, ck)
            elif algo == LOC:
                learn_loc(k, rewards[k], cells[k], done[k], fp, ip, ag, q, tq, ck)
            else:
                learn_indep(k, rewards[k], cells[k], done[k], fp, ip, ag, q)
            _step_outcome(k, cells[k], over or done[k], fp, ip, ag, eps, q, mt, jsi, jsf, head, wt, wtr, wtk, row)
        ret += total
    ep[STARTED] = 0
    out[0] = t
    out[1] = collisions
    out[2] = ag[:, PLAYS].sum() - ep[PLAYS0]
    out[3] = fp[JS_STATES] if algo == JS or algo == JSA else n * ip[N_CELLS] + n_js.sum()
    out[4] = ret
    out[5] = t >= ip[STEP_CAP] and not done.all()
    out[6] = ag[:, HEARD].sum() - ep[HEARD0]
    return True


@njit(cache=True)
def play_many(geo, fp, ip, world, ag, eps, q, mt, js, cq, win, tab, out):
    """`play` for every row of `out`, the pools and the table grown where it asks; the pools and the table."""
    jsi, jsf, free, meta, head, tail, n_js = js
    wi, wf, pool, used, part, vals, wrow = win
    tk, tq, th, tm = tab
    n = geo[1].shape[0]
    tmp = (np.array([fp[R_STEP], fp[R_WALL], fp[R_COLL], fp[R_GOAL]]), np.empty(q.shape[2]),
           np.full(n, -1, np.int64), np.zeros(6), np.empty(n + 1, np.int64), np.empty(tq.shape[1]))
    for e in range(out.shape[0]):
        while not play(geo, fp, ip, world, ag, eps, q, mt, (jsi, jsf, free, meta, head, tail, n_js), cq,
                       (wi, wf, pool, used, part, vals, wrow), (tk, tq, th, tm), tmp, out[e]):
            jsi, jsf, free = grow_pool(jsi, jsf, free, meta, n * (n - 1))
            pool = W.room(pool, used, n)
            tk, tq, th = grow_table(tk, tq, th, tm, 2 * n)
    return jsi, jsf, free, pool, tk, tq, th

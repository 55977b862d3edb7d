"""The learners the kernel plays (indep, cq) and one episode of them (cq_ros.engine.Team.episode), compiled.

Each function is the twin of a reference method (named in its docstring) and does its float operations in the
same order, so that a compiled run is the reference's byte for byte (tests/test_compiled.py holds them one).
A learner is a row of arrays (agent k): `ag[k]` its counters and step, `eps[k]`, `q[k]` (Q_k), `mt[k]` its
Mersenne Twister. CQ's joint states of every agent live in one pool (`jsi`, `jsf`: cell, peer, peer's cell,
creation order, the cell's list links; confidence and Q^j), each cell's list in marking order, so a cell's
joint states, their order and `joint_states()`'s order are the reference's dicts' and lists'. Its waiting
step is `wt[k]` (with `wtr`, `wtk`: reward, keys) and the keys it acts on `ck[k]`: -1 is Q_k, else a slot.
Tables are indexed element by element, never sliced into rows: a view counts a reference (an atomic operation)
each time, which cost more than the learning itself; a row acted on is copied into a 4-value buffer.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import windows as W
from .jit import kernel
from .mt import randbelow, random
from .world import reset, step

# ag columns
S, A, LOOKING, LOOK_N, DROPPED, PLAYED, PLAYS, HEARD, ACTIVE, NKEYS = range(10)
# jsi columns (jsf: CONF, then the row)
JS_S, JS_J, JS_C, JS_SEQ, JS_NEXT, JS_PREV, JS_AGENT = range(7)
CONF = 0
# wt columns: the waiting step
W_ON, W_CELL, W_ACTION, W_NEXT, W_DONE, W_CONFLICT, W_LEARNT, W_NKEYS = range(8)
# fp: the float settings
ALPHA, GAMMA, EPS0, SLIP, R_STEP, R_WALL, R_COLL, R_GOAL, CONF_INIT, CONF_UP, CONF_DOWN, CONF_MAX, CONF_DROP, \
    T_TWO, T_ONE = range(15)
# ip: the int settings
N_CELLS, STEP_CAP, START_HOLD, DECAY, LEARNING, IS_CQ, MARK_RANGE, MARK_COLLIDERS, BOOT_ACTED, ALL_MET, \
    WAITS_FRESH, LOOK_DECISIVE = range(12)
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
    elif ip[BOOT_ACTED] and has_next:
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
    looking = head[k, cell] >= 0 and not (ip[LOOK_DECISIVE] and _decisive(k, cell, eps, q, jsi, jsf, head, wt))
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
    near = ip[MARK_RANGE]
    count = 0
    for j in range(n):
        if j == k:
            continue
        pc = cells[j]
        if near and _distance(rows, cols, s, pc) > near:
            continue
        if ip[MARK_COLLIDERS]:  # _could_collide
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
        if ip[WAITS_FRESH]:  # _new_row
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
    """CQLearner.act."""
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
        keep = count if ip[ALL_MET] else 1
        for m in range(keep):
            ck[k, m] = made[m]
        ag[k, NKEYS] = keep
    _acted_row(k, ag, ck, q, jsf, row)
    if was_on and not wt[k, W_LEARNT]:
        _update(k, fp, ip, ag, q, jsi, jsf, wt, wtr, wtk, row, True)
        if wt[k, W_CELL] == s:  # only then may the update have changed the row acted on (Q_k[s], or Q^j of s)
            _acted_row(k, ag, ck, q, jsf, row)
    a = epsilon_greedy(row, eps[k], mt, k)
    ag[k, A] = a
    return a


@njit(cache=True, inline="always")
def learn_cq(k, reward, next_cell, done, fp, ip, ag, q, jsi, jsf, wt, wtr, wtk, ck, wi, wf, pool, used, part, row):
    """CQLearner.learn (the pool has a row free: windows.room)."""
    if not ip[LEARNING]:
        return
    s, a = ag[k, S], ag[k, A]
    w = s * 4 + a
    conflict = False
    if W.add(wi, wf, k, w, pool, used, part, reward):
        conflict = (W.drop_t(wi, wf, k, w, pool, part) < -fp[T_TWO]
                    and not W.above_t(wi, wf, k, w, pool, part, reward) < -fp[T_ONE])
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
    if done or not ip[BOOT_ACTED]:
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
    jsi2 = np.full((size, jsi.shape[1]), -1, np.int64)
    jsi2[:cap] = jsi
    jsf2 = np.zeros((size, jsf.shape[1]))
    jsf2[:cap] = jsf
    free2 = np.empty(size, np.int64)
    free2[:meta[FREE]] = free[:meta[FREE]]
    for slot in range(size - 1, cap - 1, -1):
        free2[meta[FREE]] = slot
        meta[FREE] += 1
    return jsi2, jsf2, free2


@njit(cache=True, inline="always")
def _step_outcome(k, cell, over, fp, ip, ag, eps, q, jsi, jsf, head, wt, wtr, wtk, row):
    """engine.step_outcome once the learner learnt: end its episode if it is `over` for it, else observe `cell`."""
    ag[k, ACTIVE] = not over
    if over and ip[IS_CQ]:
        end_cq(k, fp, ip, ag, eps, q, jsi, jsf, wt, wtr, wtk, row)
    elif over:
        end_episode(k, fp, ip, ag, eps)
    elif ip[IS_CQ]:
        observe_cq(k, cell, ag.shape[0], ip, ag, eps, q, jsi, jsf, head, wt)
    else:
        ag[k, S] = cell


# ep: the episode's state between the calls of `play` (a float table: exact for these counts)
STARTED, T, COLLISIONS, RETURN, PLAYS0, HEARD0 = range(6)


@kernel
def play(geo, fp, ip, world, ag, eps, q, mt, js, cq, win, tmp, out):
    """Team.episode: one episode; its record into `out` (cq_ros.episode's columns); True once it is over. It
    stops between joint steps (False) where a CQ pool might fill in the next one: call it again once the pools
    have grown (`play_many`); `tmp` holds its scratch and where it stopped."""
    nbr, starts, goals, rows, cols = geo
    cells, done, hold, wmt, scratch = world
    ai, rewards, ci, clock, pair, listed = scratch
    jsi, jsf, free, meta, head, tail, n_js = js
    wt, wtr, wtk, ck, made = cq
    wi, wf, pool, used, part = win
    rw, row, actions, ep = tmp
    n = starts.shape[0]
    is_cq = ip[IS_CQ]
    if not ep[STARTED]:
        reset(starts, goals, cells, done, hold, wmt, ip[START_HOLD])
        ep[STARTED], ep[T], ep[COLLISIONS], ep[RETURN] = 1, 0, 0, 0.0
        ep[PLAYS0], ep[HEARD0] = ag[:, PLAYS].sum(), ag[:, HEARD].sum()
        over = done.all() or ip[STEP_CAP] <= 0
        for k in range(n):  # Team.start
            _step_outcome(k, cells[k], over or done[k], fp, ip, ag, eps, q, jsi, jsf, head, wt, wtr, wtk, row)
    t, collisions, ret = int(ep[T]), int(ep[COLLISIONS]), ep[RETURN]
    # GridWorld.over's numba twin (it cannot call the world), here and below: tests/test_compiled.py's
    # byte-identical result files hold the two to one rule.
    over = done.all() or t >= ip[STEP_CAP]
    while not over:
        if is_cq and (meta[FREE] < n * (n - 1) or used[0] + n > pool.shape[0]):  # each agent may mark n - 1
            ep[T], ep[COLLISIONS], ep[RETURN] = t, collisions, ret                 # joint states, open a window
            return False
        for k in range(n):  # Team.choose
            actions[k] = -1
            if not ag[k, ACTIVE]:
                continue
            if is_cq:
                actions[k] = act_cq(k, nbr, rows, cols, fp, ip, ag, eps, q, mt, cells, jsi, jsf, free, meta, head,
                                    tail, n_js, wt, wtr, wtk, ck, made, row)
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
        for k in range(n):  # Team.learn
            if actions[k] < 0:
                continue
            if is_cq:
                learn_cq(k, rewards[k], cells[k], done[k], fp, ip, ag, q, jsi, jsf, wt, wtr, wtk, ck, wi, wf, pool,
                         used, part, row)
            else:
                learn_indep(k, rewards[k], cells[k], done[k], fp, ip, ag, q)
            _step_outcome(k, cells[k], over or done[k], fp, ip, ag, eps, q, jsi, jsf, head, wt, wtr, wtk, row)
        total = 0.0
        for k in range(n):
            total += rewards[k]
        ret += total
    ep[STARTED] = 0
    out[0] = t
    out[1] = collisions
    out[2] = ag[:, PLAYS].sum() - ep[PLAYS0]
    out[3] = n * ip[N_CELLS] + n_js.sum()
    out[4] = ret
    out[5] = t >= ip[STEP_CAP] and not done.all()
    out[6] = ag[:, HEARD].sum() - ep[HEARD0]
    return True


@njit(cache=True)
def play_many(geo, fp, ip, world, ag, eps, q, mt, js, cq, win, out):
    """`play` for every row of `out`, the pools grown where it asks; the pools."""
    jsi, jsf, free, meta, head, tail, n_js = js
    wi, wf, pool, used, part = win
    n = geo[1].shape[0]
    tmp = (np.array([fp[R_STEP], fp[R_WALL], fp[R_COLL], fp[R_GOAL]]), np.empty(4), np.full(n, -1, np.int64),
           np.zeros(6))
    for e in range(out.shape[0]):
        while not play(geo, fp, ip, world, ag, eps, q, mt, (jsi, jsf, free, meta, head, tail, n_js), cq,
                       (wi, wf, pool, used, part), tmp, out[e]):
            jsi, jsf, free = grow_pool(jsi, jsf, free, meta, n * (n - 1))
            pool = W.room(pool, used, n)
    return jsi, jsf, free, pool

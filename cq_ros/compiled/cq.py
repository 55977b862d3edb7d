"""CQ's learner in the kernel (cq.CQLearner's and cq_paper.CQPaperLearner's twin, one as ip[OURS] says):
observe, act, learn and end an episode, on Q_k and the joint states of the pool (cq_ros.compiled.layout).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import windows as W
from .base import _distance, _grown, _max, _qmax, choose, end_episode, epsilon_greedy
from .jit import kernel
from .layout import (
    A, ALPHA, CONF, CONF_DOWN, CONF_DROP, CONF_INIT, CONF_MAX, CONF_UP, DROPPED, FREE, GAMMA, HEARD, JS_AGENT, JS_C,
    JS_J, JS_NEXT, JS_PREV, JS_S, JS_SEQ, LEARNING, LOOKING, LOOK_N, NKEYS, OURS, PLAYS, R_WALL, S, SEQ, T_ONE,
    T_TWO, W_ACTION, W_CELL, W_CONFLICT, W_DONE, W_LEARNT, W_NEXT, W_NKEYS, W_ON,
)


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

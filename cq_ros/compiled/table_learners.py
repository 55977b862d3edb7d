"""The learners on the table (cq_ros.compiled.table) in the kernel: near and JS (NextStateLearner), LoC and JSA."""

from __future__ import annotations

from .base import _qmax, choose, greedy
from .jit import kernel
from .layout import (
    A, ALGO, ALPHA, CHOICE, COORDINATE, GAMMA, HEARD, JS, LEARNING, LOC_COST, PLAYS, RANGE, S, W_ACTION, W_CELL,
    W_ON,
)
from .table import _near_key, _q_at, _q_update, _table_row


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

"""One episode of the kernel's learners (cq_ros.engine.Team.episode's twin): `play`, and `play_many`, which
plays episodes one after another and grows the pools and the table between joint steps as `play` asks.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import windows as W
from .base import end_episode, epsilon_greedy, learn_indep
from .cq import act_cq, end_cq, grow_pool, learn_cq, observe_cq
from .jit import kernel
from .layout import (
    A, ACTIVE, ALGO, CQ, FREE, HEARD, INDEP, JS, JSA, JS_STATES, LOC, NEAR, N_CELLS, PLAYS, R_COLL, R_GOAL, R_STEP,
    R_WALL, S, SLIP, START_HOLD, STEP_CAP, W_ON,
)
from .table import grow_table
from .table_learners import act_jsa, act_loc, act_near, learn_jsa, learn_loc, learn_near, observe_loc
from .world import KIND, reset, step


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

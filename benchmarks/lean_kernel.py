"""The limit under the compiled engine (bench_engine.py --limit): the same work with our learners taken out (the
compiled world's own step replaying the joint actions a reference run chose: the very same episodes) and the
leanest numba kernel of the same rules and learning dynamics we could write, not byte-identical to the reference.

What `lean_run` drops against cq_ros.compiled: CPython's Mersenne Twister streams (numba's own generator, one
stream), exact sums (no math.fsum: the windows keep plain running sums), collisions counted as agents collided
over two (not distinct pairs), delays (slip, start_hold), greedy episodes, and most rules of our CQ: the update is
made at once with the paper's bootstrap (Q_k of s'; our waiting for the row acted on at s' is dropped), a
conflict marks the peers within MARK_RANGE cells of the cell at once (the update lands in the rows made new, as
the reference's does), every joint state met is acted on (the elementwise
minimum), and a cell keeps at most `SLOTS` joint states, in dense arrays (agent, cell, slot) rather than a pool
of linked lists.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cq_ros.compiled.jit import kernel
from cq_ros.compiled.world import new_scratch, reset, step

SLOTS = 8  # joint states a cell keeps at most in the lean kernel
MARK_RANGE = 2  # a conflict marks the peers this close: those our CQ could blame (cq.CQLearner._marks)


@kernel
def _world_alone(nbr, starts, goals, rw, lengths, actions, cells, done, hold, mt, scratch, joint):
    """The compiled world's steps (cq_ros.compiled.world.step) for the joint actions `actions`, each episode
    `lengths[e]` of them from a reset; the collisions. Compiled as the engine's `play` is (no reference counts),
    each joint action copied into `joint` (a row's view would count one)."""
    ai, rewards, ci, clock, pair, listed = scratch
    collisions, t = 0, 0
    for e in range(lengths.shape[0]):
        reset(starts, goals, cells, done, hold, mt, 0)
        for _ in range(lengths[e]):
            for k in range(joint.shape[0]):
                joint[k] = actions[t, k]
            collisions += step(nbr, goals, cells, done, hold, mt, joint, 0.0, 0, rw, ai, rewards, ci, clock,
                               pair, listed)
            t += 1
    return collisions


def recorded_actions(algo: str, gridmap, settings, episodes: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The joint actions the reference engine's learners choose in `episodes` episodes of a run (-1: at the goal)
    and the episodes' lengths: the world alone replays them, so it plays the very same episodes."""
    from cq_ros.engine import GridWorld, Team, make_learners, world_seed

    team = Team(GridWorld(gridmap, settings, seed=world_seed(seed, 0)), make_learners(algo, gridmap, settings, seed, 0))
    chosen: list[list[int]] = []
    lengths = [team.episode(lambda world, actions, looks: chosen.append(
        [-1 if a is None else a for a in actions])).steps for _ in range(episodes)]
    return np.array(chosen, np.int64).reshape(-1, gridmap.n_agents), np.array(lengths, np.int64)


def world_alone(gridmap, settings, actions: np.ndarray, lengths: np.ndarray) -> int:
    """The compiled world alone (no learner) replaying recorded joint actions (recorded_actions); the collisions.
    Without delays: the world's steps are then a function of the actions."""
    if settings.slip or settings.start_hold:
        raise ValueError("the world alone replays a run without delays")
    n = gridmap.n_agents
    rw = np.array([settings.reward_step, settings.reward_wall, settings.reward_collision, settings.reward_goal])
    return _world_alone(np.array(gridmap.neighbours, np.int64), np.array(gridmap.starts, np.int64),
                        np.array(gridmap.goals, np.int64), rw, lengths, actions, np.zeros(n, np.int64),
                        np.zeros(n, np.bool_), np.zeros(n, np.int64), np.zeros((1, 625), np.int64),
                        new_scratch(n, gridmap.n_cells), np.zeros(n, np.int64))


@njit(cache=True, inline="always")
def _choose(row, epsilon):
    """epsilon-greedy on a 4-value row, ties broken at random."""
    if np.random.random() < epsilon:
        return np.random.randint(4)
    best, count, pick = row[0], 1, 0
    for a in range(1, 4):
        if row[a] > best:
            best, count, pick = row[a], 1, a
        elif row[a] == best:
            count += 1
            if np.random.randint(count) == 0:
                pick = a
    return pick


@njit(cache=True)
def _lean(nbr, starts, goals, rows, cols, fp, ip, episodes, seed, out):
    """Indep (ip[0] == 0) or CQ for `episodes` episodes; each episode's joint steps and collisions into `out`."""
    np.random.seed(seed)
    alpha, gamma, eps0, r_step, r_wall, r_coll, r_goal = fp[0], fp[1], fp[2], fp[3], fp[4], fp[5], fp[6]
    conf_init, conf_up, conf_down, conf_max, conf_drop, t_two, t_one = fp[7], fp[8], fp[9], fp[10], fp[11], \
        fp[12], fp[13]
    is_cq, step_cap, decay, window, near = ip[0], ip[1], ip[2], ip[3], ip[4]
    n, c = starts.shape[0], nbr.shape[0]
    q = np.zeros((n, c, 4))
    cells, done, target, final = (np.zeros(n, np.int64), np.zeros(n, np.bool_), np.zeros(n, np.int64),
                                  np.zeros(n, np.int64))
    count, owner, collided = np.zeros(c, np.int64), np.full(c, -1, np.int64), np.zeros(n, np.bool_)
    actions, rewards, row = np.zeros(n, np.int64), np.zeros(n), np.zeros(4)
    cw = c * 4 if is_cq else 1
    wn = np.zeros((n, cw, 3), np.int64)  # n1, n2, head
    ws = np.zeros((n, cw, 4))  # sum1, sq1, sum2, sq2
    wb = np.zeros((n, cw, window))  # W2's ring
    cj = c if is_cq else 1
    jn = np.zeros((n, cj), np.int64)
    jp, jc = np.zeros((n, cj, SLOTS), np.int64), np.zeros((n, cj, SLOTS), np.int64)
    jconf, jq = np.zeros((n, cj, SLOTS)), np.zeros((n, cj, SLOTS, 4))
    keys, nkeys = np.zeros((n, SLOTS), np.int64), np.zeros(n, np.int64)
    epsilon = eps0
    for e in range(episodes):
        if decay:
            epsilon = min(epsilon, eps0 * max(0.0, 1.0 - e / decay))
        for k in range(n):
            cells[k] = starts[k]
            done[k] = starts[k] == goals[k]
        t = 0
        collisions = 0
        while t < step_cap and not done.all():
            for k in range(n):  # choose
                actions[k] = -1
                if done[k]:
                    continue
                s = cells[k]
                for a in range(4):
                    row[a] = q[k, s, a]
                nkeys[k] = 0
                if is_cq:  # meet the cell's joint states: the met ones' rows' minimum is acted on
                    m = 0
                    while m < jn[k, s]:
                        if cells[jp[k, s, m]] == jc[k, s, m]:
                            jconf[k, s, m] = min(conf_max, jconf[k, s, m] + conf_up)
                            if nkeys[k] == 0:
                                for a in range(4):
                                    row[a] = jq[k, s, m, a]
                            else:
                                for a in range(4):
                                    row[a] = min(row[a], jq[k, s, m, a])
                            keys[k, nkeys[k]] = m
                            nkeys[k] += 1
                        else:
                            jconf[k, s, m] -= conf_down
                            if jconf[k, s, m] < conf_drop:  # forgotten: the last slot takes its place
                                last = jn[k, s] - 1
                                jp[k, s, m], jc[k, s, m], jconf[k, s, m] = jp[k, s, last], jc[k, s, last], \
                                    jconf[k, s, last]
                                for a in range(4):
                                    jq[k, s, m, a] = jq[k, s, last, a]
                                jn[k, s] = last
                                continue
                        m += 1
                actions[k] = _choose(row, epsilon)
            for k in range(n):  # the world's step: targets, then collided agents back until none moves
                target[k] = cells[k] if actions[k] < 0 else nbr[cells[k], actions[k]]
                final[k] = target[k]
                collided[k] = False
                owner[cells[k]] = k
            moved = True
            while moved:
                moved = False
                for k in range(n):
                    count[final[k]] += 1
                for k in range(n):
                    f = final[k]
                    if f == cells[k]:
                        continue
                    o = owner[f]
                    if count[f] > 1:
                        for j in range(n):  # the others ending in that cell, but those sharing it as a goal
                            if j != k and final[j] == f and not (goals[j] == goals[k] and goals[k] == f):
                                collided[j] = collided[k] = True
                    if o >= 0 and o != k and final[o] == cells[k]:  # a swap
                        collided[k] = collided[o] = True
                for k in range(n):
                    count[final[k]] = 0
                for k in range(n):
                    if collided[k] and final[k] != cells[k]:
                        final[k] = cells[k]
                        moved = True
            hit = 0
            for k in range(n):
                owner[cells[k]] = -1
                rewards[k] = 0.0
                if done[k]:
                    continue
                if collided[k]:
                    rewards[k] = r_coll
                    hit += 1
                elif actions[k] >= 0 and target[k] == cells[k]:
                    rewards[k] = r_wall
                elif target[k] == goals[k]:
                    rewards[k] = r_goal
                else:
                    rewards[k] = r_step
            collisions += hit // 2
            for k in range(n):  # learn
                if actions[k] < 0:
                    continue
                s, a, s2 = cells[k], actions[k], final[k]
                d = s2 == goals[k]
                r = rewards[k]
                target_q = r if d else r + gamma * max(q[k, s2, 0], q[k, s2, 1], q[k, s2, 2], q[k, s2, 3])
                if not is_cq:
                    q[k, s, a] += alpha * (target_q - q[k, s, a])
                    continue
                w = s * 4 + a
                conflict = False
                if wn[k, w, 0] < window:
                    wn[k, w, 0] += 1
                    ws[k, w, 0] += r
                    ws[k, w, 1] += r * r
                else:
                    h = wn[k, w, 2]
                    old = wb[k, w, h]
                    wb[k, w, h] = r
                    wn[k, w, 2] = h + 1 if h + 1 < window else 0
                    if wn[k, w, 1] < window:
                        wn[k, w, 1] += 1
                        old = 0.0
                    ws[k, w, 2] += r - old
                    ws[k, w, 3] += r * r - old * old
                    if wn[k, w, 1] == window and not d:  # both full: the two t-tests
                        m1, m2 = ws[k, w, 0] / window, ws[k, w, 2] / window
                        ss1 = max(0.0, ws[k, w, 1] - ws[k, w, 0] * m1)
                        ss2 = max(0.0, ws[k, w, 3] - ws[k, w, 2] * m2)
                        se_drop = (ss1 + ss2) / (window - 1) / window
                        se_above = ss2 / (window - 1) / window
                        conflict = (se_drop > 0.0 and (m2 - m1) / math.sqrt(se_drop) < -t_two
                                    and not (se_above > 0.0 and (m2 - r) / math.sqrt(se_above) < -t_one))
                local = nkeys[k] == 0  # acted on Q_k: it learns the step, and so do the rows marked now
                if conflict:  # mark the peers near s, where they are now
                    for j in range(n):
                        if j == k or abs(rows[s] - rows[cells[j]]) + abs(cols[s] - cols[cells[j]]) > near:
                            continue
                        m = 0
                        while m < jn[k, s] and not (jp[k, s, m] == j and jc[k, s, m] == final[j]):
                            m += 1
                        if m < jn[k, s]:
                            jconf[k, s, m] = max(jconf[k, s, m], conf_init)
                        elif m < SLOTS:
                            jp[k, s, m], jc[k, s, m], jconf[k, s, m] = j, final[j], conf_init
                            for b in range(4):
                                jq[k, s, m, b] = q[k, s, b]
                            jn[k, s] += 1
                            if nkeys[k] < SLOTS:
                                keys[k, nkeys[k]] = m
                                nkeys[k] += 1
                if local:
                    q[k, s, a] += alpha * (target_q - q[k, s, a])
                for m in range(nkeys[k]):
                    jq[k, s, keys[k, m], a] += alpha * (target_q - jq[k, s, keys[k, m], a])
            for k in range(n):
                cells[k] = final[k]
                done[k] = done[k] or cells[k] == goals[k]
            t += 1
        out[e, 0], out[e, 1] = t, collisions


def lean_run(algo: str, gridmap, settings, episodes: int, seed: int = 0) -> np.ndarray:
    """The lean kernel's run of indep or CQ: each episode's (joint steps, collisions)."""
    from cq_ros.settings import CONF_DROP, CONF_INIT
    from cq_ros.stats import ConflictTest

    st = settings
    test = ConflictTest(st.window, st.significance)
    rows, cols = zip(*gridmap.cells)
    fp = np.array([st.alpha, st.gamma, st.epsilon, st.reward_step, st.reward_wall, st.reward_collision,
                   st.reward_goal, CONF_INIT, st.conf_up, st.conf_down, st.conf_max, CONF_DROP, test.t_two,
                   test.t_one])
    ip = np.array([algo == "cq", st.step_cap, st.epsilon_decay_episodes, st.window, MARK_RANGE], np.int64)
    out = np.zeros((episodes, 2), np.int64)
    _lean(np.array(gridmap.neighbours, np.int64), np.array(gridmap.starts, np.int64),
          np.array(gridmap.goals, np.int64), np.array(rows, np.int64), np.array(cols, np.int64), fp, ip, episodes,
          seed, out)
    return out

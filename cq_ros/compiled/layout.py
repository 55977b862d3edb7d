"""The kernel's arrays, column by column: a learner is a row of each (agent k), `ag[k]` its counters and step,
`eps[k]`, `q[k]` (Q_k), `mt[k]` its Mersenne Twister; `fp` and `ip` hold the run's settings.

CQ's joint states of every agent live in one pool (`jsi`, `jsf`: cell, peer, peer's cell, creation order, the
cell's list links; confidence and Q^j), each cell's list in marking order, so a cell's joint states, their order
and `joint_states()`'s order are the reference's dicts' and lists'. Its waiting step is `wt[k]` (with `wtr`,
`wtk`: reward, keys) and the keys it acts on `ck[k]`: -1 is Q_k, else a slot. The waiting step of near and JS
(NextStateLearner) is CQ's `wt[k]`, its row `wtk[k, 0]`, and the row acted on `ck[k, 0]`, in the same
convention. The other learners' states with peers live in one hash table (cq_ros.compiled.table).

Tables are indexed element by element, never sliced into rows: a view counts a reference (an atomic operation)
each time, which cost more than the learning itself; a row acted on is copied into a buffer.
"""

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
# the paper's, cq_paper.CQPaperLearner's; RANGE: cq_ros.world.COLLISION_REACH for near and LoC, or for JS
# beyond any distance)
N_CELLS, STEP_CAP, START_HOLD, DECAY, LEARNING, ALGO, OURS, RANGE = range(8)
INDEP, CQ, NEAR, LOC, JS, JSA = range(6)
ALGO_CODES = {"indep": INDEP, "cq": CQ, "cq_paper": CQ, "near": NEAR, "loc": LOC, "js": JS, "jsa": JSA}
COORDINATE = 4  # LoC's fifth action (cq_ros.learners.loc.COORDINATE)
# meta: the pool's free slots, the next creation number
FREE, SEQ = 0, 1

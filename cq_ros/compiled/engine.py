"""The compiled engine: `run` plays one (algorithm, run) as cq_ros.engine.run does and returns the same RunResult,
byte for byte, drawing from the same Mersenne Twister streams (cq_ros.compiled.mt) as the reference's learners
and world. `Kernel` holds one run's world and learners as arrays; `team_of` hands them over as a reference Team
whose learners hold the learnt tables, the windows and the generators' states, so a run learnt here goes on in
the reference engine, a filmed episode or a ROS launch exactly as if the reference had learnt it.
"""

from __future__ import annotations

import copy
import random
import time
from collections.abc import Callable

import numpy as np
from numpy.lib import recfunctions

from .. import episode as record
from ..engine import RunResult, Team, learner_seed, make_learners, world_seed
from ..gridmap import GridMap
from ..settings import CONF_DROP, CONF_INIT, Settings
from ..stats import ConflictTest, _sums
from ..world import COLLISION_REACH, GridWorld, rewards_alone
from . import layout as L
from .algorithms import KERNEL_ALGORITHMS
from . import windows as W
from ..learners import CQ_LEARNERS as CQS  # their joint states live in the kernel's pool
from ..learners.base import N_MOVES, Learner
from ..learners.jsa import MAX_AGENTS
from .episode import play_many
from .mt import set_state, state_of
from .table import index_table
from .world import new_scratch

# the learners whose states with peers live in the kernel's table (cq_ros.compiled.table), by the attribute
# holding them in the reference learner
TABLES = {"near": "q_near", "loc": "q_coord", "js": "q_joint", "jsa": "q_joint"}
_EVERYWHERE = np.iinfo(np.int64).max  # the range of JS and JSA: every peer is seen


def new_table(cap: int, algo: str, n: int):
    """An empty table (cq_ros.compiled.table says its layout) of `cap` slots for `algo` and `n` agents: a
    row holds the moves, or JSA's 4^n joint actions."""
    width = N_MOVES ** n if algo == "jsa" else N_MOVES
    return (np.full((cap, n + 1), -1, np.int64), np.zeros((cap, width)), np.full(2 * cap, -1, np.int64),
            np.zeros(1, np.int64))


class Kernel:
    """One run's world and learners as the kernel's arrays (cq_ros.compiled.layout says their layout)."""

    def __init__(self, algo: str, gridmap: GridMap, settings: Settings, seed: int, run_index: int):
        if algo not in KERNEL_ALGORITHMS:
            raise ValueError(f"the compiled engine plays {', '.join(KERNEL_ALGORITHMS)}, not {algo!r}")
        if algo == "jsa" and gridmap.n_agents > MAX_AGENTS:
            raise ValueError(f"jsa supports at most {MAX_AGENTS} agents (4^n joint actions), "
                             f"the map has {gridmap.n_agents}")
        self.algo, self.map, self.settings, self.seed, self.run_index = algo, gridmap, settings, seed, run_index
        st, cq, tables, ours = settings, algo in CQS, algo in TABLES, algo == "cq"  # ours: cq.CQLearner's rules
        n, c = gridmap.n_agents, gridmap.n_cells
        rows, cols = zip(*gridmap.cells)
        self.geo = (np.array(gridmap.neighbours, np.int64), np.array(gridmap.starts, np.int64),
                    np.array(gridmap.goals, np.int64), np.array(rows, np.int64), np.array(cols, np.int64))
        test = ConflictTest(st.window, st.significance) if cq else None
        self.fp = np.array([st.alpha, st.gamma, st.epsilon, st.slip, st.reward_step, st.reward_wall,
                            st.reward_collision, st.reward_goal, CONF_INIT, st.conf_up, st.conf_down, st.conf_max,
                            CONF_DROP, test.t_two if cq else 0.0, test.t_one if cq else 0.0, st.loc_cost,
                            # the learners' state_count (JS's, JSA's: n_cells^n each), summed, as the episode's
                            # table holds it
                            float((1 if algo == "jsa" else n) * c ** n) if algo in ("js", "jsa") else 0.0])
        self.ip = np.array([c, st.step_cap, st.start_hold, st.epsilon_decay_episodes, 1, L.ALGO_CODES[algo],
                            ours,
                            COLLISION_REACH if algo in ("loc", "near") else _EVERYWHERE],
                           np.int64)
        self.world = (np.zeros(n, np.int64), np.zeros(n, np.bool_), np.zeros(n, np.int64),
                      # the world's generator as GridWorld's constructor leaves it
                      state_of(GridWorld(gridmap, settings, seed=world_seed(seed, run_index))._rng)[None],
                      new_scratch(n, c))
        self.ag = np.zeros((n, 11), np.int64)
        self.ag[:, L.NKEYS] = 1  # keys = [None]
        self.eps = np.full(n, st.epsilon)
        self.q = np.zeros((n, c, 5 if algo == "loc" else 4))  # LoC's Q* has COORDINATE
        self.mt = np.array([state_of(random.Random(learner_seed(seed, run_index, k))) for k in range(n)])
        cap = 64 if cq else 1
        cells_kept = (n, c) if cq else (1, 1)
        self.js = (np.full((cap, 7), -1, np.int64), np.zeros((cap, 5)), np.arange(cap - 1, -1, -1, dtype=np.int64),
                   np.array([cap, 0], np.int64), np.full(cells_kept, -1, np.int64),
                   np.full(cells_kept, -1, np.int64), np.zeros(n, np.int64))
        ck = np.full((n, 2 * n), -1, np.int64)
        self.cq = (np.zeros((n, 8), np.int64), np.zeros(n), np.full((n, 4 * n), -1, np.int64), ck,
                   np.zeros(n, np.int64))
        self.win = W.new_windows((n, c * 4) if cq else (1, 1), st.window, self.fp[[L.R_STEP, L.R_WALL, L.R_COLL,
                                                                                  L.R_GOAL]])
        self.tab = new_table(64 if tables else 1, algo, n)
        if ours:
            self._w1_alone()

    def _w1_alone(self) -> None:
        """W1 of every window full of what acting alone earns, as CQLearner's constructor fills it:
        the sums of rewards_alone's list, one per kind of move (a wall, the goal, a step)."""
        wi, wf = self.win[0], self.win[1]
        nbr, goals = self.geo[0], self.geo[2]
        cells = np.arange(self.map.n_cells)[:, None]
        wi[..., W.N1] = self.settings.window
        for k in range(self.map.n_agents):
            kinds = np.where(nbr == cells, 0, np.where(nbr == goals[k], 1, 2)).ravel()
            for kind in (0, 1, 2):
                where = np.flatnonzero(kinds == kind)
                if where.size:
                    s, a = divmod(int(where[0]), 4)
                    wf[k, where, W.SUM1], wf[k, where, W.SQ1] = _sums(
                        rewards_alone(self.map, self.settings, k, s, a, self.settings.window))

    def play(self, episodes: int, on_episode: Callable[[], None] | None = None) -> np.ndarray:
        """Play `episodes` episodes; their table (cq_ros.episode). Episodes go to the kernel in batches that
        grow while one takes under a tenth of a second, `on_episode` called after each batch for each episode."""
        out = np.zeros((episodes, len(record.COLUMNS)))
        done, batch = 0, 1
        while done < episodes:
            size = min(batch, episodes - done)
            started = time.perf_counter()
            try:
                jsi, jsf, free, pool, tk, tq, th = play_many(self.geo, self.fp, self.ip, self.world, self.ag,
                                                             self.eps, self.q, self.mt, self.js, self.cq, self.win,
                                                             self.tab, out[done:done + size])
            except SystemError as e:  # Ctrl-C (or SIGTERM, as the CLI raises it) while numba called back into
                interrupt = _interrupt(e)  # Python: numba wraps it; it goes on as what it was
                if interrupt is not None:
                    raise interrupt from e
                raise
            self.js = (jsi, jsf, free, *self.js[3:])
            self.win = (*self.win[:2], pool, *self.win[3:])
            self.tab = (tk, tq, th, self.tab[3])
            done += size
            if time.perf_counter() - started < 0.1:
                batch *= 2
            if on_episode is not None:
                for _ in range(size):
                    on_episode()
        return recfunctions.unstructured_to_structured(out, record.DTYPE) if episodes else record.table(())

    def learnt(self) -> tuple[np.ndarray, ...]:
        """The arrays only a learning step writes: Q_k, the joint-state pool and its cells' lists, the windows and
        their samples, the table. A frozen learner's episodes read them and leave them as they were."""
        jsi, jsf, free, _meta, head, tail, _n_js = self.js
        return (self.q, jsi, jsf, free, head, tail, *self.win[:3], *self.tab[:3])

    def greedy(self, learning: bool | None = None, keep: bool = True) -> "Kernel":
        """engine.greedy_team: at epsilon 0, frozen unless `learning` (None: settings.eval_learning). A copy, or
        (`keep` False, for a caller done with the run) the kernel itself, which costs no memory. A frozen copy
        shares `learnt()` with the run and copies the rest (the agents' counters, generators, step state): a
        deep copy held every window and row again, on a MovingAI-size map as much as the run itself."""
        learning = bool(self.settings.eval_learning if learning is None else learning)
        if not keep:
            other = self
        elif learning:
            other = copy.deepcopy(self)
        else:
            other = copy.deepcopy(self, {id(a): a for a in self.learnt()})
        other.eps[:] = 0.0
        other.ip[L.LEARNING] = int(learning)
        return other

    def joint_states(self) -> list[tuple[int, int, int, int, float]]:
        """RunResult.joint_states: (agent, cell, peer, peer_cell, confidence), each agent's in marking order."""
        jsi, jsf = self.js[0], self.js[1]
        alive = np.flatnonzero(jsi[:, L.JS_SEQ] >= 0)
        alive = alive[np.lexsort((jsi[alive, L.JS_SEQ], jsi[alive, L.JS_AGENT]))]
        return [(int(jsi[i, L.JS_AGENT]), int(jsi[i, L.JS_S]), int(jsi[i, L.JS_J]), int(jsi[i, L.JS_C]),
                 float(jsf[i, L.CONF])) for i in alive]


def _interrupt(error: BaseException | None) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt (or subclass) among an error's causes, if any."""
    while error is not None:
        if isinstance(error, KeyboardInterrupt):
            return error
        error = error.__cause__ or error.__context__
    return None


def run(algo: str, gridmap: GridMap, settings: Settings, seed: int, run_index: int, episodes: int,
        on_episode: Callable[[], None] | None = None) -> RunResult:
    """cq_ros.engine.run, compiled (for KERNEL_ALGORITHMS)."""
    kernel = Kernel(algo, gridmap, settings, seed, run_index)
    table = kernel.play(episodes, on_episode)
    kept = kernel.joint_states()
    greedy = kernel.greedy(keep=False).play(settings.eval_episodes) if settings.eval_episodes else record.table(())
    return RunResult(algo, run_index, table, kept, greedy, engine="compiled")


_WARM_MAP = """agent 1: start 0,0  goal 0,2
agent 2: start 0,2  goal 0,0

+-+-+-+
|. . .|
+-+-+-+
"""


def warm_up() -> None:
    """Load the kernel (compile it where no cache holds it): a few episodes of CQ, under delays, on a tiny map."""
    from ..gridmap import parse_map

    Kernel("cq", parse_map(_WARM_MAP), Settings(window=2, slip=0.1, step_cap=20), 0, 0).play(3)


def _js_key(jsi, slot) -> tuple[int, int, int]:
    return int(jsi[slot, L.JS_S]), int(jsi[slot, L.JS_J]), int(jsi[slot, L.JS_C])


def _state_key(key: np.ndarray, k: int, joint: bool) -> tuple:
    """A table key of agent k as the reference's: (cell, near), the peers in range with their cells; for a
    joint-state learner (JS, JSA) every cell, its own first."""
    cells = key[1:].tolist()
    if joint:
        return cells[k], *cells[:k], *cells[k + 1:]
    return cells[k], tuple((j, c) for j, c in enumerate(cells) if j != k and c >= 0)


def _hand_over(kernel: Kernel, learner: Learner, k: int) -> None:
    """Learner k of the kernel, as the reference learner `learner` (fresh from make_learners) holds it."""
    set_state(learner.rng, kernel.mt[k])
    ag = kernel.ag[k]
    learner.epsilon = float(kernel.eps[k])
    learner.learning = bool(kernel.ip[L.LEARNING])
    learner.episodes_played, learner.joint_plays, learner.heard = (int(ag[L.PLAYED]), int(ag[L.PLAYS]),
                                                                   int(ag[L.HEARD]))
    learner.a = int(ag[L.A])
    if not learner.central:  # the central learner's state is the cells, observed afresh at each step
        learner.s = int(ag[L.S])
    if hasattr(learner, "q_local"):  # JS and JSA keep none
        learner.q_local = kernel.q[k].tolist()
    if kernel.algo in TABLES:
        tk, tq, used = kernel.tab[0], kernel.tab[1], int(kernel.tab[3][0])
        mine = np.flatnonzero(tk[:used, 0] == k)
        setattr(learner, TABLES[kernel.algo], {_state_key(tk[i], k, learner.joint_state): tq[i].tolist()
                                                      for i in mine})
    if kernel.algo not in CQS:
        return
    jsi, jsf = kernel.js[0], kernel.js[1]
    learner.dropped_updates = int(ag[L.DROPPED])
    learner.looking = bool(ag[L.LOOKING])
    mine = np.flatnonzero((jsi[:, L.JS_SEQ] >= 0) & (jsi[:, L.JS_AGENT] == k))
    mine = mine[np.argsort(jsi[mine, L.JS_SEQ])]
    learner.q_joint = {_js_key(jsi, i): jsf[i, 1:].tolist() for i in mine}
    learner.confidence = {_js_key(jsi, i): float(jsf[i, L.CONF]) for i in mine}
    learner.marked, learner.watch = {}, {}
    for i in mine:
        learner.marked.setdefault(int(jsi[i, L.JS_S]), []).append(_js_key(jsi, i))
    for s in learner.marked:
        learner._rewatch(s)
    learner.keys = [None if key < 0 else _js_key(jsi, key) for key in kernel.cq[3][k, :ag[L.NKEYS]]]
    assert not kernel.cq[0][k, L.W_ON], "between episodes no step waits"
    learner.waiting = None
    wi, wf, pool, vals = kernel.win[0][k], kernel.win[1][k], kernel.win[2], kernel.win[5]
    size = pool.shape[1]
    for w in np.flatnonzero(wi[:, W.BUF] >= 0):  # the windows untouched are as the learner's constructor made them
        windows, ints, floats, buf = learner.windows[w], wi[w], wf[w], vals[pool[wi[w, W.BUF]]]
        windows.n1 = int(ints[W.N1])
        windows.w1 = buf[:windows.n1].tolist() if windows.n1 < size else []
        windows.w2 = buf[:ints[W.N2]].tolist() if windows.n1 == size else []
        windows.head, windows.exact2 = int(ints[W.HEAD]), bool(ints[W.EXACT2])
        windows.sum1, windows.sq1, windows.sum2, windows.sq2 = (float(v) for v in floats)


def team_of(kernel: Kernel) -> Team:
    """The kernel's run as a reference Team (learners and world), between episodes: it plays on as the reference
    would have, had it learnt what the kernel learnt."""
    learners = make_learners(kernel.algo, kernel.map, kernel.settings, kernel.seed, kernel.run_index)
    for k, learner in enumerate(learners):
        _hand_over(kernel, learner, k)
    world = GridWorld(kernel.map, kernel.settings)
    set_state(world._rng, kernel.world[3][0])
    return Team(world, learners)


def _take_over(kernel: Kernel, learner: Learner, k: int, slots: dict[tuple[int, tuple], int]) -> None:
    """Learner k of the kernel from the reference learner `learner` (between episodes): _hand_over's inverse.
    `slots` gathers the pool slot of each (agent, joint state), in each learner's creation order."""
    kernel.mt[k] = state_of(learner.rng)
    ag = kernel.ag[k]
    kernel.eps[k] = learner.epsilon
    ag[L.PLAYED], ag[L.PLAYS], ag[L.HEARD] = learner.episodes_played, learner.joint_plays, learner.heard
    ag[L.A] = getattr(learner, "a", 0)
    if not learner.central:  # the central learner's state is the cells, observed afresh at each step
        ag[L.S] = getattr(learner, "s", 0)
    if hasattr(learner, "q_local"):  # JS and JSA keep none: the kernel's stays zeros
        kernel.q[k] = learner.q_local
    if getattr(learner, "waiting", None) is not None:
        raise ValueError(f"a {kernel.algo} learner hands over between episodes, where no step waits")
    if kernel.algo in TABLES:
        tk, tq, tm = kernel.tab[0], kernel.tab[1], kernel.tab[3]
        table = getattr(learner, TABLES[kernel.algo])
        for state, row in table.items():  # into a fresh table's free slots (kernel_of indexes them)
            tk[tm[0], 0] = k
            if learner.joint_state:
                tk[tm[0], 1:] = (*state[1:k + 1], state[0], *state[k + 1:])
            else:
                tk[tm[0], 1 + k] = state[0]
                for j, c in state[1]:
                    tk[tm[0], 1 + j] = c
            tq[tm[0]] = row
            tm[0] += 1
        kernel.js[6][k] = len(table)
    if kernel.algo not in CQS:
        return
    ag[L.DROPPED], ag[L.LOOKING] = learner.dropped_updates, learner.looking
    jsi, jsf = kernel.js[0], kernel.js[1]
    head, tail, n_js = kernel.js[4], kernel.js[5], kernel.js[6]
    for key, row in learner.q_joint.items():
        slot = slots[k, key] = len(slots)
        jsi[slot, [L.JS_S, L.JS_J, L.JS_C, L.JS_SEQ, L.JS_AGENT]] = (*key, slot, k)
        jsf[slot] = (learner.confidence[key], *row)
    for s, keys in learner.marked.items():  # each cell's list in marking order
        chain = [slots[k, key] for key in keys]
        head[k, s], tail[k, s] = chain[0], chain[-1]
        for prev, slot, nxt in zip([-1, *chain], chain, [*chain[1:], -1]):
            jsi[slot, L.JS_PREV], jsi[slot, L.JS_NEXT] = prev, nxt
    n_js[k] = len(learner.q_joint)
    ag[L.NKEYS] = len(learner.keys)
    kernel.cq[3][k, :len(learner.keys)] = [-1 if key is None else slots[k, key] for key in learner.keys]
    wi, wf = kernel.win[0][k], kernel.win[1][k]
    rows = []
    for w, windows in enumerate(learner.windows):
        samples = windows.w1 or windows.w2
        wi[w, [W.N1, W.N2, W.HEAD, W.EXACT2, W.BUF]] = (windows.n1, len(windows.w2), windows.head, windows.exact2,
                                                        -1)
        wf[w] = (windows.sum1, windows.sq1, windows.sum2, windows.sq2)
        if samples or windows.n1 == windows.size:  # the kernel keeps a row from a window's first reward on
            wi[w, W.BUF] = kernel.win[3][0] + len(rows)
            rows.append(samples)
    if rows:
        pool, used = kernel.win[2], kernel.win[3]
        pool = W.room(pool, used, len(rows))
        kinds, vals = W.kinds_of(kernel.win[5], np.concatenate([np.asarray(samples, np.float64) for samples in rows]))
        at = 0
        for i, samples in enumerate(rows):
            pool[used[0] + i, :len(samples)] = kinds[at:at + len(samples)]
            at += len(samples)
        used[0] += len(rows)
        kernel.win = (*kernel.win[:2], pool, used, kernel.win[4], vals, kernel.win[6])


def _slots_for(need: int) -> int:
    """A pool's or the table's size holding `need` slots: 64, doubled as often as that needs."""
    cap = 64
    while cap < need:
        cap *= 2
    return cap


def kernel_of(team: Team, seed: int = 0, run_index: int = 0) -> Kernel:
    """A reference Team (learners and world, between episodes: fresh, learnt or loaded from checkpoints) as the
    kernel's arrays: it plays on as the reference would have (team_of's inverse). `seed` and `run_index` only
    name the run; the generators' states are the team's."""
    learners = team.learners
    algo = learners[0].name
    kernel = Kernel(algo, team.world.map, learners[0].settings, seed, run_index)
    kernel.ip[L.LEARNING] = int(learners[0].learning)
    kernel.world[3][0] = state_of(team.world._rng)
    if algo in CQS:
        total = sum(len(learner.q_joint) for learner in learners)
        cap = _slots_for(total + len(learners) ** 2)
        jsi, jsf, free, meta, head, tail, n_js = (np.full((cap, 7), -1, np.int64), np.zeros((cap, 5)),
                                                  np.arange(cap - 1, total - 1, -1, dtype=np.int64),
                                                  np.array([cap - total, total], np.int64), *kernel.js[4:])
        free = np.concatenate([free, np.zeros(total, np.int64)])
        kernel.js = (jsi, jsf, free, meta, head, tail, n_js)
    if algo in TABLES:
        n = team.world.map.n_agents
        kernel.tab = new_table(_slots_for(sum(len(getattr(learner, TABLES[algo])) for learner in learners) + 2 * n),
                               algo, n)
    slots: dict[tuple[int, tuple], int] = {}
    for k, learner in enumerate(learners):
        _take_over(kernel, learner, k, slots)
    if algo in TABLES:
        index_table(kernel.tab[0], kernel.tab[2], kernel.tab[3][0])
    return kernel

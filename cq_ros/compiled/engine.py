"""The compiled engine: `run` plays one (algorithm, run) as cq_ros.engine.run does and returns the same RunResult,
byte for byte, drawing from the same Mersenne Twister streams (cq_ros.compiled.mt) as the reference's learners
and world. `Kernel` holds one run's world and learners as arrays; `Kernel.learners()` hands them over as
reference learner objects (the learnt tables, the windows, the generators' states), so a run learnt here goes
on in the reference engine, a filmed episode or a ROS launch exactly as if the reference had learnt it.
"""

from __future__ import annotations

import copy
import random
from collections.abc import Callable

import numpy as np
from numpy.lib import recfunctions

from .. import episode as record
from ..engine import RunResult, learner_seed, world_seed
from ..gridmap import GridMap
from ..settings import Settings
from ..stats import ConflictTest, _sums
from ..world import GridWorld, rewards_alone
from . import learners as K
from . import windows as W
from .mt import state_of
from .world import new_scratch

ALGORITHMS = ("indep", "cq")  # the learners the kernel plays; the others play on the reference engine


class Kernel:
    """One run's world and learners as the kernel's arrays (cq_ros.compiled.learners says their layout)."""

    def __init__(self, algo: str, gridmap: GridMap, settings: Settings, seed: int, run_index: int):
        if algo not in ALGORITHMS:
            raise ValueError(f"the compiled engine plays {', '.join(ALGORITHMS)}, not {algo!r}")
        self.algo, self.map, self.settings, self.run_index = algo, gridmap, settings, run_index
        st, cq = settings, algo == "cq"
        n, c = gridmap.n_agents, gridmap.n_cells
        rows, cols = zip(*gridmap.cells)
        self.geo = (np.array(gridmap.neighbours, np.int64), np.array(gridmap.starts, np.int64),
                    np.array(gridmap.goals, np.int64), np.array(rows, np.int64), np.array(cols, np.int64))
        test = ConflictTest(st.window, st.significance) if cq else None
        self.fp = np.array([st.alpha, st.gamma, st.epsilon, st.slip, st.reward_step, st.reward_wall,
                            st.reward_collision, st.reward_goal, st.conf_init, st.conf_up, st.conf_down, st.conf_max,
                            st.conf_drop, test.t_two if cq else 0.0, test.t_one if cq else 0.0])
        self.ip = np.array([c, st.step_cap, st.start_hold, st.epsilon_decay_episodes, 1, int(cq), st.cq_mark_range,
                            st.cq_mark_colliders, st.cq_bootstrap_acted, st.cq_all_met, st.cq_waits_fresh,
                            st.cq_look_if_decisive], np.int64)
        self.world = (np.zeros(n, np.int64), np.zeros(n, np.bool_), np.zeros(n, np.int64),
                      state_of(GridWorld(gridmap, settings, seed=world_seed(seed, run_index))._rng),  # as constructed
                      new_scratch(n, c))
        self.ag = np.zeros((n, 10), np.int64)
        self.ag[:, K.NKEYS] = 1  # keys = [None]
        self.eps = np.full(n, st.epsilon)
        self.q = np.zeros((n, c, 4))
        self.mt = np.array([state_of(random.Random(learner_seed(seed, run_index, k))) for k in range(n)])
        cap = 64 if cq else 1
        cells_kept = (n, c) if cq else (1, 1)
        self.js = (np.full((cap, 7), -1, np.int64), np.zeros((cap, 5)), np.arange(cap - 1, -1, -1, dtype=np.int64),
                   np.array([cap, 0], np.int64), np.full(cells_kept, -1, np.int64),
                   np.full(cells_kept, -1, np.int64), np.zeros(n, np.int64))
        ck = np.full((n, 2 * n), -1, np.int64)
        self.cq = (np.zeros((n, 8), np.int64), np.zeros(n), np.full((n, 4 * n), -1, np.int64), ck,
                   np.zeros(n, np.int64), np.zeros(n, np.bool_))
        self.win = W.new_windows((n, c * 4) if cq else (1, 1), st.window)
        if cq and st.cq_w1_alone:
            self._w1_alone()

    def _w1_alone(self) -> None:
        """W1 of every window full of what acting alone earns (cq_w1_alone), as CQLearner's constructor fills it:
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
        import time

        out = np.zeros((episodes, len(record.COLUMNS)))
        done, batch = 0, 1
        while done < episodes:
            size = min(batch, episodes - done)
            started = time.perf_counter()
            jsi, jsf, free, pool = K.play_many(self.geo, self.fp, self.ip, self.world, self.ag, self.eps, self.q,
                                               self.mt, self.js, self.cq, self.win, out[done:done + size])
            self.js = (jsi, jsf, free, *self.js[3:])
            self.win = (*self.win[:2], pool, self.win[3])
            done += size
            if time.perf_counter() - started < 0.1:
                batch *= 2
            if on_episode is not None:
                for _ in range(size):
                    on_episode()
        return recfunctions.unstructured_to_structured(out, record.DTYPE) if episodes else record.table(())

    def greedy(self) -> "Kernel":
        """engine.greedy_team: a copy at epsilon 0, frozen unless settings.eval_learning."""
        other = copy.deepcopy(self)
        other.eps[:] = 0.0
        other.ip[K.LEARNING] = int(bool(self.settings.eval_learning))
        return other

    def joint_states(self) -> list[tuple[int, int, int, int, float]]:
        """RunResult.joint_states: (agent, cell, peer, peer_cell, confidence), each agent's in marking order."""
        jsi, jsf = self.js[0], self.js[1]
        alive = np.flatnonzero(jsi[:, K.JS_SEQ] >= 0)
        alive = alive[np.lexsort((jsi[alive, K.JS_SEQ], jsi[alive, K.JS_AGENT]))]
        return [(int(jsi[i, K.JS_AGENT]), int(jsi[i, K.JS_S]), int(jsi[i, K.JS_J]), int(jsi[i, K.JS_C]),
                 float(jsf[i, K.CONF])) for i in alive]


def run(algo: str, gridmap: GridMap, settings: Settings, seed: int, run_index: int, episodes: int,
        on_episode: Callable[[], None] | None = None) -> RunResult:
    """cq_ros.engine.run, compiled (for ALGORITHMS)."""
    kernel = Kernel(algo, gridmap, settings, seed, run_index)
    table = kernel.play(episodes, on_episode)
    greedy = kernel.greedy().play(settings.eval_episodes) if settings.eval_episodes else record.table(())
    return RunResult(algo, run_index, table, kernel.joint_states(), greedy)

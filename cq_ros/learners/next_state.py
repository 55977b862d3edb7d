"""What the learners whose state holds their peers' cells share (JS, near): the next state includes the peers'
next cells, which the agent sees only when it next acts, so a step's update waits there (and is made at once,
without bootstrap, when the agent reaches its goal). A step cut by the step cap has no next state to
bootstrap from and is left out rather than guessed. These learners drop no state, so a waiting step may hold
its row itself."""

from .base import Learner, epsilon_greedy, q_update


class NextStateLearner(Learner):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.waiting = None  # (row, action, reward): a step waiting for the next state's row

    def act_on(self, row: list[float]) -> int:
        """Finish the waiting update from `row`, the row of the state seen now, and choose on it."""
        last, self.waiting = self.waiting, None
        if last is not None:
            self._update(last, row)
        self.row = row
        self.a = epsilon_greedy(row, self.epsilon, self.rng)
        return self.a

    def learn(self, reward, next_cell, done):
        if not self.learning:
            return
        step = (self.row, self.a, reward)
        if done:
            self._update(step, None)
        else:
            self.waiting = step

    def _update(self, step, next_row):
        """Q(s, a) <- (1 - alpha) Q(s, a) + alpha [r + gamma max_a' Q(s', a')]; `next_row` None: the step reached
        the goal, nothing follows it."""
        row, a, reward = step
        target = reward if next_row is None else reward + self.gamma * max(next_row)
        q_update(row, a, target, self.alpha)

    def end_episode(self):
        super().end_episode()
        self.waiting = None

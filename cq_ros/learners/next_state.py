"""What the learners whose state holds their peers' cells share (JS, near): the next state includes the peers'
next cells, which the agent sees only when it next acts, so a step's update is finished there (at once,
without bootstrap, when the agent reaches its goal). A step cut by the step cap has no next state to
bootstrap from and is left out rather than guessed."""

from .base import Learner, epsilon_greedy, q_update


class NextStateLearner(Learner):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.pending = None  # (row, action, reward) waiting for the next state's row

    def act_on(self, row: list[float]) -> int:
        """Finish the waiting update from `row`, the row of the state seen now, and choose on it."""
        if self.pending is not None:
            prev, a, reward = self.pending
            q_update(prev, a, reward + self.gamma * max(row), self.alpha)
            self.pending = None
        self.row = row
        self.a = epsilon_greedy(row, self.epsilon, self.rng)
        return self.a

    def learn(self, reward, next_cell, done):
        if not self.learning:
            return
        if done:
            q_update(self.row, self.a, reward, self.alpha)
        else:
            self.pending = (self.row, self.a, reward)

    def end_episode(self):
        super().end_episode()
        self.pending = None

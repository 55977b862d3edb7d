"""The yardstick the learners are measured against: a central multi-agent path planner under the world's own
rules, and the executor that carries its plan out in the delayed world. Planned, not learned."""

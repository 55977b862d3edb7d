"""Our gridworlds behind the interfaces other RL tooling expects (PettingZoo's ParallelEnv)."""

"""What `cq-ros reproduce` runs: the paper's four maps x five algorithms, the same grid with exploration that
stops, the settings the sweep moves, our CQ (`cq`) beside the paper's (`cq_paper`, the grid's), and where each
master seed's grid goes. The run (reproduce.py), the claims (reproduce_claims.py) and REPORT.md
(reproduce_report.py) read them here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ..settings import Settings

PAPER_MAPS = ("grid_game_2", "tunnel_to_goal", "tunnel_to_goal_3", "isr")
SWEEP_MAP = "tunnel_to_goal_3"
# With exploration gone, a greedy policy that misses its goal loops until the step cap: 500 steps (for
# every algorithm alike) keeps such runs to seconds; those episodes count as truncated.
DECAY_STEP_CAP = 500
CQ = "cq_paper"  # the CQ of the paper's grid, whose claims are checked
OURS, OURS_DIR = "cq", "ours"  # our CQ beside it on the four maps, first seed, fixed exploration


@dataclass(frozen=True)
class Variant:
    name: str
    why: str
    changes: dict


def sweep_variants(base: Settings) -> list[Variant]:
    """The settings the paper leaves open, each moved on its own from our defaults."""
    scaled = {k: getattr(base, k) * 0.1 for k in ("reward_step", "reward_wall", "reward_collision", "reward_goal")}
    return [
        Variant("defaults", "our defaults", {}),
        Variant("rewards_x0.1", "every reward scaled by 0.1", scaled),
        Variant("collision_-2", "a milder collision penalty (-2 instead of -10)", {"reward_collision": -2.0}),
        Variant("step_-1", "a cost of -1 per step", {"reward_step": -1.0}),
        Variant("significance_0.01", "stricter t-tests", {"significance": 0.01}),
        Variant("significance_0.10", "looser t-tests", {"significance": 0.10}),
        Variant("gamma_0.95", "a longer horizon", {"gamma": 0.95}),
        Variant("confidence_fading", "joint states fade fast (conf_up 0.1, conf_max 1)",
                {"conf_up": 0.1, "conf_max": 1.0}),
    ]


def decaying(settings: Settings, episodes: int) -> Settings:
    """Exploration that stops: epsilon falls linearly to 0 over the first half of the episodes."""
    return settings.with_overrides({"epsilon_decay_episodes": max(1, episodes // 2),
                                    "step_cap": min(settings.step_cap, DECAY_STEP_CAP)})


def seed_dir(out: Path, seeds: Sequence[int], seed: int) -> Path:
    """Where a seed's grid goes: the first seed's in `out` itself, the others' in out/seed_<seed>."""
    return out if seed == seeds[0] else out / f"seed_{seed}"

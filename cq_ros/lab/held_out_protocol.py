"""A held-out study's protocol and files (held_out.py runs the study, held_out_report.py writes its tables): the
generator seeds its maps come from, its configurations (learners, and variants with settings of their own),
the protocol study.json keeps, which a resume must match, and the rows of its csv files.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ..learners import LEARNERS
from .output import check_folder
from .results import ResultExists

# Generator seeds: those the settings were chosen on (docs/choices.md), and the block the study draws from,
# which no tuning run, and no document or test but the study's own, names (map i of a size is
# HELD_OUT_SEEDS[i]).
TUNING_SEEDS = (0, 7)
HELD_OUT_SEEDS = range(1001, 1101)
COPIES = ("frozen", "learning")  # eval_learning 0 and 1
KEY = ("agents", "generator_seed", "run", "config")


@dataclass(frozen=True)
class Config:
    name: str
    algo: str
    sets: tuple[str, ...] = ()  # settings of its own ("key=value"), over the study's

    def record(self) -> dict:
        """As study.json keeps it (`sets` only where there are any, as in studies kept before variants were)."""
        kept = {"name": self.name, "algo": self.algo}
        return {**kept, "sets": list(self.sets)} if self.sets else kept

    @classmethod
    def of_record(cls, record: dict) -> "Config":
        return cls(**{**record, "sets": tuple(record.get("sets", ()))})


def parse_variant(spec: str) -> Config:
    """"cq_a2=cq:alpha=0.2,gamma=0.95" -> Config("cq_a2", "cq", sets=("alpha=0.2", "gamma=0.95"))."""
    name, sep, rest = spec.partition("=")
    algo, _, pairs = rest.partition(":")
    if not sep or not name or not algo:
        raise ValueError(f"--variant takes NAME=ALGO:KEY=VALUE,..., got {spec!r}")
    if algo not in LEARNERS:
        raise ValueError(f"--variant {spec!r}: unknown algorithm {algo!r}; choose from {','.join(LEARNERS)}")
    return Config(name, algo, sets=tuple(pair for pair in pairs.split(",") if pair))


def parse_configs(algos: Sequence[str], variants: Sequence[str] = ()) -> list[Config]:
    """The learners by name, then each variant (NAME=ALGO:KEY=VALUE,...: a learner with settings of its own)."""
    configs = [Config(a, a) for a in algos]
    configs += [parse_variant(v) for v in variants]
    names = [c.name for c in configs]
    if len(set(names)) < len(names):
        raise ValueError(f"configuration names must differ, got {', '.join(names)}")
    return configs


def generator_seeds(tuning: bool) -> Sequence[int]:
    """The generator seeds a study draws its maps from, in order: the tuning seeds, or the held-out ones."""
    return TUNING_SEEDS if tuning else HELD_OUT_SEEDS


def protocol_of(episodes: int, greedy_episodes: int, curve_every: int, curve_episodes: int, seed: int, slip: float,
                overrides: Sequence[str], configs: Sequence[Config], tuning: bool = False,
                settings: dict[str, dict] | None = None) -> dict:
    """What a resumed study must share with the units already played (maps, runs, sizes and configurations may
    grow; a configuration keeps its algorithm and settings, and the settings they resolve to, `settings`,
    which a change of the code's defaults moves). A tuning study says so (`generator_seeds`); a held-out one, as
    every study kept before tuning studies were, has no such key."""
    return {"episodes": episodes, "greedy_episodes": greedy_episodes, "curve_every": curve_every,
            "curve_episodes": curve_episodes, "seed": seed, "slip": slip, "overrides": list(overrides),
            **({"generator_seeds": "tuning"} if tuning else {}),
            "configs": {c.name: c.record() for c in configs}, "settings": settings or {}}


def settings_moved(old: dict, new: dict) -> list[str]:
    """For each configuration both protocols resolved, the settings whose values differ, as "name (key a -> b)"."""
    moved = []
    for name in sorted(set(old) & set(new)):
        keys = [k for k in sorted(set(old[name]) | set(new[name])) if old[name].get(k) != new[name].get(k)]
        if keys:
            moved.append(f"the settings of {name} ("
                         + ", ".join(f"{k} {old[name].get(k)} -> {new[name].get(k)}" for k in keys) + ")")
    return moved


def seeds_of(protocol: dict) -> Sequence[int]:
    return generator_seeds(protocol.get("generator_seeds") == "tuning")


def open_output(out: Path, protocol: dict, force: bool) -> Path:
    """OUT, new, or holding a study of the same protocol (to resume it); with force, emptied first."""
    out = Path(out)
    kept = out / "study.json"
    if out.is_dir() and any(out.iterdir()):
        if force:
            for name in ("units.csv", "curve.csv", "planner.csv", "study.json", "study.md"):
                (out / name).unlink(missing_ok=True)
            for path in (out / "maps").glob("warehouse_*_gen*.txt"):
                path.unlink()
        elif not kept.exists():
            raise ResultExists(f"output directory {out} is not empty and holds no study; choose another or pass "
                               "--force to overwrite")
        else:
            old = json.loads(kept.read_text())
            mine = {k: v for k, v in protocol.items() if k not in ("configs", "settings", "shown")}
            clash = [k for k in {*mine, "generator_seeds"} if old.get(k) != mine.get(k)] + [
                name for name, c in protocol["configs"].items() if old["configs"].get(name, c) != c] + settings_moved(
                old.get("settings", {}), protocol["settings"])
            if clash:
                raise ResultExists(f"output directory {out} holds a study of another protocol ({', '.join(clash)} "
                                   "differ); choose another or pass --force to overwrite")
            protocol = {**old, **protocol, "configs": {**old["configs"], **protocol["configs"]},
                        "settings": {**old.get("settings", {}), **protocol["settings"]}}
    out = check_folder(out, "output directory")
    kept.write_text(json.dumps(protocol, indent=1) + "\n")
    return out


def read_rows(path: Path) -> list[dict]:
    """A csv's rows, numbers as numbers (the configuration's name stays a string)."""
    if not path.exists():
        return []
    with open(path, newline="") as f:
        return [{k: v if k == "config" else (int(v) if k in KEY else float(v)) for k, v in row.items()}
                for row in csv.DictReader(f)]


def append_rows(path: Path, rows: list[dict]) -> None:
    new = not path.exists()
    with open(path, "a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        if new:
            writer.writeheader()
        writer.writerows(rows)

"""`cq-ros study` (cq_ros.lab.held_out) end to end on a tiny study: its units come from one learning run each
(the frozen and learning greedy copies are those `cq-ros experiment` plays with eval_learning 0 and 1), a rerun
plays nothing twice, and its tables are cq_ros.lab.study's arithmetic on the units it kept."""

import csv
from pathlib import Path

import pytest

from cq_ros import compiled
from cq_ros.lab import held_out as held_out_module
from cq_ros.cli.main import main
from cq_ros.gridmap import load_map
from cq_ros.lab.held_out_protocol import HELD_OUT_SEEDS, TUNING_SEEDS
from cq_ros.lab.held_out_report import BOOTSTRAP_SEED, show_ratio, shown_rows
from cq_ros.lab.study import mean_interval, paired_difference, ratio_interval
from cq_ros.settings import run_settings

TINY = ["study", "--agents", "4", "--maps", "2", "--episodes", "20", "--greedy-episodes", "3", "--curve-every", "10",
        "--curve-episodes", "2", "--set", "step_cap=60", "--jobs", "1"]


ROOT = Path(__file__).resolve().parents[1]


def rows_of(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_a_tiny_study_resumes_and_its_tables_are_the_units_arithmetic(tmp_path, capsys, monkeypatch):
    out = tmp_path / "study"
    assert main([*TINY, "--runs", "2", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "study: planning warehouse_4_gen1001.txt (1/2)" in captured.err and "study: unit 8/8" in captured.err
    assert not set(HELD_OUT_SEEDS) & set(TUNING_SEEDS)
    rows = rows_of(out / "units.csv")
    assert len(rows) == 2 * 2 * 2  # maps x runs x configurations
    assert {r["generator_seed"] for r in rows} == {"1001", "1002"}
    # the curve: a frozen copy after 10 episodes, and the frozen copy's figure at the end (20)
    curve = rows_of(out / "curve.csv")
    assert sorted({int(r["episode"]) for r in curve}) == [10, 20] and len(curve) == 2 * len(rows)
    for r in rows:
        end = [c for c in curve if (c["generator_seed"], c["run"], c["config"], c["episode"])
               == (r["generator_seed"], r["run"], r["config"], "20")]
        assert [float(c["collisions"]) for c in end] == [float(r["frozen_collisions"])]

    # One learning run per unit: its frozen and learning copies are the experiment's greedy episodes with
    # eval_learning 0 and 1 (the curve's copies leave the run as it was).
    gridmap = load_map(out / "maps" / "warehouse_4_gen1002.txt")
    unit = next(r for r in rows if (r["generator_seed"], r["run"], r["config"]) == ("1002", "1", "cq"))
    for copy, learning in (("frozen", 0), ("learning", 1)):
        settings = run_settings(gridmap, ["step_cap=60", f"eval_learning={learning}", "eval_episodes=3"])
        played = compiled.play("cq", gridmap, settings, 0, 1, 20)
        assert float(unit[f"{copy}_collisions"]) == played.greedy["collisions"].mean()
        assert float(unit[f"{copy}_makespan"]) == played.greedy["steps"].mean()
        assert float(unit["states"]) == played.episodes["states"][-1]

    text = (out / "study.md").read_text()
    assert captured.out == text and "Generator seeds 1001-1002 (held out; tuning seeds 0, 7 never)" in text

    def values(config, column):
        mine = sorted((r for r in rows if r["config"] == config), key=lambda r: (r["generator_seed"], r["run"]))
        return [float(r[column]) for r in mine]

    for copy in ("frozen", "learning"):
        part = text.split(f"Greedy policy, {copy}:")[1]
        assert f"| cq | {mean_interval(values('cq', f'{copy}_collisions')).show(3)} | " in part
        difference = paired_difference(values("indep", f"{copy}_collisions"), values("cq", f"{copy}_collisions"))
        assert f"| indep - cq | {difference.show(3)} | " in part
        ratio = ratio_interval(values("indep", f"{copy}_collisions"), values("cq", f"{copy}_collisions"),
                               BOOTSTRAP_SEED)
        assert f"| indep | {show_ratio(ratio)} | - (divides by 0) |" in part  # indep hears nothing

    # A rerun plays nothing; one with a run more plays that run's units only; another protocol is refused.
    assert main([*TINY, "--runs", "2", "--out", str(out)]) == 0
    assert "8 units of" in capsys.readouterr().err and len(rows_of(out / "units.csv")) == 8
    assert main([*TINY, "--runs", "3", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "8 units of" in err and "4 to play" in err and "study: unit 4/4" in err
    grown = rows_of(out / "units.csv")
    keys = [(r["generator_seed"], r["run"], r["config"]) for r in grown]
    assert len(grown) == 12 and len(set(keys)) == 12 and grown[:8] == rows
    assert len(rows_of(out / "planner.csv")) == 2 * 3
    with pytest.raises(SystemExit) as exited:
        main([*TINY[:6], "21", *TINY[7:], "--runs", "3", "--out", str(out)])
    assert exited.value.code == 2
    assert "another protocol (episodes differ)" in capsys.readouterr().err
    # Code whose defaults moved since the units were played (here, a confidence fall) is refused too: its cq
    # units would be mixed with the kept ones under one name.
    real = held_out_module.run_settings
    monkeypatch.setattr(held_out_module, "run_settings", lambda gm, given=(): real(gm, ["conf_down=0.05", *given]))
    with pytest.raises(SystemExit) as exited:
        main([*TINY, "--runs", "3", "--out", str(out)])
    assert exited.value.code == 2
    assert "the settings of cq (conf_down 0.02 -> 0.05)" in capsys.readouterr().err
    monkeypatch.undo()

    # A study stopped after a unit's curve was written but before its row plays the unit again, and the curve
    # counts it once.
    kept = (out / "units.csv").read_text().splitlines(keepends=True)
    (out / "units.csv").write_text("".join(kept[:-1]))
    assert main([*TINY, "--runs", "3", "--out", str(out)]) == 0
    assert "1 to play" in capsys.readouterr().err
    assert len(rows_of(out / "curve.csv")) == 2 * 12 + 2 and len(shown_rows(out, "curve.csv")) == 2 * 12

    # A smaller command shows only the units it asked for, though units.csv keeps the 12.
    assert main([*TINY, "--runs", "1", "--out", str(out)]) == 0
    assert "## 4 AGVs: 2 units" in capsys.readouterr().out
    shown = shown_rows(out, "units.csv")
    assert len(shown) == 4 and {(r["generator_seed"], r["run"]) for r in shown} == {(1001, 0), (1002, 0)}

    # A kept map the generator no longer makes (a generator changed since) refuses a resume, which would mix
    # units on two maps; --force starts again.
    kept_map = out / "maps" / "warehouse_4_gen1002.txt"
    kept_map.write_text(kept_map.read_text() + "\n")
    with pytest.raises(SystemExit) as exited:
        main([*TINY, "--runs", "1", "--out", str(out)])
    assert exited.value.code == 2 and "is not the map the generator makes now" in capsys.readouterr().err
    assert main([*TINY, "--runs", "1", "--out", str(out), "--force"]) == 0
    assert len(rows_of(out / "units.csv")) == 4


def test_a_tuning_study_plays_the_tuning_maps_and_a_variant_with_its_own_settings(tmp_path, capsys):
    out = tmp_path / "tuning"
    variant = "cq_col=cq:conf_down=0.1,window=7"
    assert main([*TINY, "--runs", "1", "--tuning", "--variant", variant, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    rows = rows_of(out / "units.csv")
    assert {(int(r["generator_seed"]), r["config"]) for r in rows} == {
        (g, c) for g in TUNING_SEEDS for c in ("cq", "indep", "cq_col")}
    assert text.startswith("# Tuning study") and "Generator seeds 0, 7 (the tuning seeds" in text
    assert "Settings of cq_col: conf_down=0.1 window=7" in text and "| cq_col - cq | " in text
    # the variant's unit is the experiment's run with its settings
    gridmap = load_map(out / "maps" / "warehouse_4_gen7.txt")
    settings = run_settings(gridmap, ["step_cap=60", "conf_down=0.1", "window=7", "eval_learning=0",
                                      "eval_episodes=3"])
    unit = next(r for r in rows if (r["generator_seed"], r["config"]) == ("7", "cq_col"))
    assert float(unit["frozen_collisions"]) == compiled.play("cq", gridmap, settings, 0, 0, 20).greedy[
        "collisions"].mean()
    # the same folder as a held-out study, a third tuning map, or a bad variant: refused, naming why
    for argv, why in (([], "another protocol (generator_seeds differ)"),
                      (["--tuning", "--maps", "3"], "--maps takes at most 2 (the tuning generator seeds), got 3"),
                      (["--tuning", "--variant", "x=nosuch:alpha=0.2"], "unknown algorithm 'nosuch'"),
                      (["--tuning", "--variant", "cq=cq:alpha=0.2"], "configuration names must differ"),
                      (["--tuning", "--variant", "a=cq:alpha=7"], "alpha")):
        with pytest.raises(SystemExit) as exited:
            main([*TINY, "--runs", "1", "--out", str(out), *argv])
        assert exited.value.code == 2 and why in capsys.readouterr().err, argv


@pytest.mark.parametrize("engine", compiled.ENGINES)
def test_a_unit_on_either_engine_is_its_experiment_run_too(tmp_path, monkeypatch, engine):
    from cq_ros.engine import run
    from cq_ros.lab.held_out import Unit, generated, play_unit

    path = generated(tmp_path, 4, HELD_OUT_SEEDS[0], 0.1)
    gridmap = load_map(path)
    settings = run_settings(gridmap, ["step_cap=60", "eval_learning=0", "eval_episodes=3"])
    if engine == "reference":  # as where numba cannot load: the kernel plays every learner
        monkeypatch.setattr(compiled, "engine_of", lambda algo, engine="compiled": "reference")
    assert compiled.engine_of("near") == engine
    unit = Unit(str(path), "near", 1, 12, 0, settings, "near", 4, HELD_OUT_SEEDS[0], 3, 5, 2)
    played = play_unit({str(path): gridmap}, unit, lambda: None)
    assert [e for e, _, _ in played["curve"]] == [5, 10, 12]
    for copy, learning in (("frozen", 0), ("learning", 1)):
        reference = run("near", gridmap, run_settings(gridmap, ["step_cap=60", f"eval_learning={learning}",
                                                                "eval_episodes=3"]), 0, 1, 12)
        assert played["row"][f"{copy}_heard"] == reference.greedy["heard"].mean()
        assert played["row"][f"{copy}_collisions"] == reference.greedy["collisions"].mean()


def test_paired_figures_pair_the_same_units_where_configurations_played_different_ones():
    """cq played units (1001, 0), (1001, 1), (1002, 0); near (1001, 1), (1002, 0), (1002, 1), as a study resumed
    with near and stopped part way leaves them: the paired difference is over the two units both played, unit by
    unit (near - cq: 1.0 and 3.0), never the first three of each in sort order (which would pair (1001, 0) with
    (1001, 1))."""
    from cq_ros.lab.held_out_protocol import Config
    from cq_ros.lab.held_out_report import size_tables

    def unit(config, seed, run, collisions):
        figures = {f"{copy}_{name}": 1.0 for copy in ("frozen", "learning") for name in ("home", "heard", "makespan")}
        return {"agents": 4, "generator_seed": seed, "run": run, "config": config, "states": 10.0, **figures,
                "planner_makespan": 1.0,
                "frozen_collisions": collisions, "learning_collisions": collisions}

    rows = [unit("cq", 1001, 0, 9.0), unit("cq", 1001, 1, 1.0), unit("cq", 1002, 0, 2.0),
            unit("near", 1001, 1, 2.0), unit("near", 1002, 0, 5.0), unit("near", 1002, 1, 0.0)]
    planner = [{"makespan": 1.0, "collisions": 0.0, "messages": 0.0, "home": 1}]
    lines = size_tables(4, rows, [Config("cq", "cq"), Config("near", "near")], planner)
    at = lines.index("Paired differences, frozen (over the 2 units every configuration played):")
    assert lines[at + 4].startswith(f"| near - cq | {paired_difference([2.0, 5.0], [1.0, 2.0]).show(3)} |")
    ratios = lines.index("Ratios of means, frozen (bootstrap 95%) (over the 2 units every configuration played):")
    assert lines[ratios + 4].startswith(
        f"| near | {show_ratio(ratio_interval([2.0, 5.0], [1.0, 2.0], BOOTSTRAP_SEED))} |")

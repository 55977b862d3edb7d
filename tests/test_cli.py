"""The `cq-ros` command: listing and drawing maps, experiments and reproduce on small budgets, and one
clear line with exit code 2 for every kind of bad argument."""

import csv
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from cq_ros.cli.main import main
from cq_ros.gridmap import load_map
from cq_ros.lab.results import EPISODE_COLUMNS
from cq_ros.settings import Settings


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "cq_ros.cli", *args], capture_output=True, text=True, timeout=120)


def test_maps_lists_every_shipped_map(capsys):
    assert main(["maps"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^tunnel_to_goal_3 +55 +2$", out, re.M)
    assert "warehouse_8" in out


def test_show_draws_the_map(capsys):
    assert main(["show", "grid_game_2"]) == 0
    out = capsys.readouterr().out
    assert "9 cells, 2 agents" in out and "+-+-+-+" in out


def test_show_says_which_agents_an_early_arrival_can_wall_in(tmp_path, capsys):
    walled = tmp_path / "walled.txt"  # agent 2 parked at 0,1 is in agent 1's only way to 0,2
    walled.write_text("agent 1: start 1,0  goal 0,2\nagent 2: start 1,1  goal 0,1\n"
                      "+-+-+-+\n|. . .|\n+ +-+-+\n|. . #\n+-+-+-+\n")
    assert main(["show", str(walled)]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[-1] == ("walled in by an early arrival (agent: by the agent parked at its goal): "
                                    "1: by 2 at 0,1")
    for name in ("tunnel_to_goal", "warehouse_8"):
        assert main(["show", name]) == 0
        lines = capsys.readouterr().out.splitlines()
        assert lines[-1].endswith(": none")
    assert "map defaults: reward_step=-1, gamma=0.98, epsilon_decay_episodes=1500" in lines


@pytest.mark.parametrize(
    "args, phrase",
    [
        (["experiment", "--map", "nowhere", "--out", "X"], "no such map"),
        (["experiment", "--map", "grid_game_2", "--algo", "cq,sarsa", "--out", "X"], "unknown algorithm sarsa"),
        (["experiment", "--map", "grid_game_2", "--episodes", "0", "--out", "X"], "must be at least 1"),
        (["experiment", "--map", "grid_game_2", "--set", "alhpa=0.2", "--out", "X"], "unknown setting 'alhpa'"),
        (["experiment", "--map", "grid_game_2", "--set", "window=2.5", "--out", "X"], "window takes an integer"),
        (["experiment", "--map", "grid_game_2", "--set", "alpha=abc", "--out", "X"], "alpha takes a number"),
        (["experiment", "--map", "grid_game_2", "--set", "gamma=1.5", "--out", "X"], "gamma must be in [0, 1)"),
        (["experiment", "--map", "grid_game_2", "--seed", "-1", "--out", "X"], "--seed: must be at least 0"),
        (["experiment", "--map", "grid_game_2", "--set", "slip=1", "--out", "X"], "at 1 every move fails"),
        (["experiment", "--map", "grid_game_2", "--set", "step_cap=50", "--set", "start_hold=60", "--out", "X"],
         "start_hold must be below step_cap=50"),
        (["launch", "--map", "grid_game_2", "--algo", "cq", "--set", "slip=1", "--out", "X"], "at 1 every move fails"),
        (["reproduce", "--seed", "-1", "--out", "X"], "--seed: must be at least 0"),
        (["reproduce", "--seeds", "0,-1", "--out", "X"], "--seeds: every seed must be at least 0"),
        (["generate", "warehouse", "--agents", "8", "--seed", "-2", "--out", "X"], "--seed: must be at least 0"),
        # absurd sizes: one line at once, not a run or a map that never finishes
        (["experiment", "--map", "grid_game_2", "--episodes", "99999999999999999999", "--out", "X"],
         "--episodes: must be at most 10,000,000, got 99999999999999999999"),
        (["experiment", "--map", "grid_game_2", "--runs", "1000000", "--out", "X"], "--runs: must be at most 10,000"),
        (["render", "--map", "grid_game_2", "--episodes", "99999999999999999999", "--out", "X"], "--episodes: must be"),
        (["generate", "warehouse", "--agents", "100000", "--out", "X"], "--agents: must be at most 256"),
        (["generate", "warehouse", "--agents", "8", "--aisle-length", "100000", "--out", "X"], "--aisle-length: must"),
        (["generate", "warehouse", "--agents", "8", "--aisles", "100000", "--out", "X"], "--aisles: must be at most"),
        (["launch", "--map", "grid_game_2", "--algo", "cq", "--episodes", "99999999999999999999", "--out", "X"],
         "--episodes: must be at most"),
        (["study", "--agents", "8,0", "--out", "X"], "--agents: must be at least 1"),
        (["study", "--agents", "8", "--set", "slp=0.1", "--out", "X"], "unknown setting 'slp'"),
        (["study", "--agents", "8", "--maps", "101", "--out", "X"], "--maps takes at most 100"),
        # an option that would do nothing here is refused, not ignored
        (["launch", "--map", "grid_game_2", "--algo", "cq", "--discovery", "static", "--out", "X"],
         "--discovery chooses how the nodes on --hosts find each other"),
        # a number that passes every comparison (nan) or makes every step time out: refused with the reason
        (["record", "--out", "X", "--duration", "nan"], "--duration: must be a finite number, got nan"),
        (["launch", "--map", "grid_game_2", "--algo", "cq", "--set", "step_timeout=0.0001", "--out", "X"],
         "step_timeout must be at least 0.1 s, got 0.0001: an action takes longer to come whenever its agent waits"),
        (["launch", "--map", "grid_game_2", "--algo", "cq", "--step-timeout", "0.0001", "--out", "X"],
         "step_timeout must be at least 0.1 s"),
    ],
)
def test_bad_arguments_give_one_line_and_exit_2(tmp_path, args, phrase):
    args = [str(tmp_path / a) if a == "X" else a for a in args]
    result = run_cli(*args)
    assert result.returncode == 2
    assert phrase in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "X").exists()


@pytest.mark.parametrize("content, where", [
    ("agent 1: start 0,0  goal 0,1\n+-+-+\n|. .|  caf\u00e9\n+-+-+\n".encode("latin-1"), ":3:11: not a UTF-8"),
    (bytes(range(128, 256)), ":1:1: not a UTF-8"),  # not text at all
    (b"hello world\n", ":1: drawing size inconsistent"),  # text, but no map
])
def test_a_map_file_that_is_not_a_map_gets_a_line_naming_it(tmp_path, content, where):
    path = tmp_path / "mine.txt"
    path.write_bytes(content)
    result = run_cli("experiment", "--map", str(path), "--out", str(tmp_path / "X"))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.strip().splitlines() == [result.stderr.strip()]
    assert f"{path}{where}" in result.stderr


@pytest.mark.parametrize("content, says", [(bytes(range(200, 232)), "is not a key file: byte 0 is not text (0xc8)"),
                                           (b"not hex at all\n", "must hold at least 16 bytes as hex")])
def test_a_junk_key_file_gets_a_line_naming_it(tmp_path, content, says):
    key = tmp_path / "junk.key"
    key.write_bytes(content)
    key.chmod(0o600)
    result = run_cli("launch", "--map", "grid_game_2", "--algo", "cq", "--key", str(key), "--out", str(tmp_path / "X"))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    line = result.stderr.strip()
    assert "\n" not in line and line.startswith(f"cq-ros launch: error: parameter key_file: {str(key)!r} {says}")
    assert not (tmp_path / "X").exists()


@pytest.mark.slow
def test_output_that_is_a_file_or_a_result_is_never_overwritten(tmp_path):
    a_file = tmp_path / "file"
    a_file.write_text("mine")
    inside = run_cli("experiment", "--map", "grid_game_2", "--out", str(a_file / "res"))
    assert inside.returncode == 2 and "cannot make output directory" in inside.stderr
    assert len(inside.stderr.strip().splitlines()) == 1
    result = run_cli("experiment", "--map", "grid_game_2", "--runs", "1", "--episodes", "5", "--out", str(a_file))
    assert result.returncode == 2 and "is a file" in result.stderr
    assert a_file.read_text() == "mine"

    out = tmp_path / "res"
    assert run_cli("experiment", "--map", "grid_game_2", "--runs", "1", "--episodes", "5", "--no-figures",
                   "--out", str(out)).returncode == 0
    before = (out / "episodes.csv").read_text()
    again = run_cli("experiment", "--map", "grid_game_2", "--runs", "1", "--episodes", "5", "--seed", "9",
                    "--no-figures", "--out", str(out))
    assert again.returncode == 2 and "--force" in again.stderr
    assert (out / "episodes.csv").read_text() == before


@pytest.mark.slow
def test_experiment_writes_tables_manifest_and_figures_and_the_same_seed_gives_the_same_file(tmp_path, capsys):
    args = ["experiment", "--map", "tunnel_to_goal", "--algo", "cq,indep,loc", "--runs", "2", "--episodes", "60",
            "--seed", "5", "--set", "window=10"]
    first, second = tmp_path / "a", tmp_path / "b"
    assert main([*args, "--out", str(first)]) == 0
    # It ends with the greedy policy's line per algorithm, as a launch does (summary.greedy_lines).
    stdout = capsys.readouterr().out
    for algo in ("indep", "loc", "cq"):
        rows = [r for r in csv.DictReader(open(first / "greedy.csv")) if r["algo"] == algo]
        collisions = sum(float(r["collisions"]) for r in rows) / len(rows)
        steps = sum(float(r["steps"]) for r in rows) / len(rows)
        assert (f"greedy policy, {algo}, 2 runs x 20 episodes: {collisions:.2f} collisions/ep, {steps:.1f} steps/ep, "
                f"{sum(int(r['truncated']) for r in rows)} truncated") in stdout
    assert main([*args, "--out", str(second), "--jobs", "1", "--no-figures"]) == 0
    assert (first / "episodes.csv").read_bytes() == (second / "episodes.csv").read_bytes()
    assert (first / "observe.csv").read_bytes() == (second / "observe.csv").read_bytes()
    assert (first / "greedy.csv").read_bytes() == (second / "greedy.csv").read_bytes()
    # greedy.csv: a row per greedy episode (eval_episodes 20 per run), in episodes.csv's columns
    greedy = list(csv.DictReader(open(first / "greedy.csv")))
    assert tuple(greedy[0]) == EPISODE_COLUMNS
    assert [(r["algo"], r["run"], int(r["episode"])) for r in greedy] == \
        [(a, run, e) for a in ("indep", "loc", "cq") for run in ("0", "1") for e in range(20)]

    rows = list(csv.DictReader(open(first / "episodes.csv")))
    assert len(rows) == 3 * 2 * 60
    assert {r["algo"] for r in rows} == {"cq", "indep", "loc"}
    # Episodes from 0, as on the wire, in bags and in render --episode; runs from 0 too.
    assert [(r["run"], int(r["episode"])) for r in rows if r["algo"] == "cq"] == \
        [(run, e) for run in ("0", "1") for e in range(60)]
    manifest = json.loads((first / "manifest.json").read_text())
    assert manifest["settings"]["window"] == 10 and manifest["seed"] == 5
    assert manifest["settings"]["reward_collision"] == -10.0
    assert {"numpy", "scipy", "cq_ros"} <= set(manifest["versions"])
    for png in ("collisions.png", "joint_plays.png", "state_space.png", "observe_map.png"):
        assert (first / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_reproduce_small_grid_writes_a_report_with_every_claim(tmp_path):
    assert main(["reproduce", "--out", str(tmp_path / "r"), "--runs", "1", "--episodes", "10", "--no-sweep",
                 "--set", "step_cap=50", "--seeds", "5,6,7"]) == 0
    report = (tmp_path / "r" / "REPORT.md").read_text()
    for n in range(1, 8):
        assert f"\n{n}. *" in report
    assert "holds" in report and "--seeds 5,6,7" in report
    for claim in (1, 2):  # at both thresholds, with fixed and with decaying exploration, judged over the seeds
        section = report.split(f"\n{claim}. *")[1].split(f"\n{claim + 1}. *")[0]
        assert section.count("below 0.05: **") == section.count("below 0.1: **") == 2
        assert "epsilon 0.1 fixed" in section and "epsilon falling to 0 by episode 5" in section
    assert "## In short\n\n- **" in report and "## Collision-free from, over seeds 5, 6, 7\n" in report
    for where in ("", "decay/"):
        for m in ("grid_game_2", "tunnel_to_goal", "tunnel_to_goal_3", "isr"):
            assert (tmp_path / "r" / where / m / "episodes.csv").exists()
            assert (tmp_path / "r" / where / m / "collisions_log.png").exists()
            for other in (6, 7):  # the other seeds' grids: tables, no figures
                manifest = tmp_path / "r" / f"seed_{other}" / where / m / "manifest.json"
                assert json.loads(manifest.read_text())["seed"] == other
    assert json.loads((tmp_path / "r" / "isr" / "manifest.json").read_text())["seed"] == 5
    decay = json.loads((tmp_path / "r" / "decay" / "isr" / "manifest.json").read_text())["settings"]
    assert decay["epsilon_decay_episodes"] == 5 and decay["step_cap"] == 50  # at most 500


@pytest.mark.slow
def test_every_command_taking_a_map_accepts_a_path_to_a_copied_map(tmp_path, capsys):
    """The map given is the map used, to the last figure: a copy named unlike any shipped map."""
    copied = tmp_path / "my" / "mymap.txt"
    copied.parent.mkdir()
    copied.write_text(Path(load_map("tunnel_to_goal").source).read_text())
    assert main(["show", str(copied)]) == 0
    assert "mymap: 25 cells, 2 agents" in capsys.readouterr().out

    out = tmp_path / "result"
    assert main(["experiment", "--map", str(copied), "--algo", "cq,loc", "--runs", "1", "--episodes", "30",
                 "--set", "window=10", "--jobs", "1", "--out", str(out)]) == 0
    assert json.loads((out / "manifest.json").read_text())["map_source"] == str(copied.resolve())
    for png in ("collisions.png", "joint_plays.png", "state_space.png", "observe_map.png", "steps.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", png


@pytest.mark.parametrize("workers", [1, 2])
def test_long_runs_show_progress_on_stderr_from_every_worker(capsys, workers):
    """Not on a terminal: a plain line at the start, then at most every interval (here 0.02 s), and at the
    end, with runs and episodes done, the rate and the time left; the counts come from the workers."""
    from cq_ros.lab.experiment import Job, run_jobs
    from cq_ros.settings import Settings

    # enough episodes (about half a second at ~8,000 a second on the reference engine, which the compiled one
    # plays within one interval) that the runs cannot end within one interval
    jobs = [Job("grid_game_2", "cq", r, 1500, 0, Settings(eval_episodes=0), engine="reference") for r in range(3)]
    results, _ = run_jobs(jobs, workers=workers, label="test", progress_interval=0.02)
    assert len(results) == 3
    lines = capsys.readouterr().err.splitlines()
    pattern = re.compile(r"test: runs (\d)/3, episodes ([\d,]+)/4,500, [\d,]+ episodes/s, \d+ s elapsed, "
                         r"(\d+ s left|time left unknown)")
    parsed = [pattern.fullmatch(line) for line in lines]
    assert all(parsed), lines
    episodes = [int(m.group(2).replace(",", "")) for m in parsed]
    assert episodes[0] == 0 and episodes[-1] == 4500 and parsed[-1].group(1) == "3"
    assert episodes == sorted(episodes)
    assert any(0 < e < 4500 for e in episodes), lines  # lines while the runs were going, not only at the ends


def test_settings_lists_every_setting_with_its_default_and_description(capsys):
    assert main(["settings"]) == 0
    out = capsys.readouterr().out
    for name, value in Settings().as_dict().items():
        described = re.search(rf"^{name} = {re.escape(str(value))}\n((?:    .*\n)+)", out, re.M)
        assert described, name
        assert " ".join(described.group(1).split()) == Settings.describe(name)


@pytest.mark.parametrize("sig, runs", [("SIGINT", 1), ("SIGTERM", 1), ("SIGTERM", 2)])
def test_ctrl_c_or_sigterm_on_an_experiment_before_its_results_leaves_no_folder(tmp_path, sig, runs):
    """SIGTERM unwinds as Ctrl-C does (cq_ros/cli/main.py), its worker processes (2 runs) stopped with it."""
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "made" / "result"
    cmd = [sys.executable, "-m", "cq_ros.cli", "experiment", "--map", "tunnel_to_goal", "--algo", "cq", "--runs",
           str(runs), "--episodes", "10000000", "--seed", "0", "--out", str(out)]
    # Ctrl-C's default, as at a terminal: a suite started as a shell's background job runs with SIGINT ignored,
    # which a child inherits, and Python then leaves it ignored (the experiment ran on, 60 s, in such a run)
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 60
        while not out.exists():  # the folder is made (and probed) before any run starts
            assert time.monotonic() < deadline and proc.poll() is None, proc.stderr.read() if proc.poll() else "late"
            time.sleep(0.05)
        time.sleep(1)
        proc.send_signal(getattr(signal, sig))
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=30)
    # 130 is main()'s answer to Ctrl-C. Under `python -m`, 2 of 15 such runs here printed "interrupted", returned
    # 130 from main() and still ended killed by SIGINT (CPython's exit for an interrupted run): either is Ctrl-C's.
    assert proc.returncode in (130, -signal.SIGINT), err
    assert ("interrupted by SIGTERM" if sig == "SIGTERM" else "interrupted") in err, err
    assert "Traceback" not in err and not (tmp_path / "made").exists(), err


def test_ctrl_c_on_an_experiment_keeps_the_runs_it_finished_and_says_which_are_missing(tmp_path):
    """Ctrl-C once run 0 of 2 has finished (its progress line says so): run 0's results, the manifest naming run
    1 missing, exit 130; run 1, cut short, is not among them."""
    import signal
    import subprocess
    import sys

    out = tmp_path / "result"
    episodes = 600_000  # about 3 s a run on the compiled engine, so that Ctrl-C lands inside run 1
    cmd = [sys.executable, "-m", "cq_ros.cli", "experiment", "--map", "tunnel_to_goal", "--algo", "cq", "--runs", "2",
           "--episodes", str(episodes), "--jobs", "1", "--set", "eval_episodes=0", "--seed", "0", "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        seen = []
        for line in proc.stderr:  # bounded by the run's own length: each line comes within seconds
            seen.append(line)
            if "runs 1/2" in line:
                proc.send_signal(signal.SIGINT)
                break
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=30)
    err = "".join(seen) + err
    assert proc.returncode in (130, -signal.SIGINT), err
    assert "the 1 of 2 runs that finished are kept" in err and "missing: tunnel_to_goal cq seed 0 run 1" in err, err
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["interrupted"] == ["tunnel_to_goal cq seed 0 run 1"]
    rows = (out / "episodes.csv").read_text().splitlines()
    assert len(rows) == 1 + episodes and {row.split(",")[2] for row in rows[1:]} == {"0"}


def test_reproduce_reports_the_papers_cq_beside_ours(tmp_path):
    """The paper's grid plays cq_paper; ours, cq, is played beside it on the four maps and reported so."""
    assert main(["reproduce", "--out", str(tmp_path / "r"), "--runs", "1", "--episodes", "10", "--no-sweep",
                 "--set", "step_cap=50"]) == 0
    report = (tmp_path / "r" / "REPORT.md").read_text()
    section = report.split("## The paper's CQ beside ours (seed 0, epsilon 0.1 fixed (the paper's))\n")[1]
    for m in ("grid_game_2", "tunnel_to_goal", "tunnel_to_goal_3", "isr"):
        grid = json.loads((tmp_path / "r" / m / "manifest.json").read_text())
        assert "cq_paper" in grid["algos"] and "cq" not in grid["algos"]
        manifest = json.loads((tmp_path / "r" / "ours" / m / "manifest.json").read_text())
        assert manifest["algos"] == ["cq"] and manifest["settings"]["step_cap"] == 50
        assert f"\n| {m} | " in section




@pytest.mark.parametrize("module", ["cq_ros.cli", "cq_ros.cli.main"])
def test_each_python_m_form_runs_the_command(module):
    done = subprocess.run([sys.executable, "-m", module, "maps"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "tunnel_to_goal" in done.stdout


@pytest.mark.parametrize("argv, says", [
    (["experiment", "--map", "tunnel_to_goal", "--algo", "cq,cq", "--out", "x"], "an algorithm is given twice"),
    (["experiment", "--map", "tunnel_to_goal", "--out", ""], "--out: expected a path, got an empty one"),
    (["experiment", "--map", "tunnel_to_goal", "--out", "", "--force"], "--out: expected a path"),
    (["render", "--map", "tunnel_to_goal", "--dpi", "100000", "--out", "x.gif"], "--dpi: must be more than 0"),
    (["plan", "--map", "warehouse_8", "--time-limit", "nan"], "--time-limit: must be a finite number"),
])
def test_a_bad_argument_is_one_line_and_exit_2(argv, says, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exited:
        main(argv)
    err = capsys.readouterr().err
    assert exited.value.code == 2 and says in err and len(err.strip().splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []  # nothing written, the current directory least of all

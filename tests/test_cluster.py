"""`--cluster`: the runs of `cq-ros experiment`, `cq-ros reproduce` and bench_warehouse.py on a real Dask cluster
(a `dask scheduler` and `dask worker` processes on 127.0.0.1, tests/dask_cluster.py; and, where root and `ip`
allow, workers on hosts made by `cq-ros hosts`). The result files equal, byte for byte, those of a run in this
process and on a local pool (the manifest but for its circumstances); progress comes from the workers'
episodes; a failing run is named with the worker's traceback; a worker killed mid-grid costs nothing; a worker
with another cq_ros is refused in one line.
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from cq_ros.cli.main import main
from cq_ros.lab.experiment import Job, experiment, run_jobs
from cq_ros.lab.results import CIRCUMSTANCES
from cq_ros.lab.reproduce import reproduce
from cq_ros.lab.runner import RunFailed
from cq_ros.settings import Settings
from dask_cluster import START_S, DaskCluster
from helpers import wait_for_line, wait_until
from ros_tools.hosts import HostsError, check_can_make_hosts, hosts_down, hosts_up

ROOT = Path(__file__).resolve().parent.parent
CQ_ROS = str(Path(sys.executable).with_name("cq-ros"))
# a greedy policy that loops runs to the step cap: 200 steps, 3 greedy episodes keep that short
GRID = ["--map", "grid_game_2", "--algo", "cq,indep,loc", "--runs", "2", "--episodes", "300", "--seed", "3",
        "--set", "step_cap=200", "--set", "eval_episodes=3", "--no-figures"]
FILES = ("episodes.csv", "greedy.csv", "observe.csv")
GRID_S = 240.0  # bound on one small grid: 2-10 s each on 2 cores, 150 s seen at load 30


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    with DaskCluster(tmp_path_factory.mktemp("dask")) as made:
        first = made.add_worker(wait=False)  # both start at once
        made.add_worker()
        wait_for_line(made.folder / f"{first.log_name}.log", "Registered to:", START_S, first)
        yield made


@pytest.fixture(scope="module")
def in_process(tmp_path_factory) -> Path:
    """The grid played in this process, the reference every other way of running it must equal."""
    out = tmp_path_factory.mktemp("grid") / "in_process"
    assert main(["experiment", *GRID, "--jobs", "1", "--out", str(out)]) == 0
    return out


def assert_same_results(a: Path, b: Path) -> None:
    for name in FILES:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    first, second = (json.loads((d / "manifest.json").read_text()) for d in (a, b))
    for manifest in (first, second):
        for key in CIRCUMSTANCES:
            manifest.pop(key)
    assert first == second


def test_a_grid_on_the_cluster_writes_the_files_of_a_run_in_one_process_and_on_a_pool(cluster, in_process,
                                                                                      tmp_path, capsys):
    on_pool, on_cluster = tmp_path / "pool", tmp_path / "cluster"
    assert main(["experiment", *GRID, "--jobs", "2", "--out", str(on_pool)]) == 0
    assert main(["experiment", *GRID, "--cluster", cluster.address, "--out", str(on_cluster)]) == 0
    assert_same_results(in_process, on_pool)
    assert_same_results(in_process, on_cluster)
    said = capsys.readouterr().err
    assert f"on the Dask cluster at {cluster.address}: 2 workers, 2 threads, versions checked" in said

    where = json.loads((on_cluster / "manifest.json").read_text())["executed_on"]
    assert where["where"] == "dask" and where["scheduler"] == cluster.address
    assert len(where["workers"]) == 2 and sum(w["runs"] for w in where["workers"]) == 6
    assert all(w["cq_ros"] == "0.1.0" and w["python"] == f"{sys.version_info.major}.{sys.version_info.minor}."
               f"{sys.version_info.micro}" and w["numpy"] and w["address"].startswith("tcp://127.0.0.1:")
               for w in where["workers"])
    assert json.loads((on_pool / "manifest.json").read_text())["executed_on"] == {"where": "local processes",
                                                                                    "workers": 2}


def test_progress_on_the_cluster_counts_the_episodes_the_workers_play(cluster, capsys):
    # the reference engine: the compiled one plays both runs within one progress interval
    jobs = [Job("grid_game_2", "cq", r, 3000, 0, Settings(eval_episodes=0), "reference") for r in range(2)]
    results, _ = run_jobs(jobs, label="test", progress_interval=0.05, cluster=cluster.address)
    assert [r.run for r in results.values()] == [0, 1]
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("test: runs")]
    episodes = [int(re.search(r"episodes ([\d,]+)/6,000", line).group(1).replace(",", "")) for line in lines]
    assert episodes[0] == 0 and episodes[-1] == 6000 and episodes == sorted(episodes)
    # within a run, not only as runs end: the workers' events
    assert any(0 < e < 6000 and e % 3000 for e in episodes), lines


@pytest.mark.slow
def test_reproduce_and_bench_warehouse_run_on_the_cluster_too(cluster, tmp_path):
    small = {"runs": 1, "episodes": 10, "sweep": False, "figures": False, "settings": Settings(step_cap=100)}
    reproduce(tmp_path / "local", workers=1, **small)
    reproduce(tmp_path / "cluster", cluster=cluster.address, **small)
    for where in (".", "decay"):
        for m in ("grid_game_2", "tunnel_to_goal", "tunnel_to_goal_3", "isr"):
            assert_same_results(tmp_path / "local" / where / m, tmp_path / "cluster" / where / m)
    assert f"on the Dask cluster at {cluster.address} (2 workers)" in (tmp_path / "cluster" / "REPORT.md").read_text()

    bench = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_warehouse.py"), "--maps", "tunnel_to_goal",
                            "--algos", "indep,cq", "--runs", "2", "--episodes", "20", "--check-every", "10",
                            "--cluster", cluster.address], capture_output=True, text=True, timeout=GRID_S)
    assert bench.returncode == 0, bench.stderr
    rows = [line for line in bench.stdout.splitlines() if line.startswith("| tunnel_to_goal |")]
    assert [row.split("|")[2].strip() for row in rows] == ["indep", "cq"]
    assert "runs: runs 4/4, episodes 80/80" in bench.stderr


def test_a_failing_run_is_named_with_the_workers_traceback(cluster):
    jobs = [Job("grid_game_2", "cq", 0, 20, 0), Job("grid_game_2", "sarsa", 1, 20, 0)]
    with pytest.raises(RunFailed) as failed:
        run_jobs(jobs, cluster=cluster.address)
    assert str(failed.value).startswith("run failed: map grid_game_2, algo sarsa, run 1: ")
    assert "cq_ros/engine.py" in failed.value.details and "make_learners" in failed.value.details


def test_the_command_prints_a_failing_runs_traceback_then_names_it_and_exits_1(monkeypatch, tmp_path, capsys):
    import cq_ros.lab.experiment

    def broken(algo, gridmap, settings, seed, run_index, episodes, on_episode, engine):
        if run_index == 1:
            raise ArithmeticError("broken on purpose")
        return real(algo, gridmap, settings, seed, run_index, episodes, on_episode, engine=engine)

    real = cq_ros.lab.experiment.compiled.play
    monkeypatch.setattr(cq_ros.lab.experiment.compiled, "play", broken)
    with pytest.raises(SystemExit) as stopped:
        main(["experiment", "--map", "grid_game_2", "--algo", "cq", "--runs", "3", "--episodes", "5",
              "--jobs", "1", "--no-figures", "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err.splitlines()
    assert stopped.value.code == 1
    assert err[-1] == ("cq-ros experiment: error: run failed: map grid_game_2, algo cq, run 1: "
                       "ArithmeticError: broken on purpose")
    assert "Traceback (most recent call last):" in err and any("in broken" in line for line in err)
    assert not (tmp_path / "r" / "episodes.csv").exists()


def test_a_worker_killed_mid_grid_has_its_runs_played_elsewhere_and_the_files_are_the_same(cluster, in_process,
                                                                                           tmp_path):
    from distributed import Client

    victim = cluster.add_worker()  # a third worker, so that the others stay for the tests after
    worker = cluster.worker_address(victim)
    out, failed = tmp_path / "cluster", []

    def grid() -> None:
        try:
            experiment("grid_game_2", ["cq", "indep", "loc"], 2, 300, 3, out, Settings(step_cap=200, eval_episodes=3),
                       figures=False, cluster=cluster.address)
        except BaseException as e:  # seen by the test below
            failed.append(e)

    with Client(cluster.address, timeout=30, set_as_default=False) as client:
        playing = threading.Thread(target=grid)
        playing.start()
        try:
            assert wait_until_processing(client, worker), "the victim never got a run"
            assert playing.is_alive()  # mid-grid
        finally:
            cluster.remove(victim)
        playing.join(GRID_S)
    assert not playing.is_alive() and not failed, failed
    assert_same_results(in_process, out)


def wait_until_processing(client, worker: str) -> bool:
    """True once `worker` is given a run (the scheduler's view), False after GRID_S."""
    return bool(wait_until(lambda: client.processing(workers=[worker]).get(worker), GRID_S, "processing",
                           fail=False))


def test_a_worker_with_another_cq_ros_is_refused_in_one_line(cluster, tmp_path, capsys):
    fake = tmp_path / "other_cq_ros.py"
    fake.write_text("import cq_ros\n\ncq_ros.__version__ = '0.0.9'  # as if another release were installed\n")
    other = cluster.add_worker("--preload", str(fake))
    try:
        with pytest.raises(SystemExit) as stopped:
            main(["experiment", *GRID, "--cluster", cluster.address, "--out", str(tmp_path / "r")])
    finally:
        cluster.remove(other)
    err = capsys.readouterr().err.splitlines()
    assert stopped.value.code == 1
    assert err == [f"cq-ros experiment: error: worker {cluster.worker_address(other)} on {socket.gethostname()} "
                   "refused: cq_ros 0.0.9 where this client has 0.1.0"]


def test_bad_cluster_addresses_are_refused_before_any_work(capsys):
    for bad in ("127.0.0.1:8786", "tcp://127.0.0.1", "tcp://127.0.0.1:99999", "http://h:1"):
        with pytest.raises(SystemExit) as stopped:
            main(["experiment", *GRID, "--cluster", bad, "--out", "unused"])
        assert stopped.value.code == 2
        assert f"expected a Dask scheduler address tcp://HOST:PORT, got {bad!r}" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stopped:
        main(["experiment", *GRID, "--cluster", "tcp://127.0.0.1:1", "--jobs", "2", "--out", "unused"])
    assert stopped.value.code == 2 and "not allowed with argument" in capsys.readouterr().err


def _no_hosts() -> str | None:
    try:
        check_can_make_hosts()
    except HostsError as e:
        return str(e)
    return None


@pytest.mark.skipif(_no_hosts() is not None, reason=f"no network namespaces here: {_no_hosts()}")
@pytest.mark.root
@pytest.mark.slow
def test_workers_on_hosts_of_their_own_play_the_same_grid(in_process, tmp_path):
    """The scheduler and the client on the `world` host, a worker on each of two others (198.18.0.0/15)."""
    hosts = hosts_up(2)
    try:
        with DaskCluster(tmp_path / "dask", host=hosts.address("world"), on=hosts.exec_on("world")) as made:
            for agv in ("agv1", "agv2"):
                made.add_worker(on=hosts.exec_on(agv))
            out = tmp_path / "cluster"
            client = subprocess.run([*hosts.exec_on("world"), CQ_ROS, "experiment", *GRID,
                                     "--cluster", made.address, "--out", str(out)],
                                    capture_output=True, text=True, timeout=GRID_S)
            assert client.returncode == 0, client.stderr
        where = json.loads((out / "manifest.json").read_text())["executed_on"]
        assert made.address == "tcp://198.18.0.1:" + made.address.rsplit(":", 1)[1]
        assert sorted(w["address"].rsplit(":", 1)[0] for w in where["workers"]) == ["tcp://198.18.0.2",
                                                                                    "tcp://198.18.0.3"]
        assert_same_results(in_process, out)
    finally:
        for pid in hosts.pids():  # none unless the cluster above failed to close
            os.kill(pid, signal.SIGKILL)
        hosts_down(hosts.prefix)

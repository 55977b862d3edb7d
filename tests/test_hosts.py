"""Several hosts, for real: the world and each AGV in a network namespace of its own, joined by a bridge, with
addresses from 198.18.0.0/15 (`cq-ros hosts`, ros_tools/hosts.py), and `cq-ros launch --hosts` across them.
The run equals the offline engine's with discovery on the subnet and with unicast to ROS_STATIC_PEERS only; a
link down for 2 s costs a few counted misses and the agent is back in step; a host cut for good ends the run as
a lost agent does, with what was written before intact. Every namespace made is removed, even on failure, and
nothing changes in the machine's own network namespace.

Needs root and the `ip` command (skipped otherwise, with the reason); CI here runs as root.
"""

from __future__ import annotations

import csv
import ipaddress
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cq_ros.engine import run
from cq_ros.gridmap import load_map
from cq_ros.settings import Settings, run_settings
from helpers import SEED, WaitTimeout, launch_command, read_episodes, unique, wait_until
from ros_tools.hosts import HostsError, check_can_make_hosts, existing_prefixes, hosts_up, hosts_down


def why_not() -> str | None:
    try:
        check_can_make_hosts()
    except HostsError as e:
        return str(e)
    return None


pytestmark = pytest.mark.skipif(why_not() is not None, reason=f"no network namespaces here: {why_not()}")

LAUNCH_TIMEOUT_S = 90.0  # bound on one launch across hosts; each below takes 10-30 s on 2 busy cores
CUT_MISSES = 2  # the link stays down until the world has missed agv1 on this many steps (step_timeout 1 s each)
# agv1's misses once the link is back: the next DDS heartbeat repairs the reliable feedback stream (every 50 ms,
# node_runtime/fastdds_profile.xml), or the agent catches up; counted in steps, which a busy machine does not
# stretch as it does seconds
RECOVERY_MISSES = 8


def own_links() -> list[str]:
    """The interfaces of this process's (the machine's) network namespace."""
    out = subprocess.run(["ip", "-o", "link", "show"], capture_output=True, text=True, timeout=10).stdout
    return sorted(line.split(":")[1].strip() for line in out.splitlines())


@pytest.fixture
def hosts():
    before = own_links()
    made = hosts_up(2)
    left = []
    try:
        yield made
    finally:
        left = made.pids()
        for pid in left:  # a process left by a failed test: kill it, then fail below
            os.kill(pid, signal.SIGKILL)
        hosts_down(made.prefix)
    assert not left, f"processes left on the hosts: {left}"
    assert made.prefix not in existing_prefixes()
    assert own_links() == before


def launch_on(hosts, out: Path, map_name: str, algo: str, episodes: int, sets, discovery: str) -> list[str]:
    return [*launch_command(out, unique("hosts"), map_name, algo, episodes, sets), "--hosts", hosts.prefix,
            "--discovery", discovery, "--no-figures"]


@pytest.mark.root
def test_hosts_up_and_down_make_and_remove_namespaces_only(hosts, capsys):
    from cq_ros.cli.main import main

    def cq_ros(*args: str):
        code = main(list(args))
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess(args, code, out, err)

    listed = cq_ros("hosts", "list")
    assert listed.returncode == 0
    assert f"{hosts.prefix}: {', '.join(sorted(hosts.namespaces))}" in listed.stdout
    for host in hosts.names:  # lo and eth0 up, the address from the test range, the cable plugged into br0
        ns = hosts.namespace(host)
        addresses = subprocess.run(["ip", "-n", ns, "-o", "-4", "addr"], capture_output=True, text=True).stdout
        assert re.search(r"\blo\b.*127\.0\.0\.1", addresses)
        assert re.search(rf"\beth0\b.*inet {re.escape(hosts.address(host))}/24", addresses)
        assert ipaddress.ip_address(hosts.address(host)) in ipaddress.ip_network("198.18.0.0/15")
        cable = subprocess.run(["ip", "-n", hosts.switch, "-o", "link", "show", hosts.cable(host)],
                               capture_output=True, text=True).stdout
        assert "master br0" in cable and "state UP" in cable

    made = cq_ros("hosts", "up", "--agents", "1")
    assert made.returncode == 0, made.stderr
    prefix = made.stdout.split()[1].rstrip(":")
    try:
        assert f"{prefix}-agv1: eth0 198.18.0.2/24" in made.stdout
        again = cq_ros("hosts", "up", "--prefix", prefix)
        assert again.returncode == 2 and f"hosts {prefix} exist already" in again.stderr
    finally:
        gone = cq_ros("hosts", "down", "--prefix", prefix)
    assert gone.returncode == 0 and sorted(gone.stdout.split("removed ")[1].strip().split(", ")) == sorted(
        f"{prefix}-{n}" for n in ("net", "world", "agv1"))
    twice = cq_ros("hosts", "down", "--prefix", prefix)  # after any failure: nothing left is not an error
    assert twice.returncode == 0 and "nothing to remove" in twice.stdout


@pytest.mark.root
def test_a_failed_up_removes_what_it_made(monkeypatch):
    from ros_tools import hosts as module

    real = module._ip
    calls = []

    def fail_at_the_second_host(*args):
        calls.append(args)
        if args[:2] == ("netns", "add") and args[2].endswith("-agv1"):
            raise module.HostsError("`ip netns add` failed: injected")
        real(*args)

    monkeypatch.setattr(module, "_ip", fail_at_the_second_host)
    with pytest.raises(module.HostsError, match="injected .*removed what was made"):
        module.hosts_up(2, prefix="cqrfail" + unique("x")[-1])
    prefix = calls[0][2].split("-")[0]
    assert prefix not in module.existing_prefixes()


@pytest.mark.parametrize("args, phrase", [
    (["--algo", "jsa"], "jsa is one central node"),
    (["--algo", "cq", "--map", "warehouse_8"], "have 2 AGV hosts, map warehouse_8 has 8 agents"),
])
@pytest.mark.root
def test_launch_refuses_hosts_it_cannot_use_with_exit_2(hosts, tmp_path, args, phrase):
    command = [*launch_command(tmp_path / "X", unique("bad"), "grid_game_2", "cq", 5), *args, "--hosts", hosts.prefix]
    done = subprocess.run(command, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and phrase in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "X").exists()


def test_launch_on_hosts_that_are_not_there_is_exit_2(tmp_path, capsys):
    from cq_ros.cli.main import main

    with pytest.raises(SystemExit) as exit_:
        main(["launch", "--map", "grid_game_2", "--algo", "cq", "--out", str(tmp_path / "X"), "--hosts", "cqrnone"])
    assert exit_.value.code == 2
    assert "no hosts cqrnone on this machine" in capsys.readouterr().err


@pytest.mark.parametrize("problem, patch", [
    ("the `ip` command", lambda m: m.setattr(shutil, "which", lambda name: None)),
    ("needs root", lambda m: m.setattr(os, "geteuid", lambda: 1000)),
])
def test_hosts_refuse_with_exit_2_without_root_or_ip(monkeypatch, capsys, problem, patch):
    from cq_ros.cli.main import main

    patch(monkeypatch)
    assert main(["hosts", "up", "--agents", "2"]) == 2
    err = capsys.readouterr().err
    assert problem in err and len(err.strip().splitlines()) == 1


def launch_equals_offline(hosts, out: Path, map_name: str, algo: str, episodes: int, sets, discovery: str) -> dict:
    """Launch across the hosts, check that its episodes are the offline engine's; the run's manifest."""
    done = subprocess.run(launch_on(hosts, out, map_name, algo, episodes, sets, discovery),
                          capture_output=True, text=True, timeout=LAUNCH_TIMEOUT_S)
    assert done.returncode == 0, done.stderr
    offline = run(algo, load_map(map_name), Settings().with_overrides(list(sets)), SEED, 0, episodes)
    np.testing.assert_array_equal(read_episodes(out), offline.episodes)
    return json.loads((out / "manifest.json").read_text())


@pytest.mark.root
@pytest.mark.ros
@pytest.mark.slow
def test_discovery_on_the_subnet_gives_the_offline_engines_episodes(hosts, tmp_path):
    manifest = launch_equals_offline(hosts, tmp_path / "result", "tunnel_to_goal", "cq", 20,
                                     ("step_cap=100", "reward_step=-1", "eval_episodes=2"), "subnet")
    assert manifest["hosts"] == {"prefix": hosts.prefix, "discovery": "subnet",
                                 "addresses": {"world": "198.18.0.1", "agv1": "198.18.0.2", "agv2": "198.18.0.3"}}
    assert manifest["world"]["missed_actions"] == 0


def start_nodes(hosts, namespace: str, env: dict[str, str], params: list[str],
                world_params: list[str]) -> list[subprocess.Popen]:
    """The world and each agent node on its own host, as `cq-ros launch --hosts` starts them, by hand."""
    ros = ["--ros-args", "-r", f"__ns:=/{namespace}", *[a for p in params for a in ("-p", p)]]
    procs = [subprocess.Popen([*hosts.exec_on("world"), sys.executable, "-m", "world_node", *ros,
                               *[a for p in world_params for a in ("-p", p)]],
                              env={**os.environ, **env}, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)]
    for k in range(1, hosts.agents + 1):
        procs.append(subprocess.Popen([*hosts.exec_on(f"agv{k}"), sys.executable, "-m", "agent_node", *ros,
                                       "-r", f"__node:=agv{k}", "-p", f"agent_id:={k}", "-p", "algo:=indep"],
                                      env={**os.environ, **env}, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL))
    return procs


@pytest.mark.root
@pytest.mark.ros
@pytest.mark.slow
def test_unicast_to_static_peers_alone_gives_the_offline_engines_episodes(hosts, tmp_path, ros_domain_id):
    # The switch stops flooding multicast: discovery can only be the unicast one, to ROS_STATIC_PEERS.
    for host in hosts.names:
        subprocess.run(["ip", "-n", hosts.switch, "link", "set", "dev", hosts.cable(host), "type", "bridge_slave",
                        "mcast_flood", "off"], check=True, timeout=10)
    # That it does: with discovery on the subnet the world never sees its agents.
    namespace = unique("control")
    env = {"ROS_DOMAIN_ID": str(ros_domain_id), **hosts.discovery_env("world", "subnet")}
    procs = start_nodes(hosts, namespace, env,
                        ["map:=grid_game_2", "episodes:=1"], ["startup_timeout:=4.0"])
    try:
        world_out, _ = procs[0].communicate(timeout=LAUNCH_TIMEOUT_S)
        assert procs[0].returncode == 1
        assert "still waiting for agv1, agv2" in world_out
        assert [p.poll() for p in procs[1:]] == [None, None]  # the agents were there, waiting to be found
    finally:
        for proc in procs:
            proc.kill()
            proc.wait(timeout=10)
    # window 10: CQ marks joint states and subscribes to its peer's position
    manifest = launch_equals_offline(hosts, tmp_path / "result", "grid_game_2", "cq", 40,
                                     ("window=10", "eval_episodes=3"), "static")
    assert manifest["hosts"]["discovery"] == "static"
    assert sum(agent["peer_messages"] for agent in manifest["communication"].values()) > 0


def launch_until(hosts, out: Path, episodes: int, sets, after: int, step_timeout: float, rows_of: bool = True):
    """Start a launch across the hosts (tunnel_to_goal, indep) and return (process, stderr file) once it has
    played `after` episodes: with `rows_of`, once its episodes.csv holds that many rows, a row needing every
    agent's statistics too, which an agent holds until its writer has matched the launcher's (a suite run once
    cut agv1 with no row written after 6 of the world's episodes); else once the launcher's progress (the world's
    statistics, which the world matches before its first step) says so. Under load the rows can lag the world
    by hundreds of episodes: beside two busy loops, 2 of 4 runs of the link-down test had their first rows when
    the world was at episode 290 of 300, too late for a cut mid-run."""
    err = out.parent / "launch.stderr"
    with open(err, "w") as f:
        launcher = subprocess.Popen([*launch_on(hosts, out, "tunnel_to_goal", "indep", episodes, sets, "subnet"),
                                     "--step-timeout", str(step_timeout)], stdout=subprocess.DEVNULL, stderr=f)
    rows = out / "episodes.csv"

    def played() -> bool:
        if rows_of:  # the header, then a row an episode
            return rows.exists() and len(rows.read_text().splitlines()) > after
        return any(int(n) >= after for n in re.findall(r": episodes (\d+)/", err.read_text()))

    try:
        wait_until(played, LAUNCH_TIMEOUT_S, f"the launch never reached episode {after}",
                   ended=lambda: launcher.poll() is not None, detail=err.read_text)
    except WaitTimeout:
        launcher.kill()
        launcher.wait(timeout=30)
        raise
    return launcher, err


def missed(world_log: Path) -> list[tuple[float, int, str]]:
    """(wall time, episode, agents) of every step the world played without an agent's action."""
    return [(float(t), int(e), who) for t, e, who in re.findall(
        r"\[(\d+\.\d+)\] \[[^]]*world\]: episode (\d+) step \d+: no action from ([a-z0-9, ]+) within",
        world_log.read_text())]


@pytest.mark.root
@pytest.mark.ros
@pytest.mark.slow
def test_a_link_down_for_2_s_costs_counted_misses_and_the_agent_comes_back_in_step(hosts, tmp_path):
    # 300 episodes: the link must go down mid-run, and 60 took 1.6 s of stepping on the lean codec (the whole
    # run was over, or nearly, by the time the launcher had written the 6 rows the cut waits for: no step missed)
    out, episodes, sets = tmp_path / "result", 300, ("step_cap=100", "reward_step=-1", "eval_episodes=2")
    # the cut needs no row before it (agv1 holds its statistics until the link is back): the world's progress,
    # which comes every 5% of the run
    launcher, err = launch_until(hosts, out, episodes, sets, after=15, step_timeout=1.0, rows_of=False)
    world_log = out / "logs" / "world.log"

    def agv1_missed_since(t: float) -> list[tuple[float, int]]:
        return [(when, e) for when, e, who in missed(world_log) if "agv1" in who.split(", ") and when >= t]

    try:
        down = time.time()
        hosts.set_link("agv1", up=False)
        # down until the world has gone without agv1 for CUT_MISSES steps (at least 2 s of its waiting)
        wait_until(lambda: len(agv1_missed_since(down)) >= CUT_MISSES, LAUNCH_TIMEOUT_S,
                   f"the world never missed agv1 {CUT_MISSES} times with its link down",
                   ended=lambda: launcher.poll() is not None, detail=err.read_text)
        hosts.set_link("agv1", up=True)
        up = time.time()
        # 3: every episode played, but the steps the link was down for not as offline (the last line says so)
        assert launcher.wait(timeout=LAUNCH_TIMEOUT_S) == 3, err.read_text()
    finally:
        launcher.kill()
        launcher.wait(timeout=30)
    manifest = json.loads((out / "manifest.json").read_text())
    misses = missed(out / "logs" / "world.log")
    assert manifest["world"]["missed_actions"] == sum(len(who.split(", ")) for _, _, who in misses)
    # (a loaded machine can make agv2 miss a step too; that is not what this test is about)
    agv1 = [(t, e) for t, e, who in misses if "agv1" in who.split(", ")]
    assert agv1
    # Only while the cable was out, and a few steps more until the next DDS heartbeat repairs the reliable
    # feedback stream (every 50 ms) or the agent catches up: then agv1 answers every step again, to the last episode.
    assert all(down <= t for t, _ in agv1), (down, agv1)
    assert len(agv1_missed_since(up)) <= RECOVERY_MISSES, (up, agv1)
    assert max(e for _, e in agv1) + 5 < episodes
    assert read_episodes(out).shape == (episodes,)
    # agv1's side of the loss is counted too: the feedback it heard late (DDS repaired the stream) it answered
    # too late for the world, which drops those answers as stale; the feedback it never heard, it counts.
    late = manifest["world"]["counters"].get("dropped.stale_step", 0)
    never_heard = manifest["communication"]["agv1"]["counters"].get("missed_feedback", 0)
    assert late + never_heard >= 1


@pytest.mark.root
@pytest.mark.ros
@pytest.mark.slow
def test_a_host_cut_for_good_ends_the_run_as_a_lost_agent_does_and_keeps_what_was_written(hosts, tmp_path):
    from agent_node.checkpoint import load_checkpoint

    out, sets = tmp_path / "result", ("step_cap=100", "reward_step=-1", "checkpoint_every=5", "feedback_timeout=5")
    # agv1 gives up 5-5.5 s after the cut (feedback_timeout, checked every 0.5 s), long before the world would
    # end the run itself once agv2 is home (ten silent steps and its startup_timeout, 30 s under a launch)
    launcher, err = launch_until(hosts, out, 1000, sets, after=6, step_timeout=0.5)
    try:
        hosts.set_link("agv1", up=False)
        code = launcher.wait(timeout=LAUNCH_TIMEOUT_S)
    finally:
        launcher.kill()
        launcher.wait(timeout=30)
    assert code == 1
    last = err.read_text().strip().splitlines()[-1]
    # the line gives the agent's own reason, its log's last error
    assert re.fullmatch(r"cq-ros launch: error: agv1 \(pid \d+\) exited with code 1 \(no valid message from the "
                        r"world .*\(feedback_timeout=5\.0\): giving up\) after \d+/1020 episodes "
                        r"\(its log: .*agv1\.log\); stopped world, agv2 \(logs in .*\)", last), last
    # a failed launch keeps the rows it heard, one per episode in order, and a manifest that says how it ended.
    # The count in the error is the world's; a row needs every agent's statistics too, and the world may finish
    # an episode whose statistics the cut agent never sent
    played = int(re.search(r"after (\d+)/1020 episodes", last)[1])
    with open(out / "episodes.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert 6 <= len(rows) <= played
    assert [int(r["episode"]) for r in rows] == list(range(len(rows)))
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["ended"]["how"] == "node_failed" and manifest["ended_early"]["episodes_written"] == len(rows)
    gridmap = load_map("tunnel_to_goal")
    for k in (1, 2):  # each agent's last checkpoint, written before the cut, loads whole
        learner, episode = load_checkpoint(out / "checkpoints" / f"agv{k}.npz", "indep", gridmap, k - 1,
                                          run_settings(gridmap, list(sets[:2])))
        assert episode >= 4 and learner.agent == k - 1
    assert not list((out / "checkpoints").glob("*.tmp"))


LOSS = 0.02  # the share of packets dropped each way on the lossy link
LOSSY_EPISODES = 30
# Episodes that may differ from the offline run's with LOSS each way on agv1's link. Measured (docs/faults.md, a
# lossy link): 0 of 30 with the profile's 50 ms heartbeat period (30 of 30, 143 missed actions, with Fast DDS's
# 3 s). A lost packet is resent within about 50 ms, well inside step_timeout; a step is missed only when the
# resends keep being lost for a second or a busy machine stalls a node too: a few, not one a lost packet.
LOSSY_DIFFERING = 3


def iptables_why_not() -> str | None:
    """Why the lossy-link test cannot run here; never a reason in CI, whose .ci/run installs iptables (there a
    missing one fails the test, not skips it)."""
    if shutil.which("iptables") or os.environ.get("CI"):
        return None
    return "no iptables command here (the lossy link is an iptables rule; apt-get install iptables)"


def loss_rules(hosts, host: str) -> list[list[str]]:
    """iptables arguments that drop LOSS of the packets each way through the host's eth0; run in the host's own
    namespace, so the machine's own firewall is never touched."""
    statistic = ["-m", "statistic", "--mode", "random", "--probability", str(LOSS), "-j", "DROP"]
    return [["INPUT", "-i", "eth0", *statistic], ["OUTPUT", "-o", "eth0", *statistic]]


@pytest.mark.root
@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.skipif(iptables_why_not() is not None, reason=str(iptables_why_not()))
def test_a_lossy_link_costs_few_steps_not_a_step_timeout_a_lost_packet(hosts, tmp_path):
    out, sets = tmp_path / "result", ("step_cap=100", "reward_step=-1", "eval_episodes=2")
    rules = loss_rules(hosts, "agv1")
    added = []
    try:
        for rule in rules:
            subprocess.run([*hosts.exec_on("agv1"), "iptables", "-A", *rule], check=True, timeout=10)
            added.append(rule)
        start = time.monotonic()
        done = subprocess.run([*launch_on(hosts, out, "tunnel_to_goal", "indep", LOSSY_EPISODES, sets, "subnet"),
                               "--step-timeout", "1.0"], capture_output=True, text=True, timeout=LAUNCH_TIMEOUT_S)
        wall = time.monotonic() - start
        counted = subprocess.run([*hosts.exec_on("agv1"), "iptables", "-L", "-v", "-n", "-x"], capture_output=True,
                                 text=True, timeout=10).stdout
    finally:
        for rule in reversed(added):
            subprocess.run([*hosts.exec_on("agv1"), "iptables", "-D", *rule], check=True, timeout=10)
    # 0 (the offline run) or 3 (degraded: some step played without agv1's action); never a failure
    assert done.returncode in (0, 3), done.stderr
    offline = run("indep", load_map("tunnel_to_goal"), Settings().with_overrides(list(sets)), SEED, 0, LOSSY_EPISODES)
    episodes = read_episodes(out)
    assert episodes.shape == offline.episodes.shape  # every episode written
    differing = int(np.count_nonzero(episodes != offline.episodes))
    manifest = json.loads((out / "manifest.json").read_text())
    dropped = [int(line.split()[0]) for line in counted.splitlines() if "statistic" in line]
    print(f"\nlossy link: {wall:.1f} s, {differing}/{LOSSY_EPISODES} episodes differ from offline, "
          f"missed_actions {manifest['world']['missed_actions']}, packets dropped {dropped}")
    assert sum(dropped) > 0  # the link was lossy
    assert differing <= LOSSY_DIFFERING, (differing, manifest["world"]["missed_actions"], done.stderr[-2000:])

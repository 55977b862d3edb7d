"""The ROS commands of `cq-ros` (launch, collect, key, view, hosts, echo, topics, nodes, record): each imports
rclpy (through ros_tools) only when it runs, so the rest of cq_ros works without it. The parsers are
ros_parser.py's.
"""

from __future__ import annotations

import importlib.util
import os
import sys
from typing import Any, Callable

from ..gridmap import load_map
from ..lab.output import check_parent
from .offline import print_summary

__all__ = ["hosts", "launch", "collect", "checkpoint", "key", "view", "ros_tool"]


def hosts(args) -> int:
    from ros_tools.hosts import HostsError, existing_prefixes, hosts_down, hosts_up

    try:
        if args.action == "up":
            print(hosts_up(args.agents, args.prefix).describe())
        elif args.action == "down":
            if args.prefix is None:
                raise HostsError("down needs --prefix (`cq-ros hosts list` shows the sets)")
            gone = hosts_down(args.prefix)
            print(f"removed {', '.join(gone)}" if gone else f"no hosts {args.prefix}: nothing to remove")
        else:
            for prefix, names in existing_prefixes().items():
                print(f"{prefix}: {', '.join(names)}")
    except HostsError as e:
        print(f"cq-ros hosts: error: {e}", file=sys.stderr)
        return 2
    return 0


def launch(args) -> int:
    from ros_tools.hosts import HostsError, check_can_make_hosts, find_hosts
    from ros_tools.launch import check_hosts, launch
    from ros_tools.launch_nodes import split_sets

    _system_arguments(args)
    if args.discovery is not None and args.hosts is None:  # one process on this host discovers nothing
        raise ValueError("--discovery chooses how the nodes on --hosts find each other: give --hosts PREFIX too")
    args.discovery = args.discovery or "subnet"
    if args.view is not None and importlib.util.find_spec("foxglove") is None:
        raise ValueError("--view needs foxglove-sdk: pip install '.[view]'")
    # Settings fields (over the map's defaults) and node parameters alike
    settings, node_parameters = split_sets(args.overrides, load_map(args.map))
    node_parameters = {**node_parameters, **args.node_parameters}
    hosts = None
    if args.hosts is not None:
        try:
            check_can_make_hosts()
            hosts = find_hosts(args.hosts)
        except HostsError as e:
            raise ValueError(e) from None
        check_hosts(hosts, load_map(args.map), args.algo, args.discovery)
        if hosts.current_host() != "world":  # the launcher listens on the world's host: run there
            sys.stdout.flush()
            os.execvp("ip", [*hosts.exec_on("world"), sys.executable, "-m", "cq_ros.cli", *args.argv])
    result, code = _ended("launch", lambda: launch(
        args.map, args.algo, args.episodes, args.seed, args.out, settings, domain_id=args.domain_id,
        namespace=args.namespace, step_timeout=args.step_timeout, peer_linger_steps=args.peer_linger_steps,
        compose=args.compose, executor=args.executor, node_parameters=node_parameters, force=args.force,
        figures=args.figures, hosts=hosts, discovery=args.discovery, key_file=args.key, view_port=args.view,
        restart_agents=args.restart_agents))
    if result is None:
        return code
    print_summary(result.out)
    for node, cost in result.manifest["communication"].items():
        print(f"{node}: {cost['peer_messages']} peer position messages ({cost['peer_deliveries']} delivered), "
              f"{cost['subscriptions_created']} subscriptions created")
    print(f"results: {result.out}")
    ended = result.manifest["ended"]
    if ended["how"] == "degraded":  # the last line: a summary that looks clean must not hide it
        print(f"cq-ros launch: {ended['reason']}; exit status {ended['exit_status']}", file=sys.stderr)
    return ended["exit_status"]


def checkpoint(args) -> int:
    from ros_tools.checkpoints import convert

    print(convert(args.old, args.new))
    return 0


def _ended(command: str, run: Callable[[], Any]) -> tuple[Any, int]:
    """(run()'s result, 0), or (None, exit code) after one line: 130 interrupted, 1 the run failed (the error's
    `exit_status`)."""
    from ros_tools.launch_end import Interrupted, LaunchError

    try:
        return run(), 0
    except Interrupted as e:
        print(f"cq-ros {command}: {e}", file=sys.stderr)
        return None, e.exit_status
    except LaunchError as e:
        print(f"cq-ros {command}: error: {e}", file=sys.stderr)
        return None, e.exit_status


def collect(args) -> int:
    from ros_tools.collect import collect

    out, code = _ended("collect", lambda: collect(args.out, domain_id=args.domain_id, namespace=args.namespace,
                                                  force=args.force, wait_s=args.wait))
    if out is None:
        return code
    print_summary(out)
    print(f"results: {out}")
    return 0


def _system_arguments(args) -> None:
    """A launch's map, algorithm, episodes, seed, settings, node parameters and key: from its options, or from
    the system file --params-file names (ros_tools.params_file), which then excludes those options."""
    args.node_parameters = {}
    if args.params_file is None:
        if args.map is None or args.algo is None:
            raise ValueError("--map and --algo are required (or --params-file FILE, a system as a launch writes it)")
        args.episodes = 500 if args.episodes is None else args.episodes
        args.seed = 0 if args.seed is None else args.seed
        return
    from ros_tools.params_file import read_system

    given = [f"--{name}" for name in ("map", "algo", "episodes", "seed", "key") if getattr(args, name) is not None]
    if args.overrides:
        given.append("--set")
    if given:
        raise ValueError(f"--params-file gives the system: drop {', '.join(given)} (or edit the file)")
    system = read_system(args.params_file)
    args.map, args.algo, args.episodes, args.seed, args.key = (system.map, system.algo, system.episodes,
                                                               system.seed, system.key_file)
    args.overrides = [f"{k}={v}" for k, v in system.settings.items()]
    args.node_parameters = system.node_parameters


def key(args) -> int:
    from ros_tools.params_file import make_key

    print(f"wrote {make_key(args.out)} (readable by you only): name it as key_file in a params file, or "
          "cq-ros launch --key FILE")
    return 0


def view(args) -> int:
    from ros_tools.session import ToolError
    from ros_tools.view import view as serve

    try:
        relayed = serve(domain_id=args.domain_id, namespace=args.namespace, host=args.host, port=args.port,
                        wait_s=args.wait)
    except ToolError as e:
        print(f"cq-ros view: error: {e}", file=sys.stderr)
        return 1
    print(f"cq-ros view: stopped after {relayed} messages", file=sys.stderr)
    return 0


def ros_tool(args) -> int:
    from ros_tools import commands as tools

    try:
        if args.command == "echo":
            tools.echo(args.topic, count=args.count, timeout_s=args.timeout, domain_id=args.domain_id)
        elif args.command == "topics":
            tools.topics(show_types=args.show_types, wait_s=args.wait, domain_id=args.domain_id)
        elif args.command == "nodes":
            tools.nodes(all_nodes=args.all_nodes, wait_s=args.wait, domain_id=args.domain_id)
        else:
            check_parent(args.out, "--out")
            tools.record(args.out, topics=args.topics, duration_s=args.duration, count=args.count,
                         storage=args.storage, domain_id=args.domain_id, namespace=args.namespace)
    except tools.ToolError as e:
        print(f"cq-ros {args.command}: error: {e}", file=sys.stderr)
        return 1
    return 0

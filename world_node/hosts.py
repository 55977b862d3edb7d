"""Hosts made of Linux network namespaces, to run the nodes as on separate machines (root and `ip` needed).

    python -m world_node.hosts up world agv1 agv2      # prints the namespaces and addresses
    ip netns exec cqh<token>-world python -m world_node --ros-args ...   # one node per host
    python -m world_node.hosts link cqh<token> agv1 down|up
    python -m world_node.hosts down cqh<token>

Each host is a namespace `<prefix>-<host>` whose `eth0` (a veth pair) is plugged into one bridge, in a
namespace of its own (`<prefix>-sw`), with an address from 198.18.0.0/15 (the range set aside for network
tests, RFC 2544) and a multicast route, so DDS discovery works over the subnet
(`ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET`) or by unicast (`ROS_STATIC_PEERS`, `Hosts.addresses`). Taking a
host's switch port down (`link`) is a cable pulled out: the host keeps its address and its processes, and
hears nothing. `down` deletes every namespace (and with them every link) the prefix made. No `tc netem`:
this kernel has none (DESIGN.md field notes).
"""

from __future__ import annotations

import secrets
import shutil
import subprocess
import sys
from pathlib import Path

__all__ = ["SUBNET", "Hosts", "available"]

SUBNET = "198.18.0"  # /24 inside 198.18.0.0/15
ENTER = ["ip", "netns", "exec"]


def available() -> str | None:
    """None when network namespaces can be made here, else why not."""
    if shutil.which("ip") is None:
        return "no `ip` command (iproute2)"
    if not Path("/proc/self/ns/net").exists():
        return "no network namespaces in this kernel"
    import os

    if os.geteuid() != 0:
        return "network namespaces need root"
    return None


def _ip(*args: str) -> None:
    done = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=30)
    if done.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {done.stderr.strip()}")


class Hosts:
    """Hosts `names` (e.g. world, agv1, agv2) on one bridge; a context manager that removes them all."""

    def __init__(self, names: list[str], prefix: str | None = None):
        self.names = list(names)
        self.prefix = prefix or f"cqh{secrets.token_hex(3)}"
        self.addresses = {name: f"{SUBNET}.{i + 1}" for i, name in enumerate(self.names)}

    def namespace(self, name: str) -> str:
        return f"{self.prefix}-{name}"

    @property
    def switch(self) -> str:
        return f"{self.prefix}-sw"

    def up(self) -> "Hosts":
        try:
            _ip("netns", "add", self.switch)
            _ip("-n", self.switch, "link", "add", "br0", "type", "bridge", "mcast_snooping", "0")
            _ip("-n", self.switch, "link", "set", "br0", "up")
            for name in self.names:
                ns, port = self.namespace(name), self.port(name)
                _ip("netns", "add", ns)
                _ip("link", "add", "eth0", "netns", ns, "type", "veth", "peer", "name", port, "netns", self.switch)
                _ip("-n", self.switch, "link", "set", port, "master", "br0", "up")
                _ip("-n", ns, "addr", "add", f"{self.addresses[name]}/24", "dev", "eth0")
                _ip("-n", ns, "link", "set", "lo", "up")
                _ip("-n", ns, "link", "set", "eth0", "up")
                _ip("-n", ns, "route", "add", "224.0.0.0/4", "dev", "eth0")
        except BaseException:
            self.down()
            raise
        return self

    def link(self, name: str, up: bool) -> None:
        """Plug host `name`'s cable in (up) or pull it out (down), at the switch."""
        _ip("-n", self.switch, "link", "set", self.port(name), "up" if up else "down")

    @staticmethod
    def port(name: str) -> str:
        """The switch port of host `name` (an interface name: at most 15 characters)."""
        return f"p-{name}"[:15]

    def command(self, name: str, argv: list[str]) -> list[str]:
        """`argv` run on host `name`."""
        return [*ENTER, self.namespace(name), *argv]

    def down(self) -> None:
        """Delete every namespace of this prefix (their links go with them); never raises."""
        listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, timeout=30).stdout
        for line in listed.splitlines():
            ns = line.split()[0] if line.split() else ""
            if ns.startswith(f"{self.prefix}-"):
                subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30)

    def __enter__(self) -> "Hosts":
        return self.up()

    def __exit__(self, *exc) -> None:
        self.down()


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(prog="python -m world_node.hosts", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="command", required=True)
    p = sub.add_parser("up", help="make hosts on one bridge")
    p.add_argument("names", nargs="+")
    p = sub.add_parser("link", help="a host's cable out (down) or in (up)")
    p.add_argument("prefix")
    p.add_argument("name")
    p.add_argument("state", choices=("up", "down"))
    p = sub.add_parser("down", help="remove every namespace of a prefix")
    p.add_argument("prefix")
    args = ap.parse_args(argv)
    why = available()
    if why:
        print(f"world_node.hosts: {why}", file=sys.stderr)
        return 2
    try:
        if args.command == "up":
            hosts = Hosts(args.names).up()
            print(f"prefix {hosts.prefix}; switch {hosts.switch}")
            for name, address in hosts.addresses.items():
                print(f"{hosts.namespace(name)} {address}")
            print(f"ROS_STATIC_PEERS={';'.join(hosts.addresses.values())}")
        elif args.command == "link":
            Hosts([args.name], args.prefix).link(args.name, args.state == "up")
        else:
            Hosts([], args.prefix).down()
    except (RuntimeError, ValueError) as e:
        print(f"world_node.hosts: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

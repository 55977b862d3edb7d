"""`cq-ros hosts`: several hosts on one Linux machine, made of network namespaces, to run the world and each AGV
on a host of its own (root and the `ip` command of iproute2 needed).

A set of hosts has a prefix, `cqr` and 5 hex digits unless given (so parallel sets and the clean-up of
leftovers never collide), and is made of namespaces only: `<prefix>-world` and `<prefix>-agv<k>` (the hosts:
loopback up, one interface `eth0` with an address from 198.18.0.0/15, the block set aside for network tests,
RFC 2544), and `<prefix>-net`, the switch: a bridge `br0` and, per host, the other end of its veth pair, named
`<prefix>w` (the world's) or `<prefix>a<k>` (agv k's). Nothing is made in the machine's own namespace, so no
interface, address or route of the host itself changes, and no packet can leave the set: `ip -n <prefix>-net
link set <prefix>a1 down` pulls agv1's cable. The bridge floods multicast (DDS discovery) to every port:
multicast snooping is off, as there is no querier.

Deleting a namespace deletes its interfaces, and a veth pair goes with either end, so `down` (deleting every
namespace of the prefix) removes everything `up` made; `up` tears down what it made when a step fails.
"""

from __future__ import annotations

import ipaddress
import os
import re
import secrets
import shutil
import subprocess
from dataclasses import dataclass

__all__ = ["HostsError", "Hosts", "SUBNET", "DISCOVERY", "check_can_make_hosts", "hosts_up", "hosts_down",
           "find_hosts", "existing_prefixes", "new_prefix"]

SUBNET = ipaddress.ip_network("198.18.0.0/24")  # inside 198.18.0.0/15 (RFC 2544): never a real network's
PREFIX = re.compile(r"cqr[0-9a-z]{1,8}")  # short enough for interface names (15 characters at most)
NETNS_DIR = "/run/netns"
IP_TIMEOUT_S = 10.0
# How nodes on the hosts find each other: multicast on the subnet, or unicast to the other hosts' addresses only
# (ROS_STATIC_PEERS; Jazzy's LOCALHOST range stops multicast and keeps the static peers, while OFF drops them too).
DISCOVERY = ("subnet", "static")


class HostsError(RuntimeError):
    """Hosts cannot be made or removed here; the message is one line."""


@dataclass(frozen=True)
class Hosts:
    """One set of hosts: its prefix and number of AGVs; names and addresses follow from them."""

    prefix: str
    agents: int

    @property
    def switch(self) -> str:
        return f"{self.prefix}-net"

    @property
    def names(self) -> list[str]:
        """The hosts' names, the world first: world, agv1, agv2, ... (as the launcher names its nodes)."""
        return ["world"] + [f"agv{k}" for k in range(1, self.agents + 1)]

    def namespace(self, host: str) -> str:
        return f"{self.prefix}-{host}"

    def address(self, host: str) -> str:
        """world .1, agv k .(k+1)."""
        index = 0 if host == "world" else int(host[3:])
        return str(SUBNET.network_address + 1 + index)

    def cable(self, host: str) -> str:
        """The switch's end of the host's veth pair (in the switch namespace): down is the cable pulled."""
        return f"{self.prefix}w" if host == "world" else f"{self.prefix}a{host[3:]}"

    @property
    def namespaces(self) -> list[str]:
        return [self.switch] + [self.namespace(h) for h in self.names]

    def discovery_env(self, host: str, discovery: str) -> dict[str, str]:
        """The environment of a ROS process on `host`. UDP only: Fast DDS would otherwise carry data between
        processes of one machine through shared memory, /dev/shm being common to every network namespace,
        and the network would not be between them."""
        if discovery not in DISCOVERY:
            raise HostsError(f"discovery must be one of {', '.join(DISCOVERY)}, got {discovery!r}")
        env = {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}
        if discovery == "subnet":
            return {**env, "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "ROS_STATIC_PEERS": ""}
        peers = ";".join(self.address(h) for h in self.names if h != host)
        return {**env, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_STATIC_PEERS": peers}

    def current_host(self) -> str | None:
        """The host this process runs on, None if none of these."""
        mine = os.stat("/proc/self/ns/net")
        for host in self.names:
            try:
                ns = os.stat(os.path.join(NETNS_DIR, self.namespace(host)))
            except FileNotFoundError:
                continue
            if (ns.st_dev, ns.st_ino) == (mine.st_dev, mine.st_ino):
                return host
        return None

    def pids(self) -> list[int]:
        """Every process running on one of these hosts (the switch included)."""
        ours = set()
        for ns in self.namespaces:
            try:
                st = os.stat(os.path.join(NETNS_DIR, ns))
            except FileNotFoundError:
                continue
            ours.add((st.st_dev, st.st_ino))
        found = []
        for pid in filter(str.isdigit, os.listdir("/proc")):
            try:
                st = os.stat(f"/proc/{pid}/ns/net")
            except OSError:  # gone meanwhile, or not ours to see
                continue
            if (st.st_dev, st.st_ino) in ours:
                found.append(int(pid))
        return found

    def exec_on(self, host: str) -> list[str]:
        """The command prefix that runs a program on `host`."""
        return ["ip", "netns", "exec", self.namespace(host)]

    def set_link(self, host: str, up: bool) -> None:
        """Plug (up) or pull (down) the host's cable at the switch."""
        _ip("-n", self.switch, "link", "set", self.cable(host), "up" if up else "down")

    def describe(self) -> str:
        lines = [f"hosts {self.prefix}: switch namespace {self.switch} (bridge br0, subnet {SUBNET})"]
        lines += [f"  {self.namespace(h)}: eth0 {self.address(h)}/{SUBNET.prefixlen}, cable {self.cable(h)}"
                  for h in self.names]
        return "\n".join(lines)


def new_prefix() -> str:
    return f"cqr{secrets.token_hex(3)[:5]}"


def check_can_make_hosts() -> None:
    """HostsError unless this process can make network namespaces: root, and `ip` on the PATH."""
    if shutil.which("ip") is None:
        raise HostsError("the `ip` command (iproute2) is not on the PATH")
    if os.geteuid() != 0:
        raise HostsError("making network namespaces needs root (run as root, e.g. with sudo)")


def _ip(*args: str) -> None:
    done = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=IP_TIMEOUT_S)
    if done.returncode != 0:
        raise HostsError(f"`ip {' '.join(args)}` failed: {done.stderr.strip() or done.returncode}")


def existing_prefixes() -> dict[str, list[str]]:
    """Every set of hosts on this machine: prefix -> its namespaces (made by us: named <prefix>-...)."""
    try:
        names = sorted(os.listdir(NETNS_DIR))
    except FileNotFoundError:
        return {}
    found: dict[str, list[str]] = {}
    for name in names:
        prefix, _, _ = name.partition("-")
        if PREFIX.fullmatch(prefix) and name != prefix:
            found.setdefault(prefix, []).append(name)
    return found


def _check_prefix(prefix: str) -> None:
    if not PREFIX.fullmatch(prefix):
        raise HostsError(f"prefix {prefix!r} must be 'cqr' and 1 to 8 lower-case letters or digits")


def find_hosts(prefix: str) -> Hosts:
    """The complete set of hosts `prefix` made by hosts_up; HostsError if it is missing or incomplete."""
    _check_prefix(prefix)
    names = existing_prefixes().get(prefix)
    if not names:
        raise HostsError(f"no hosts {prefix} on this machine (`cq-ros hosts up --agents N` makes them)")
    hosts = Hosts(prefix, sum(name.startswith(f"{prefix}-agv") for name in names))
    if sorted(names) != sorted(hosts.namespaces):
        raise HostsError(f"hosts {prefix} are incomplete ({', '.join(names)}): `cq-ros hosts down --prefix "
                         f"{prefix}` removes them")
    return hosts


def hosts_up(agents: int, prefix: str | None = None) -> Hosts:
    """Make the switch and agents + 1 hosts (see the module docstring); on any failure remove what was made
    and raise HostsError."""
    check_can_make_hosts()
    if agents < 1 or agents > SUBNET.num_addresses - 3:
        raise HostsError(f"agents must be 1..{SUBNET.num_addresses - 3}, got {agents}")
    prefix = prefix or new_prefix()
    _check_prefix(prefix)
    if prefix in existing_prefixes():
        raise HostsError(f"hosts {prefix} exist already (`cq-ros hosts down --prefix {prefix}` removes them)")
    hosts = Hosts(prefix, agents)
    try:
        _ip("netns", "add", hosts.switch)
        sw = ["-n", hosts.switch]
        _ip(*sw, "link", "add", "br0", "type", "bridge", "mcast_snooping", "0")
        _ip(*sw, "link", "set", "br0", "up")
        for host in hosts.names:
            ns = hosts.namespace(host)
            _ip("netns", "add", ns)
            _ip(*sw, "link", "add", hosts.cable(host), "type", "veth", "peer", "name", "eth0", "netns", ns)
            _ip(*sw, "link", "set", hosts.cable(host), "master", "br0", "up")
            _ip("-n", ns, "link", "set", "lo", "up")
            _ip("-n", ns, "addr", "add", f"{hosts.address(host)}/{SUBNET.prefixlen}", "dev", "eth0")
            _ip("-n", ns, "link", "set", "eth0", "up")
    except (HostsError, subprocess.TimeoutExpired) as e:
        hosts_down(prefix)
        raise HostsError(f"{e} (removed what was made)") from None
    return hosts


def hosts_down(prefix: str) -> list[str]:
    """Delete every namespace of `prefix` (their interfaces and veth pairs go with them); the names deleted.
    Nothing to delete is not an error, so it can run after any failure."""
    check_can_make_hosts()
    _check_prefix(prefix)
    gone = []
    for ns in existing_prefixes().get(prefix, []):
        _ip("netns", "del", ns)
        gone.append(ns)
    return gone

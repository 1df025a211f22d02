"""Which sockets a process tree has open, and this host's own non-loopback address.

Sockets are read with ``ss`` (iproute2), which also shows a socket bound to a device
(``0.0.0.0%lo:43113``): a udp_multicast bus is bound to every address but only to the loopback
device, and /proc/net/udp does not say so.
"""

from __future__ import annotations

import ipaddress
import re
import subprocess
from dataclasses import dataclass
from pathlib import Path

_USERS = re.compile(r"pid=(\d+),")


@dataclass(frozen=True)
class OpenSocket:
    protocol: str
    state: str
    local: str
    pid: int

    @property
    def host_local(self) -> bool:
        """Bound to a loopback address, or to the loopback device."""
        address = self.local.rsplit(":", 1)[0]
        if address.endswith("%lo"):
            return True
        try:
            return ipaddress.ip_address(address.strip("[]")).is_loopback
        except ValueError:
            return False


def process_tree(root: int) -> set[int]:
    """``root`` and every process descended from it."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue  # gone meanwhile
            parents[int(entry.name)] = int(stat.rsplit(")", 1)[1].split()[1])
    tree, grew = {root}, True
    while grew:
        grew = False
        for pid, parent in parents.items():
            if parent in tree and pid not in tree:
                tree.add(pid)
                grew = True
    return tree


def inet_sockets(pids: set[int]) -> list[OpenSocket]:
    """Every TCP and UDP socket (listening, connected or bound) the processes hold."""
    result = subprocess.run(["ss", "-H", "-tuanp"], capture_output=True, text=True, check=True)
    sockets = []
    for line in result.stdout.splitlines():
        fields = line.split()
        owners = {int(pid) for pid in _USERS.findall(line)}
        if len(fields) >= 6 and owners & pids:
            protocol, state, local = fields[0], fields[1], fields[4]
            sockets.extend(OpenSocket(protocol, state, local, pid) for pid in owners & pids)
    return sockets


def own_non_loopback_address() -> str:
    """An IPv4 address of this host on a network interface (the test sends from it as another
    host on that network would).

    Raises:
        AssertionError: the host has none; what needs it cannot be exercised here.
    """
    result = subprocess.run(["ip", "-4", "-o", "addr", "show", "scope", "global"],
                            capture_output=True, text=True, check=True)
    for line in result.stdout.splitlines():
        address = line.split()[3].split("/")[0]
        if not ipaddress.ip_address(address).is_loopback:
            return address
    raise AssertionError("this host has no non-loopback IPv4 address to send from: reaching "
                         "the bus from the network cannot be exercised here")

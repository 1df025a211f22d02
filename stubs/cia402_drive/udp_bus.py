"""The emulator's side of a ``udp_multicast`` bus: its socket, set up once python-can made it.

python-can binds the socket to every interface and sends with TTL 1, so the emulated drives
would talk over the LAN and take frames from it. :func:`confine_to_host` keeps the bus on this
host; it works on a duplicate of the bus's public ``fileno()`` (the same socket, no private
attribute of python-can, python-can not patched). warden's driver does the same on its side,
written separately (``drivers/canopen402/udp_bus.py``).
"""

from __future__ import annotations

import ipaddress
import os
import socket
import struct

import can

UDP_RECEIVE_BUFFER = 4 * 1024 * 1024
"""Requested SO_RCVBUF; Linux caps it at net.core.rmem_max."""
LOOPBACK = "127.0.0.1"
IP_MULTICAST_ALL = getattr(socket, "IP_MULTICAST_ALL", 49)
"""Linux's option (linux/in.h), unnamed in Python: 0 receives only the groups this socket
joined, not every group joined by anyone on its port (the default, 1)."""


def fileno(bus: can.BusABC) -> int:
    """The bus's descriptor, -1 for a bus without one (``virtual``)."""
    try:
        return bus.fileno()
    except NotImplementedError:
        return -1


def _udp_socket(bus: can.BusABC) -> socket.socket | None:
    fd = fileno(bus)
    if fd < 0:
        return None
    sock = socket.socket(fileno=os.dup(fd))
    if sock.type != socket.SOCK_DGRAM:
        sock.close()
        return None
    return sock


def widen_receive_buffer(bus: can.BusABC, size: int = UDP_RECEIVE_BUFFER) -> None:
    """Let a UDP-backed bus ride through a stall of this process without dropping frames.

    On ``udp_multicast`` every process also receives its own frames back: six drives answering
    a 500 Hz SYNC are some 10k datagrams/s, and the default receive buffer (~212 KB) overflows
    after a pause of a few tens of milliseconds (a busy core, a GC pass), losing SDO requests
    and RPDOs. Buses without a file descriptor (``virtual``) are left as they are.
    """
    sock = _udp_socket(bus)
    if sock is None:
        return
    with sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)


def confine_to_host(bus: can.BusABC, group: str) -> None:
    """Receive only what arrives on loopback, and send only there.

    ``SO_BINDTODEVICE lo`` drops every datagram that arrives on a network interface (another
    host's, to the group or unicast to this host's address and the port); the group is joined
    on loopback instead of the default interface; frames go out through loopback with TTL 0,
    so they never reach a wire and the local loop copy is their one delivery; with
    ``IP_MULTICAST_ALL`` off only this bus's group is received, so two buses that share a port
    (different groups) stay two buses.

    Raises:
        ValueError: ``group`` is not an IPv4 multicast address.
        OSError: the kernel refused a socket option.
    """
    address = ipaddress.ip_address(group)
    if address.version != 4 or not address.is_multicast:
        raise ValueError(f"{group!r} is not an IPv4 multicast group (e.g. 239.0.0.1)")
    sock = _udp_socket(bus)
    if sock is None:
        return
    with sock:
        membership = socket.inet_aton(group)
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_DROP_MEMBERSHIP,
                        membership + struct.pack("@I", socket.INADDR_ANY))
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                        membership + socket.inet_aton(LOOPBACK))
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(LOOPBACK))
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
        sock.setsockopt(socket.IPPROTO_IP, IP_MULTICAST_ALL, 0)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_BINDTODEVICE, b"lo")

"""The socket under a ``udp_multicast`` bus (python-can's emulation of a CAN bus over IP
multicast), set up once after python-can made it.

Both functions work on a duplicate of the bus's public ``fileno()``: the same socket, no
private attribute of python-can, python-can itself not patched. The CiA 402 emulator does the
same on its side (``stubs/cia402_drive/udp_bus.py``, written separately, as every emulator is).
"""

from __future__ import annotations

import ipaddress
import os
import socket
import struct

from drivers.canopen402._sdk import CanBus

UDP_RECEIVE_BUFFER = 4 * 1024 * 1024
"""Requested SO_RCVBUF; Linux caps it at net.core.rmem_max."""
LOOPBACK = "127.0.0.1"
IP_MULTICAST_ALL = getattr(socket, "IP_MULTICAST_ALL", 49)
"""Linux's option (linux/in.h; Python does not name it): 1, the default, delivers a multicast
datagram to every socket bound to its port whatever group that socket joined; 0 only the
groups the socket itself joined."""


def _dup(bus: CanBus) -> socket.socket | None:
    """The bus's UDP socket (a duplicate descriptor), or None for a bus without one."""
    try:
        fd = bus.fileno()
    except NotImplementedError:
        return None
    if fd < 0:
        return None
    sock = socket.socket(fileno=os.dup(fd))
    if sock.type != socket.SOCK_DGRAM:
        sock.close()
        return None
    return sock


def widen_receive_buffer(bus: CanBus, size: int = UDP_RECEIVE_BUFFER) -> None:
    """Let a UDP-backed bus ride through a stall of its reader without dropping frames.

    On ``udp_multicast`` every process also receives its own frames back, some 10k datagrams/s
    with six drives at 500 Hz; the default 212 KB receive buffer overflows after a ~25 ms
    pause of the reader (a busy core, a GC pass), and a dropped SDO reply fails the bring-up.
    """
    sock = _dup(bus)
    if sock is None:
        return
    with sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)


def check_group(channel: str) -> str | None:
    """Why ``channel`` cannot be a host-local udp_multicast group, or None if it can."""
    try:
        address = ipaddress.ip_address(channel)
    except ValueError:
        return f"{channel!r} is not an IP address"
    if address.version != 4 or not address.is_multicast:
        return (f"{channel!r} is not an IPv4 multicast group (224.0.0.0/4, e.g. 239.0.0.1): "
                "the emulated bus is kept on this host over IPv4 loopback")
    return None


def confine_to_host(bus: CanBus, group: str) -> None:
    """Make a udp_multicast bus unreachable from other hosts, and keep its frames off the LAN.

    python-can binds the socket to every interface (port only), joins the group on the
    default interface and sends with TTL 1: the frames went out on the LAN, and a datagram
    from another host, to the group or to this host's address and the port, was a CAN frame
    for the drives (an NMT stop, say). From here on:

    - ``SO_BINDTODEVICE lo``: only datagrams that arrive on the loopback interface are
      received; another host's arrive on a network interface and are dropped, unicast or
      multicast, and so are this host's own sent through one;
    - the group is left on the default interface and joined on loopback;
    - frames are sent through loopback (``IP_MULTICAST_IF``) with TTL 0 (never onto a wire;
      the local loop copy, ``IP_MULTICAST_LOOP``, is their one delivery);
    - ``IP_MULTICAST_ALL`` off: only the bus's own group is received, so buses on one port are
      still separate buses (by default Linux hands a socket every group joined on its port, and
      a check of an empty channel enabled the drives of another emulator on the same port).

    Between python-can's ``bind`` and this call (microseconds, before any frame is sent) the
    socket is still open to the LAN.

    Raises:
        OSError: a socket option was refused.
        ValueError: ``group`` is not an IPv4 multicast group.
    """
    problem = check_group(group)
    if problem is not None:
        raise ValueError(problem)
    sock = _dup(bus)
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

"""The kernel's receive time of each datagram a UDP socket reads (Linux ``SO_TIMESTAMPNS``).

A datagram is dated when the kernel queued it, not when a thread of a loaded host got round
to reading it: the gaps between a node's copies (MCP-RTX-3) and its ACK latency (MCP-ACK-7)
are then the node's (``harness.driver``; ``soak.medium``). See socket(7), ``SO_TIMESTAMPNS``.
"""

from __future__ import annotations

import socket
import struct
import sys
from typing import Any

__all__ = ["SO_TIMESTAMPNS", "arrival_ns", "kernel_timestamps", "recv_stamped"]

#: Linux's SO_TIMESTAMPNS (= SCM_TIMESTAMPNS; Python's socket module does not name it): the
#: kernel's receive time of each datagram as a struct timespec in the ancillary data
SO_TIMESTAMPNS = 35
_TIMESPEC = struct.Struct("@ll")
_CMSG_SPACE = socket.CMSG_SPACE(_TIMESPEC.size) if hasattr(socket, "CMSG_SPACE") else 0


def kernel_timestamps(sock: socket.socket) -> bool:
    """Ask the kernel to timestamp each datagram ``sock`` receives; False where it cannot."""
    if not sys.platform.startswith("linux") or not _CMSG_SPACE:
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    except OSError:
        return False
    return True


def arrival_ns(ancillary: list[tuple[int, int, bytes]]) -> int | None:
    """The kernel's receive time (ns since the epoch) from ``recvmsg``'s ancillary data."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(data) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(data)
            return sec * 10**9 + nsec
    return None


def recv_stamped(sock: socket.socket, stamped: bool) -> tuple[bytes, Any, int | None]:
    """One datagram from ``sock``: (data, addr, the kernel's receive time in ns or None).
    ``stamped``: ``kernel_timestamps(sock)`` said yes. Raises what ``recvfrom`` raises."""
    if stamped:
        data, anc, _, addr = sock.recvmsg(65535, _CMSG_SPACE)
        return data, addr, arrival_ns(anc)
    data, addr = sock.recvfrom(65535)
    return data, addr, None

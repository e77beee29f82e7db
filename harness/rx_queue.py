"""How much a UDP socket on this host has received but not yet read (MCP-ROB-7's flood).

Linux's ``/proc/net/udp`` and ``/proc/net/udp6`` list every UDP socket with its local
address and its ``rx_queue``: the bytes the kernel holds for it, unread. After a flood of
malformed datagrams "as fast as loopback takes them", a node has up to its receive buffer
of them still to read; a liveness probe sent at once waits behind them, and a node starved
of CPU by a loaded host may not reach it within the probe's retransmissions although it
is working through the backlog. The flood case therefore probes once the node's socket has
read the flood (its queue empty), within a bound: a node that stops reading still gets its
probe, and its silence is still MCP-ROB-7's verdict.

Where ``/proc`` does not say (another system, a target on another host), nothing is waited
for.
"""

from __future__ import annotations

import ipaddress
import time

__all__ = ["FLOOD_READ_S", "read_backlog", "udp_rx_queue", "wait_read"]

#: How long MCP-ROB-7's flood waits for the node to read its backlog before the probe (both
#: roles: a correct node a loaded host starves of CPU works through the backlog first).
FLOOD_READ_S = 10.0

_TABLES = ("/proc/net/udp", "/proc/net/udp6")


def _hex_ip(text: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    """``/proc/net/udp``'s address: the IP's bytes in host order, word by word (x86: little-endian)."""
    try:
        raw = bytes.fromhex(text)
    except ValueError:
        return None
    words = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))
    try:
        ip = ipaddress.ip_address(words)
    except ValueError:
        return None
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        return ip.ipv4_mapped
    return ip


def udp_rx_queue(host: str, port: int, proc: str = "/proc") -> int | None:
    """The unread bytes of the UDP socket(s) bound to ``port`` that receive what is sent to
    ``host`` (bound to it or to the wildcard address); None where no table lists one."""
    try:
        want = ipaddress.ip_address(host)
    except ValueError:
        return None
    total, found = 0, False
    for table in _TABLES:
        try:
            with open(proc + table[len("/proc"):], encoding="ascii") as f:
                next(f, None)
                for line in f:
                    fields = line.split()
                    if len(fields) < 5 or ":" not in fields[1] or ":" not in fields[4]:
                        continue
                    ip_hex, port_hex = fields[1].rsplit(":", 1)
                    if int(port_hex, 16) != port:
                        continue
                    ip = _hex_ip(ip_hex)
                    if ip is None or not (ip == want or ip.is_unspecified):
                        continue
                    total += int(fields[4].rsplit(":", 1)[1], 16)
                    found = True
        except (OSError, ValueError):
            continue
    return total if found else None


def wait_read(host: str, port: int, limit: float, poll: float = 0.02, proc: str = "/proc") -> float | None:
    """Wait (at most ``limit`` s) until the socket at ``host``:``port`` has read what it was
    sent; the seconds it took, or None where the queue cannot be seen or did not empty."""
    t0 = time.monotonic()
    while True:
        queued = udp_rx_queue(host, port, proc)
        if queued is None:
            return None
        waited = time.monotonic() - t0
        if queued == 0:
            return waited
        if waited >= limit:
            return None
        time.sleep(poll)


def read_backlog(host: str, port: int, limit: float = FLOOD_READ_S) -> bool:
    """Whether the runner's own socket at ``host``:``port`` still held unread datagrams; if so,
    waits (at most ``limit`` s) until they are read. An exchange whose wait ended with some
    unread looks again among them, by the kernel's receive times: a reply that came in time
    counts, however late its receive thread got the CPU to read it (a node that ACKed the
    3,330 malformed lists of MCP-ROB-7's flood, on a loaded host, answered the probe in 0.2 ms
    and was read 1.1 s later: "no ACK after 5 copies"). Judged on what the node did."""
    if not udp_rx_queue(host, port):
        return False
    wait_read(host, port, limit)
    return True

"""harness.rx_queue: a UDP socket's unread bytes, from /proc/net/udp (MCP-ROB-7's flood)."""

from __future__ import annotations

import socket
import sys
import threading
import time
from pathlib import Path

import pytest

from mcp_conform.harness.rx_queue import udp_rx_queue, wait_read

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/net/udp is Linux's")


def _bound() -> tuple[socket.socket, int]:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    return s, s.getsockname()[1]


def test_unread_datagrams_are_counted_and_reading_them_empties_the_queue():
    s, port = _bound()
    c = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        assert udp_rx_queue("127.0.0.1", port) == 0
        for _ in range(20):
            c.sendto(b"x" * 30, ("127.0.0.1", port))
        time.sleep(0.05)
        assert udp_rx_queue("127.0.0.1", port) > 0
        assert wait_read("127.0.0.1", port, 0.1) is None  # nobody reads: not emptied in time
        s.setblocking(False)
        reader = threading.Timer(0.2, lambda: [s.recv(100) for _ in range(20)])
        reader.start()
        took = wait_read("127.0.0.1", port, 5.0)
        reader.join()
        assert took is not None and took >= 0.15
        assert udp_rx_queue("127.0.0.1", port) == 0
    finally:
        s.close()
        c.close()


def test_a_port_nothing_is_bound_to_and_another_hosts_address_are_not_waited_for():
    s, port = _bound()
    s.close()
    assert udp_rx_queue("127.0.0.1", port) is None
    assert wait_read("127.0.0.1", port, 5.0) is None
    assert udp_rx_queue("not-an-ip", 7889) is None


def test_a_wildcard_socket_and_the_tables_format(tmp_path: Path):
    """IPv4 words little-endian in the table (x86); a v4-mapped v6 wildcard socket counts."""
    net = tmp_path / "net"
    net.mkdir()
    head = "  sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode\n"
    (net / "udp").write_text(head
                             + "  1: 0100007F:1ED1 00000000:0000 07 00000000:00000340 00:00000000 00000000 0 0 1\n"
                             + "  2: 0200007F:1ED1 00000000:0000 07 00000000:00001000 00:00000000 00000000 0 0 2\n")
    (net / "udp6").write_text(head + "  3: 00000000000000000000000000000000:1ED2 "
                              "00000000000000000000000000000000:0000 07 00000000:00000010 00:00000000 00000000 0 0 3\n")
    assert udp_rx_queue("127.0.0.1", 7889, proc=str(tmp_path)) == 0x340  # not 127.0.0.2's
    assert udp_rx_queue("127.0.0.1", 7890, proc=str(tmp_path)) == 0x10  # the :: socket takes it
    assert udp_rx_queue("127.0.0.1", 7891, proc=str(tmp_path)) is None

"""A node a test starts in the background on a port of its choosing (attach mode, a capture's
target): started again on a fresh port when it exits before its first datagram, and its own
words (stderr, kept in a file) in the failure when it never speaks.

A port from ``free_port`` is free when chosen, not when the node binds it: another worker's
node can take it in between (``vehicle.ports``), and the node then exits at once with code 2.
With its stderr sent to DEVNULL a CI run said only "the reference drone sent nothing" within
20 s (tests/captures/test_dissector.py). A node that exits is seen at once (polled every
0.1 s), not at the end of the wait.
"""

from __future__ import annotations

import os
import socket
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import IO, Any

from mcp_conform.harness.rx_queue import udp_rx_queue
from tests.capturing import free_port

#: Starts of a node that exited before speaking, each on a fresh port, before the test fails.
TRIES = 3


class Node:
    """A background process whose stderr goes to a temporary file, read back by ``explain``."""

    def __init__(self, argv: list[str], **popen: Any) -> None:
        self._err: IO[bytes] = tempfile.TemporaryFile()
        popen.setdefault("stdout", subprocess.DEVNULL)
        popen.setdefault("stdin", subprocess.DEVNULL)
        self.argv = argv
        self.proc = subprocess.Popen(argv, stderr=self._err, **popen)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def explain(self) -> str:
        """Whether it still runs, else its exit code; and the last of its stderr."""
        self._err.flush()
        self._err.seek(0)
        words = self._err.read().decode(errors="replace").strip()[-1500:]
        rc = self.proc.poll()
        state = "still running" if rc is None else f"exited with code {rc}"
        return f"{state}; its stderr: {words or '(nothing)'}"

    def stop(self, kill: bool = False) -> None:
        if self.proc.poll() is None:
            (self.proc.kill if kill else self.proc.terminate)()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)
        self._err.close()


def heard_on(sock: socket.socket) -> Callable[[float], bool]:
    """Whether a datagram reaches ``sock`` (bound by the caller) within the given seconds; the
    datagram is read and dropped (a node's Mission_Ready is retransmitted until ACKed)."""

    def heard(seconds: float) -> bool:
        sock.settimeout(max(seconds, 0.001))
        try:
            sock.recvfrom(70000)
        except (TimeoutError, BlockingIOError):
            return False
        return True

    return heard


def start_node(argv_for: Callable[[int], list[str]], heard: Callable[[float], bool] | None,
               timeout: float = 60.0, settle: float = 0.0, **popen: Any) -> tuple[Node, int]:
    """``argv_for(port)`` started on a fresh ``free_port`` until ``heard(seconds)`` says it
    spoke; one that exits first is started again on another port (``TRIES`` starts). With
    ``heard`` None (a node that speaks only when spoken to) it is started once, waited for
    until its socket is bound to the port (``harness.rx_queue.udp_rx_queue`` lists it, up to ``timeout``: on a loaded host
    an interpreter takes seconds to get there, and what is sent before is lost; where that
    cannot be seen, not waited for) and must still run after ``settle`` s. AssertionError with
    its stderr when it never speaks."""
    for attempt in range(1, TRIES + 1):
        port = free_port()
        node = Node(argv_for(port), **popen)
        start = time.monotonic()
        deadline = start + (settle if heard is None else timeout)
        spoke = False
        while node.proc.poll() is None and time.monotonic() < deadline:
            if heard is None:
                time.sleep(min(0.1, max(0.0, deadline - time.monotonic())))
            elif heard(min(0.1, max(0.0, deadline - time.monotonic()))):
                spoke = True
                break
        while heard is None and node.proc.poll() is None and time.monotonic() < start + timeout:
            if not os.path.exists("/proc/net/udp") or udp_rx_queue("127.0.0.1", port) is not None:
                break  # bound to it or to the wildcard (or not to be seen here: not waited for)
            time.sleep(0.05)
        if spoke or (heard is None and node.proc.poll() is None):
            return node, port
        why = node.explain()
        node.stop(kill=True)
        if "exited" not in why or attempt == TRIES:
            said = ("exited before its first datagram" if "exited" in why else
                    "was not running" if heard is None else f"sent nothing within {timeout:g} s")
            raise AssertionError(f"the node on port {port} {said} (start {attempt} of {TRIES}): {why}\n"
                                 f"  {' '.join(argv_for(port))}")
    raise AssertionError("unreachable")


@contextmanager
def attached_node(argv_for: Callable[[int], list[str]], listen: int | None, timeout: float = 60.0,
                  settle: float = 0.0, kill: bool = True, **popen: Any) -> Iterator[tuple[Node, int]]:
    """``start_node`` for a node that sends to ``listen`` (its first datagram read there on a
    socket of ours, closed before the caller binds that port; ``listen`` None: not waited for),
    stopped (killed unless ``kill`` is False) when the block ends."""
    if listen is None:
        node, port = start_node(argv_for, None, settle=settle, **popen)
    else:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind(("127.0.0.1", listen))
            node, port = start_node(argv_for, heard_on(s), timeout, **popen)
    try:
        yield node, port
    finally:
        node.stop(kill=kill)

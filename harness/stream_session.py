"""What the sessions of the protocols the runner reaches over a connection or a link share
(Nsqd's ``harness.nsqd_session``, MAVLink's ``harness.mavlink_session`` and
``harness.mavlink_gcs_session``), beside every session's ``harness.session_base``: the
command their node is spawned with (``--spawn``, or the role's embedded reference node), the
node started on a free loopback port and waited for until it listens (or dies: its exit and
the tail of its output said), and its stop at the end of the run.
"""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Callable

from mcp_conform.harness.errors import SetupError, SpawnFailure
from mcp_conform.harness.session_base import SessionBase, SpawnedNode, fill_placeholders, free_port

__all__ = ["StreamSessionBase", "accepts"]

HOST = "127.0.0.1"


def accepts(address: tuple[str, int], timeout: float = 0.2) -> bool:
    """Whether a TCP connection to ``address`` is accepted within ``timeout`` s (closed at once)."""
    with socket.socket() as s, contextlib.suppress(OSError):
        s.settimeout(timeout)
        s.connect(address)
        return True
    return False


class StreamSessionBase(SessionBase):
    """A session whose node is reached at ``address`` over TCP (or UDP), spawned from
    ``_template`` with ``{target_host}`` ``{target_port}`` (None: attached)."""

    _template: str | None = None
    address: tuple[str, int] = (HOST, 0)

    @property
    def spawn_command(self) -> str | None:
        return self._template

    def spawn_at_free_port(self, kind: int = socket.SOCK_STREAM,
                           before: Callable[[], None] | None = None) -> SpawnedNode:
        """The node spawned on a free loopback port of ``kind`` (its ``address``), ``before``
        called once the port is known and before the process starts (a UDP link opened first)."""
        assert self._template is not None
        port = free_port(HOST, kind)
        self.address = (HOST, port)
        argv = fill_placeholders(self._template, {"target_host": HOST, "target_port": str(port)})
        if before is not None:
            before()
        node = self.node = SpawnedNode(argv)
        return node

    def await_listening(self, connect: Callable[[], bool], within: float, pause: float) -> None:
        """Try ``connect()`` every ``pause`` s until it holds; a spawned node that ended first is
        a ``SpawnFailure`` (its exit, its output's tail), one not listening by ``within`` s a
        ``SetupError``."""
        node = self.node
        assert node is not None
        host, port = self.address
        noun = self.subject.removeprefix("the ")
        deadline = time.monotonic() + within
        while time.monotonic() < deadline:
            if not node.alive():
                raise SpawnFailure(f"the spawned {noun} {node.details()['exit']} before it listened on "
                                   f"{host}:{port}", node.details(20))
            if connect():
                return
            time.sleep(pause)
        raise SetupError(f"the spawned {noun} did not listen on {host}:{port} within {within:g} s")

    def accept_from_node(self, listener: socket.socket, wait: float, url: str) -> socket.socket:
        """The spawned node's connection to ``listener`` (the runner listens at ``url``, as a
        vehicle does), Nagle off, within ``wait`` s; a node that ended first is a
        ``SpawnFailure``, one that did not connect by then a ``SetupError``."""
        node = self.node
        assert node is not None
        listener.settimeout(0.1)
        end = time.monotonic() + wait
        while time.monotonic() < end:
            if not node.alive():
                raise SpawnFailure(f"{self.subject} {self.node_exit()} before it connected to {url}", node.details(20))
            try:
                conn, _ = listener.accept()
            except TimeoutError:
                continue
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            return conn
        raise SetupError(f"{self.subject} did not connect to {url} within {wait:g} s")

    def node_exit(self) -> str:
        """How the spawned node's process ended ("exited with status 1", "killed by SIGSEGV")."""
        return str(self.node.details()["exit"]) if self.node is not None else "ended"

    def close(self) -> None:
        """The spawned node stopped (SIGTERM, SIGKILL soon after: a hung node may ignore SIGTERM)."""
        if self.node is not None:
            self.node.stop(grace=0.5)

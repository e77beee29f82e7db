"""The runner's datagram transport (issue 38, item 2): what ``harness.driver.TargetDriver``
sends and receives through, one seam.

A transport binds an address, sends a datagram to an address (``sendto``: the name a socket
gives it, so a case's side socket and the impaired link take either), and hands the driver's
receiver the next datagram with the kernel's receive time where there is one (``recv``: raises
``TimeoutError`` when nothing came within ``poll`` s, ``OSError`` once closed).

- :class:`UdpTransport` is the runner's UDP socket as it was before the seam: broadcast allowed,
  a large receive buffer, ``SO_TIMESTAMPNS`` where the kernel gives it (``harness.stamps``).
- The simulator's (``mcp_conform.sim.transport``) is the far end of a seeded link to a node
  model, on a virtual clock (``harness.clock``).
"""

from __future__ import annotations

import socket
from typing import Any

from mcp_conform.harness.stamps import kernel_timestamps, recv_stamped

__all__ = ["Transport", "UdpTransport"]

Address = tuple[str, int]


class Transport:
    """The interface (see the module docstring)."""

    #: each datagram ``recv`` returns carries the kernel's receive time
    kernel_times = False
    #: the receiver's longest block in ``recv`` (it looks at its stop flag between)
    poll: float | None = 0.05

    def bind(self, listen: Address) -> Address:
        """Listen on ``listen`` (all addresses when its host is empty); the address bound.
        OSError with a one-line message when it cannot."""
        raise NotImplementedError

    def sendto(self, data: bytes, addr: Address) -> int:
        raise NotImplementedError

    def recv(self) -> tuple[bytes, Any, int | None]:
        raise NotImplementedError

    def getsockname(self) -> Address:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    def side_socket(self, host: str) -> Any:
        """A second endpoint on another source port (MCP-TRN-2, MCP-ROB-7's flood)."""
        raise NotImplementedError


class UdpTransport(Transport):
    """The runner's UDP socket (see the module docstring)."""

    def __init__(self, rcvbuf: int = 8 * 1024 * 1024) -> None:
        self._rcvbuf = rcvbuf
        self.sock: socket.socket | None = None

    def bind(self, listen: Address) -> Address:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self._rcvbuf)
        except OSError:
            pass
        try:
            sock.bind(listen)
        except OSError as exc:
            sock.close()
            host = listen[0] or "*"
            raise OSError(f"cannot listen on {host}:{listen[1]}: {exc.strerror}") from None
        assert self.poll is not None
        sock.settimeout(self.poll)
        self.kernel_times = kernel_timestamps(sock)
        self.sock = sock
        return (listen[0], sock.getsockname()[1])

    def sendto(self, data: bytes, addr: Address) -> int:
        assert self.sock is not None, "transport not bound"
        return self.sock.sendto(data, addr)

    def recv(self) -> tuple[bytes, Any, int | None]:
        if self.sock is None:
            raise OSError("transport closed")
        return recv_stamped(self.sock, self.kernel_times)

    def getsockname(self) -> Address:
        assert self.sock is not None, "transport not bound"
        return self.sock.getsockname()  # type: ignore[no-any-return]

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None

    def side_socket(self, host: str) -> socket.socket:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind((host, 0))
        s.settimeout(0.05)
        return s

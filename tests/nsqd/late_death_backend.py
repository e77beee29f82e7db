"""A backend that dies late (tests/nsqd/test_late_death.py): the reference backend, except that
a body whose number text does not parse (SET_PID with ``kp='x'``, NSQD-MSG-7's input) closes
the connection at once and ends the process with SIGABRT ``--delay`` s later, serving nothing
meanwhile (the listen socket stays open: a new connection waits in the backlog; with
``--close-listener`` it is closed with the connection: a new connection is refused). So dies a
backend whose sockets close before its process is reaped, or one that stalls before it
aborts: the death shows only after the case that killed it has seen the close.

``python -m tests.nsqd.late_death_backend --bind HOST:PORT [--delay S] [--update-period S] [--close-listener]``
"""

from __future__ import annotations

import os
import sys
import time

from mcp_conform.reference_impl.nsqd_backend import BackendCore, BackendServer, Rejected
from tests.nsqd.backend_cli import serve


class LateDeathServer(BackendServer):
    def __init__(self, host: str, port: int, *, delay: float, update_period: float, close_listener: bool) -> None:
        super().__init__(host, port, core=BackendCore(update_period=update_period))
        self.delay, self.close_listener = delay, close_listener

    def _read(self) -> None:
        assert self._client is not None
        try:
            data = self._client.recv(65536)
        except OSError:
            data = b""
        if not data:
            self._drop_client()
            return
        events, out, close = self.core.receive(data, time.monotonic())
        if any(isinstance(e, Rejected) and "is not a decimal number" in e.reason for e in events):
            self._client.close()  # the connection ends now, the process a moment later
            if self.close_listener:  # a new connection is refused meanwhile
                self._lsock.close()
            sys.stderr.write("terminate called after throwing an instance of 'std::invalid_argument'\n")
            sys.stderr.flush()
            time.sleep(self.delay)
            os.abort()
        self._send(out)
        if close:
            self._drop_client()


def main() -> None:
    serve(lambda host, port, ns: LateDeathServer(host, port, delay=ns.delay, update_period=ns.update_period,
                                                 close_listener=ns.close_listener),
          ("--delay", {"type": float, "default": 0.6}), ("--close-listener", {"action": "store_true"}))


if __name__ == "__main__":
    main()

"""A backend that accepts slowly (tests/nsqd/test_con_cycles.py): the reference backend, except
that each accept takes ``--accept-delay`` s (a loaded host's backend, or a slow one: it still
accepts and serves every connection). With ``--stop-after N`` it stops accepting after N
connections: its listen socket stays open, so new connections fill the backlog and then go
unanswered (a backend that stopped accepting).

``python -m tests.nsqd.slow_accept_backend --bind HOST:PORT [--accept-delay S] [--stop-after N] [--update-period S]``
"""

from __future__ import annotations

import time

from mcp_conform.reference_impl.nsqd_backend import BackendCore, BackendServer
from tests.nsqd.backend_cli import serve


class SlowAcceptServer(BackendServer):
    def __init__(self, host: str, port: int, *, accept_delay: float, stop_after: int | None,
                 update_period: float) -> None:
        super().__init__(host, port, core=BackendCore(update_period=update_period))
        self.accept_delay, self.stop_after, self.accepted = accept_delay, stop_after, 0

    def _accept(self) -> None:
        if self.stop_after is not None and self.accepted >= self.stop_after:
            self._sel.unregister(self._lsock)  # never accepts again; the socket stays open
            return
        time.sleep(self.accept_delay)
        self.accepted += 1
        super()._accept()


def main() -> None:
    serve(lambda host, port, ns: SlowAcceptServer(host, port, accept_delay=ns.accept_delay, stop_after=ns.stop_after,
                                                  update_period=ns.update_period),
          ("--accept-delay", {"type": float, "default": 0.0}), ("--stop-after", {"type": int}))


if __name__ == "__main__":
    main()

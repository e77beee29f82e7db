"""A backend that accepts slowly (tests/nsqd/test_con_cycles.py): the reference backend, except
that each accept takes ``--accept-delay`` s (a loaded host's backend, or a slow one: it still
accepts and serves every connection). With ``--stop-after N`` it stops accepting after N
connections: its listen socket stays open, so new connections fill the backlog and then go
unanswered (a backend that stopped accepting).

``python -m tests.nsqd.slow_accept_backend --bind HOST:PORT [--accept-delay S] [--stop-after N] [--update-period S]``
"""

from __future__ import annotations

import argparse
import time

from mcp_conform.reference_impl.nsqd_backend import BackendCore, BackendServer


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
    ap = argparse.ArgumentParser()
    ap.add_argument("--bind", required=True)
    ap.add_argument("--accept-delay", type=float, default=0.0)
    ap.add_argument("--stop-after", type=int)
    ap.add_argument("--update-period", type=float, default=0.05)
    ns = ap.parse_args()
    host, _, port = ns.bind.rpartition(":")
    server = SlowAcceptServer(host, int(port), accept_delay=ns.accept_delay, stop_after=ns.stop_after,
                              update_period=ns.update_period)
    print(f"listening on {host}:{port}", flush=True)
    server.serve()


if __name__ == "__main__":
    main()

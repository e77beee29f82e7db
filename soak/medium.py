"""The mission's radio: one manager and K drones joined through seeded impaired links.

Each node talks to the medium on loopback instead of to its peers: the manager sends to the
medium's front socket, which routes by the MCP header's dst (the broadcast ID and datagrams
without a readable header go to every drone) down each drone's link; drone *i* sends to its
own link socket, and what it sends goes up its link to the manager. Every link direction is
impaired on its own random stream (``harness.impair``: direction ``drone<i>:down`` /
``drone<i>:up`` of one schedule, seeded by the mission's seed), so the same seed and the
same traffic give the same decisions (MCP-DUP-1, MCP-RTX-1 exercised by a bad link).

The medium records each node's own view (``views``): what the node sent as it entered the
link and what the link delivered to it, as the node's own socket saw them — a capture that
is complete for what that node took part in, judged by ``judge.judging`` as a node's own
capture. Drone *i*'s view also holds its link's decisions (``/impair``), and each node's
own datagrams the node's run delay as they came (``run_delays``: MCP-RTX-3 excuses a copy the
loaded host made late, ``judge.spacing``).

Sockets and a delivery queue here; the decisions are ``harness.impair.Impairment``'s. The
queue is ``harness.impair.DelayQueue`` at its default cap (20,000 copies, 16 MiB), as
``mcp-impair``'s: a node flooding a long delay cannot grow the soak without bound; a copy past
it is dropped and recorded in its link's view (``dropped: "queue"``).
"""

from __future__ import annotations

import contextlib
import selectors
import socket
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from mcp_conform.harness.driver import kernel_timestamps, recv_stamped
from mcp_conform.harness.impair import DelayQueue, Impairment
from mcp_conform.harness.run_delay import delay_for
from mcp_conform.spec.codec import BROADCAST_ID, PREAMBLE, Action, peek_header

__all__ = ["Medium"]

Address = tuple[str, int]
MANAGER = "manager"
ACK = int(Action.ACK)


def view_name(drone: int | None) -> str:
    return MANAGER if drone is None else f"drone{drone}"


class Medium:
    """The links of one mission. ``manager_addr`` and ``drone_addrs`` are where the nodes
    listen; ``front`` is where the manager sends, ``links[i]`` where drone *i* sends (and
    the address each hears the other from). ``recorders`` maps ``manager``/``drone<i>`` to a
    recorder (``traceio.recorder.McapRecorder``) of that node's view, or is empty;
    ``run_delays`` maps a view to a callable reading its node's run delay now (ns, or None)."""

    def __init__(self, drones: Sequence[int], impairment: Impairment, manager_addr: Address,
                 drone_addrs: dict[int, Address], recorders: dict[str, Any] | None = None,
                 host: str = "127.0.0.1",
                 run_delays: dict[str, Callable[[], int | None]] | None = None) -> None:
        self.impairment = impairment
        self.run_delays = run_delays or {}
        self.manager_addr = manager_addr
        self.drone_addrs = dict(drone_addrs)
        self.recorders = recorders or {}
        self.sel = selectors.DefaultSelector()
        self._stamped: dict[int, bool] = {}
        self.front = self._socket(host, None)
        self.links = {i: self._socket(host, i) for i in drones}
        self.queue: DelayQueue[tuple[socket.socket, bytes, Address, str, Address]] = DelayQueue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        #: per node view: retransmitted copies it sent, duplicate copies delivered to it
        self.retransmissions: dict[str, int] = {}
        self.duplicates: dict[str, int] = {}
        self._sent: dict[str, set[tuple[int, int, int, int]]] = {}
        self._got: dict[str, set[tuple[int, int]]] = {}

    def _socket(self, host: str, drone: int | None) -> socket.socket:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind((host, 0))
        s.setblocking(False)
        with contextlib.suppress(OSError):
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        # the node's datagrams are recorded at the kernel's receive time, not when this thread
        # got the CPU: on a loaded host the pickup lags and would widen the gaps between a
        # node's copies (a false MCP-RTX-3)
        self._stamped[s.fileno()] = kernel_timestamps(s)
        self.sel.register(s, selectors.EVENT_READ, drone)
        return s

    @property
    def front_addr(self) -> Address:
        return self.front.getsockname()[:2]

    def link_addr(self, drone: int) -> Address:
        return self.links[drone].getsockname()[:2]

    # ------------------------------------------------------------------ accounting
    def _tx(self, view: str, data: bytes, peer: Address, local: Address, t_ns: int | None = None) -> None:
        """What ``view``'s node sent (``t_ns``: when it reached the link, by the kernel's
        clock where it says): a message it sent before is a retransmission."""
        self._account(view, "tx", data, peer, local, lambda h: h, self._sent, self.retransmissions, t_ns,
                      delay_for(data, self.run_delays.get(view)))

    def _rx(self, view: str, data: bytes, peer: Address, local: Address) -> None:
        """What the link gave ``view``'s node: a (src, seq) it got before is a duplicate."""
        self._account(view, "rx", data, peer, local, lambda h: (h[1], h[2]), self._got, self.duplicates)

    def _account(self, view: str, direction: str, data: bytes, peer: Address, local: Address,
                 key: Any, seen_by_view: dict[str, set[Any]], again: dict[str, int],
                 t_ns: int | None = None, run_delay: int | None = None) -> None:
        h = peek_header(data) if data[:len(PREAMBLE)] == PREAMBLE else None
        if h is not None and h[3] != ACK:
            k = key(h)
            seen = seen_by_view.setdefault(view, set())
            if k in seen:
                again[view] = again.get(view, 0) + 1
            seen.add(k)
        rec = self.recorders.get(view)
        if rec is not None:
            if run_delay is None:
                rec.datagram(direction, data, peer, t_ns, local=local)
            else:
                rec.datagram(direction, data, peer, t_ns, local=local, run_delay=run_delay)

    # ------------------------------------------------------------------ the links
    def _impair(self, drone: int, way: str, data: bytes, out: socket.socket, dst: Address,
                view: str, now: float) -> None:
        decision = self.impairment.decide(f"drone{drone}:{way}", data, now)
        src = out.getsockname()[:2]
        kept = tuple(d for d in decision.deliveries
                     if self.queue.push(now + d.delay_s, len(d.data), (out, d.data, dst, view, src)))
        decision = self.impairment.refused(decision, kept)
        rec = self.recorders.get(view_name(drone))
        if rec is not None:
            rec.impairment(decision, data)

    def _read(self, sock: socket.socket, drone: int | None, now: float) -> None:
        for _ in range(64):
            try:
                data, _addr, arrived = recv_stamped(sock, self._stamped.get(sock.fileno(), False))
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            if drone is None:  # the manager's: down the link of the drone it is addressed to
                self._tx(MANAGER, data, self.front_addr, self.manager_addr, arrived)
                h = peek_header(data) if data[:len(PREAMBLE)] == PREAMBLE else None
                dst = h[0] if h is not None else BROADCAST_ID
                for i in ([dst] if dst in self.links else list(self.links)):
                    self._impair(i, "down", data, self.links[i], self.drone_addrs[i], view_name(i), now)
            else:  # drone i's: up its link to the manager, from the link's address
                self._tx(view_name(drone), data, self.link_addr(drone), self.drone_addrs[drone], arrived)
                self._impair(drone, "up", data, sock, self.manager_addr, MANAGER, now)

    def _deliver(self, now: float) -> None:
        for sock, data, dst, view, src in self.queue.pop_due(now):
            self._rx(view, data, src, dst)
            with contextlib.suppress(OSError):
                sock.sendto(data, dst)

    def serve(self) -> None:
        """Route and impair until :meth:`stop` (run in a thread by :meth:`start`)."""
        while not self._stop.is_set():
            now = time.monotonic()
            self._deliver(now)
            due = self.queue.next_due()
            wait = 0.05 if due is None else max(0.0, min(0.05, due - now))
            for key, _ in self.sel.select(wait):
                self._read(key.fileobj, key.data, time.monotonic())  # type: ignore[arg-type]
            self._deliver(time.monotonic())

    def start(self) -> None:
        self._thread = threading.Thread(target=self.serve, name="mcp-soak-medium", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        for s in [self.front, *self.links.values()]:
            with contextlib.suppress(Exception):
                self.sel.unregister(s)
            s.close()
        self.sel.close()

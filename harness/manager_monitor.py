"""The trace monitor over a manager-role mission (``judge.monitor``).

The runner's socket sees every datagram of the mission — the manager's, and the drones'
(the runner's own, fed as ``TESTER`` input, never blamed) — so the trace is complete. The
monitor judges the manager's traffic passively while the cases drive it; the cases keep
their own verify helpers for what they provoke on purpose (docs/design.md, "The trace monitor").
"""

from __future__ import annotations

from collections.abc import Sequence

from mcp_conform.harness.driver import Sent
from mcp_conform.harness.drone_players import MANAGER_ID, Mission
from mcp_conform.judge.monitor import TESTER, Monitor, Violation

__all__ = ["monitor_mission"]


def monitor_mission(m: Mission, sent: Sequence[Sent], listen: tuple[str, int], *, rto: float,
                    ack_window: float, broadcast_id: int) -> tuple[list[Violation], dict[str, str], list[str]]:
    """Feed the mission to a fresh monitor: the manager's violations, its verdicts, and the
    trace as fed (one line per datagram, for the evidence's indexes)."""
    items = m.obstacles if m.challenge == 3 else m.waypoints
    mon = Monitor(rto=rto, ack_window=ack_window, broadcast_id=broadcast_id, drones=m.drones,
                  challenge=m.challenge, waypoints=items, complete=True)
    t0_ns = m.rx[0].t_ns if m.rx else 0
    # a fresh manager may not be listening yet: the copies of the first Mission_Ready sent
    # before its first datagram went unheard, all but the last
    first = next(iter(m.ready.values()), None)
    unheard = set()
    if first is not None and m.rx:
        unheard = {id(c) for c in first.copies[:-1] if c.t < m.rx[0].t}
    trace: list[tuple[int, int, object]] = [(d.t_ns, 0, d) for d in m.rx]
    trace += [(s.t_ns, 1, s) for s in sent if m.t0 <= s.t <= m.t_end and id(s) not in unheard]
    trace.sort(key=lambda e: (e[0], e[1]))
    out: list[Violation] = []
    lines = []
    for t_ns, kind, x in trace:
        lines.append(("manager: " + x.describe()) if kind == 0 else  # type: ignore[attr-defined]
                     f"drone {x.src}: {x.data[:24].hex(' ')} ({len(x.data)} B)")  # type: ignore[attr-defined]
        if kind == 0:
            out += mon.datagram(t_ns, x.addr, listen, x.data, origin=MANAGER_ID)  # type: ignore[attr-defined]
        else:
            out += mon.datagram(t_ns, listen, x.addr, x.data, origin=TESTER)  # type: ignore[attr-defined]
    end_ns = max([t for t, _, _ in trace] + [t0_ns])
    out += mon.finish(end_ns)
    return [v for v in out if v.node == MANAGER_ID], mon.verdicts().get(MANAGER_ID, {}), lines

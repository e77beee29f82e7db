"""A drone under test that gives up its Mission_Ready short of ``min_copies`` and exits: MCP-RTX-1 observed.

The startup phase (``harness.drone_session``) withholds the ACK of the node's Mission_Ready for
``min_copies`` copies. A node whose retry limit is below the least the rule allows (spec/mcp.yaml's
``min_copies``: MCP-RTX-1 "Observed: at least 3 copies while the ACK is withheld"), and which exits
when it gives up (the C++ drone's ``--retries 1``: exit 1), sends fewer and is gone before
Start_Mission. That is MCP-RTX-1's violation, observed: a setup error ("the node exited before
Start_Mission was sent") hid it.

Spawn mode: :func:`gave_up` tells that exit from others -- a crash (a signal, a sanitizer's
report) or an exit right after a copy (a node crashing as it sends, a launcher whose process ends
as its child speaks) keep the setup error: it holds only for a process that exited by itself at
its retry timer's time, about a period after its last copy (seen running half a period after it,
gone by one and a half). One that exits later may have sent a copy a lossy network dropped (a
limit of 2, allowed, its third copy lost): a setup error as before. (A first copy lost on the way
cannot be told from a lower limit: the runner takes its link for clean unless ``--impair`` says
otherwise, and then a startup the link touched skips the case, ``conformance._impaired``.) Then
:func:`restart_quick` keeps the observation (the copies, the exit: ``WithheldCopies.gave_up``) and
restarts the node with its Mission_Ready ACKed at once, as a restart's quick startup does; the
cases run on it. No wrong ACK and no watch went to the node gone, only the right ACK: the trace
(the run monitor, ``mcp-capture check``) then shows the message answered before the new
instance's Mission_Ready, not renumbered (MCP-SEQ-2). MCP-RTX-2 is skipped ("see MCP-RTX-1"),
MCP-RTX-3 judges what copies there are.

A restarted node that again sends no Mission_Ready is a setup error (exit 2) whose line names the
first instance's MCP-RTX-1 observation: the cases never ran, and a run judged on one startup
case would read as a node judged; the line keeps the finding. Attach mode has no process to see
exit: its copies are judged as they are (MCP-RTX-1 failed; the cases after it lose the node).
"""

from __future__ import annotations

from typing import Any

from mcp_conform.harness.driver import Datagram
from mcp_conform.harness.drone_rtx2 import respawn_until_ready
from mcp_conform.harness.liveness import describe_exit
from mcp_conform.harness.session_base import MIN_COPIES, WithheldCopies, death_of
from mcp_conform.spec.codec import Action

_READY = int(Action.MISSION_READY)
#: how often the startup looks whether the node still runs while it awaits its copies (s)
POLL_S = 0.05


def gave_up(session: Any, st: WithheldCopies, seen_alive: float | None, seen_gone: float | None) -> str | None:
    """Why the spawned node's copies in ``st`` ended short of ``MIN_COPIES``: it exited by itself
    (a code, no signal, no sanitizer report) at its retry timer's time after its last copy -- a
    period ``T`` later (its copies' own, else --rto): still running at ``seen_alive``, at least
    ``T / 2`` after it, and gone at ``seen_gone`` (the clock's ``monotonic()``), at most ``1.5 T``
    and a poll (``POLL_S``) after it. None when that is not what the runner saw: it runs, it
    crashed, it ended as it sent, or it ended a period or more later than its last copy's timer
    (a copy after it may have been lost on the way: a limit of 2, allowed, whose third copy a lossy
    network dropped exits two periods after the second that came). ``session``: a
    ``harness.drone_session.Session``."""
    node, copies = session.node, st.copies
    if (not session.spawned or node is None or node.alive() or not copies or len(copies) >= MIN_COPIES
            or seen_alive is None or seen_gone is None):
        return None
    death = death_of(node)
    if death.code is None or death.signal_name is not None or death.sanitizer is not None:
        return None
    after, period = seen_alive - copies[-1].t, st.period() or session.rto
    if after < 0.5 * period or seen_gone - copies[-1].t > 1.5 * period + POLL_S:
        return None
    n = len(copies)
    return (f"it stopped after {n} cop{'y' if n == 1 else 'ies'} of its Mission_Ready without the ACK, "
            f"then {describe_exit(death.code)} (still running {after:.2f} s after its last copy)")


def others_while_waiting(session: Any, first: int, end: int | None) -> list[Datagram]:
    """MCP-BLK-1: the node's new unicast messages (not ACKs, not Mission_Ready copies) that reached
    the runner from mark ``first`` to mark ``end`` (None: up to now), while Mission_Ready awaited its ACK."""
    drv = session.driver
    return [d for d in drv.received(first, end) if d.header is not None
            and d.action not in (_READY, int(Action.ACK)) and d.header[0] != session.cfg.broadcast_id]


def restart_quick(session: Any, st: WithheldCopies) -> None:
    """The node, gone after ``st.gave_up``, restarted with its Mission_Ready ACKed at once (the
    driver ACKs it as it comes); the run goes on with the new instance. ``st`` is kept as the
    session's startup (what a setup error from here on explains with). No Mission_Ready from the
    new instance: a setup error naming MCP-RTX-1's observation (module docstring)."""
    drv = session.driver
    assert drv is not None
    period = session.period
    session.startup = st
    drv.auto_ack = lambda d: True  # from its first copy on: a quick startup's
    respawn_until_ready(session, f"the node {{how}} on its restart after MCP-RTX-1's observation ({st.gave_up})",
                        exited="exited before sending Mission_Ready")
    session.period = period

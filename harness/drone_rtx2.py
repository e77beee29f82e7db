"""MCP-RTX-2's second observation of a drone under test, when the startup's first cannot tell.

The startup phase (``harness.drone_session``) withholds the ACK of the node's Mission_Ready for
``min_copies`` copies, then sends the wrong ACKs (the wrong seq; the right seq from another
source) and awaits another copy. A node whose copies stop there may have taken a wrong ACK
(MCP-RTX-2's fault) or reached a retry limit of ``min_copies - 1`` -- the rule's configurable
limit, no violation (spec/mcp.yaml's ``min_copies``; MCP-RTX-1 "until it is ACKed or its retry
limit is reached"): one observation cannot tell them apart (``WithheldCopies.limit_or_any_ack``;
the C drone's ``--retries 2`` failed MCP-RTX-2 so).

In spawn mode the runner then restarts the node and, on the new instance's Mission_Ready, sends
the wrong ACKs after its second copy and awaits a third: the first instance's copies proved
the limit reaches that copy, so a node that keeps MCP-RTX-2 owes it, and a node that stops on
any ACK does not send it. Then the copy is ACKed right and the run goes on with that instance.
Attach mode cannot restart the node: the case is skipped, naming why. A node whose copies go
on past the wrong ACKs (the common correct node) gets no second observation.
"""

from __future__ import annotations

from typing import Any

from mcp_conform.harness.driver import TargetDriver
from mcp_conform.harness.procs import SPAWN_STARTUP_S
from mcp_conform.harness.session_base import WithheldCopies
from mcp_conform.spec.codec import Action

_READY = int(Action.MISSION_READY)

#: the observed startup's part the second observation repeats (``drone_session.STARTUP_PARTS``):
#: two copies, then the wrong ACKs, a copy awaited, the right ACK
WRONG = frozenset({"wrong"})


def ready_before_wrong_acks(driver: TargetDriver, st: WithheldCopies) -> list[float]:
    """When the node's Mission_Ready copies of ``st`` reached the runner, up to its first
    wrong ACK (all of them when none was sent)."""
    if not st.copies:
        return []
    end = st.wrong_acks[0].t if st.wrong_acks else float("inf")
    return [d.t for d in driver.received(st.copies[0].index) if d.action == _READY and d.t <= end]


def needs_second_look(session: Any, st: WithheldCopies) -> bool:
    """Spawn mode, and the first observation could not tell a retry limit from MCP-RTX-2's
    fault (``WithheldCopies.limit_or_any_ack``); ``session``: a ``harness.drone_session.Session``."""
    drv = session.driver
    return session.spawned and drv is not None and st.limit_or_any_ack(ready_before_wrong_acks(drv, st))


def observe_again(session: Any, st: Any) -> None:
    """The node restarted and its Mission_Ready observed with the wrong ACKs after its second
    copy (``WRONG``), kept as ``st.again`` (``st`` the session's ``Startup``); the run goes on
    with the new instance (its Mission_Ready ACKed right). The node's period stays the first
    observation's."""
    drv = session.driver
    assert drv is not None
    period = session.period
    ready = respawn_until_ready(session, "the node, restarted to tell its retry limit from MCP-RTX-2's fault, {how}")
    again = type(st)(vehicle=session.vehicle is not None)
    session._observe_retransmissions(again, ready, WRONG)
    session.period = period
    st.again = again


def respawn_until_ready(session: Any, failure: str, exited: str = "exited") -> Any:
    """The node restarted (``session.respawn``, the vehicle's fix given) and its first Mission_Ready
    awaited, counted from the new instance's start (``spawn_mark``, taken once the old one was
    stopped: a late copy of the old one's is not the new one's); none: the session's setup error,
    ``failure`` with ``{how}`` filled in (``exited``, or it sent none in time)."""
    drv = session.driver
    session.respawn()
    mark = session.spawn_mark if session.spawn_mark is not None else drv.mark()
    if session.vehicle is not None:
        session.vehicle.give_fix()
    wait = max(SPAWN_STARTUP_S, 4 * session.rto + 5.0)
    ready = drv.wait_for(lambda d: d.action == _READY, wait, mark)
    if ready is None:
        how = exited if not session.alive() else f"sent no Mission_Ready within {wait:g} s"
        raise session._fail_setup(failure.format(how=how))
    return ready

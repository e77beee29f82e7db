"""Whether a copy the runner received after its wrong ACKs proves that the node went on
retransmitting (MCP-RTX-2) through ``--impair`` (issue 38).

On an impaired link a pass needs more than "a copy came after the wrong ACKs": the node
must have *had* both wrong ACKs when it sent that copy, and the copy must be one the node
sent, not one the link held or duplicated (``harness.impair_link``: the runner's own link
keeps every decision it made, with the datagram's time and each delivery's delay). Seeded
``--impair loss=0.1,dup=0.05,reorder=0.1,seed=11`` dropped both wrong ACKs of the startup,
so a node that stops on *any* ACK kept retransmitting and passed; without the impairment it
fails. A copy is credited only when:

- every datagram the runner sent from the first wrong ACK up to the copy (the wrong ACKs
  themselves) reached the node, uncorrupted, at least ``MARGIN_S`` before the copy came; and
- no copy the link delayed or duplicated landed within ``MARGIN_S`` of it (the same bytes:
  the runner cannot tell the node's copy from the link's, so the link's is assumed).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["MARGIN_S", "credited_copy"]

#: how far apart two instants must be to be told apart on the runner's clock (the kernel's
#: receive stamp against the link's decision time, the loopback's latency)
MARGIN_S = 0.003

_LOST_ON_THE_WAY = ("corrupt", "cut")  # a copy the UDP checksum discards: never received


def _events(link: Any) -> list[Any]:
    return list(link.events) if link is not None else []


def _why_not(events: Sequence[Any], since: float, copy: Any) -> str | None:
    """Why ``copy`` (a ``harness.driver.Datagram``) does not prove a retransmission after
    the datagrams the runner sent from ``since`` on, or None when it does."""
    for ev in events:
        d = ev.decision
        if d.direction == "tx":
            if not since <= ev.t <= copy.t:
                continue
            landed = [ev.t + x.delay_s for x in d.deliveries
                      if not any(k in _LOST_ON_THE_WAY for k in x.kinds)]
            if not landed:
                return f"{ev.describe()}: the node never got it"
            if min(landed) + MARGIN_S > copy.t:
                return f"{ev.describe()}: it reached the node {min(landed) - since:.3f} s after the first " \
                       f"wrong ACK left, not before the copy came ({copy.t - since:.3f} s)"
        else:
            for x in d.deliveries:
                if x.delay_s > 0 and abs(ev.t + x.delay_s - copy.t) <= MARGIN_S:
                    return f"{ev.describe()}: the copy may be the link's, held {x.delay_s * 1000:.1f} ms"
    return None


def credited_copy(link: Any, wrong_acks: Sequence[Any], copies: Sequence[Any]) -> tuple[Any, list[str]]:
    """The first of ``copies`` (received after the wrong ACKs, in order) that proves the node
    retransmitted after it had both ``wrong_acks`` (``harness.driver.Sent``), and why each
    copy before it does not (``link``: the runner's ``ImpairedLink``, None on a clean link,
    where the first copy is credited)."""
    if not copies or not wrong_acks:
        return (copies[0] if copies else None), []
    events = _events(link)
    since = wrong_acks[0].t
    why: list[str] = []
    for copy in copies:
        reason = _why_not(events, since, copy)
        if reason is None:
            return copy, why
        why.append(f"the copy {copy.t - since:.3f} s after the first wrong ACK: {reason}")
    return None, why

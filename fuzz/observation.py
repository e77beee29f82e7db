"""How the fuzzer observes MCP-ACK-1 before it judges a missing ACK: as the rule says.

MCP-ACK-1 (spec/mcp.yaml): "Observed: each command sent between the node's Mission_Ready and
its End_Mission is ACKed, the runner retransmitting it every --rto as a manager would, up to
5 copies (a node may be deaf while busy, D-6; latency is MCP-ACK-7's business)". D-6: "'a
reply' is awaited across the runner's own retransmissions (MCP-ACK-1)".

A batch's input left without an ACK is one copy seen unanswered; the kernel drops what
overflows a node's receive buffer, and a plain single-threaded node deaf while it reads a
burst loses whole datagrams (issue 36: a false MUST finding on a correct node with the
system's default 212,992-byte buffer, after a 172 KB burst). So before an input's missing
ACK stands, the input is retransmitted — the same bytes, a copy the node ACKs again and does
not deliver again (MCP-ACK-1, MCP-DUP-1) — every --rto, through the runner's own exchange
(``harness.driver.TargetDriver.exchange``, the helper the conformance cases observe ACK-1
with), up to the rule's count of copies in all, the last one watched for the ACK window
(D-6). Only an input no copy of which was answered is a finding.

The cost falls on the unanswered only: a healthy node ACKs every input of a batch and pays
nothing; a dropped one costs one round trip; a node that really does not ACK costs the
rule's copies once per exchange (the first such input is the finding, the others of the
exchange are not observed and not reported: triage takes one flaw per rule and batch).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mcp_conform.harness.driver import Exchange
from mcp_conform.spec import SPEC

__all__ = ["MAX_ACK_COPIES", "Retransmitted", "retransmit_unanswered"]

#: Copies of a command in all, the unanswered original included (MCP-ACK-1, max_ack_copies)
MAX_ACK_COPIES = int(SPEC.params["max_ack_copies"])


@dataclass(frozen=True)
class Retransmitted:
    """What the retransmissions of one unanswered input showed."""

    acked: bool
    copies: int  # copies sent in all, the original included
    spacing: float  # s between copies (--rto)
    window: float  # s the last copy was watched
    exchange: Exchange

    def describe(self) -> str:
        if self.acked:
            return f"ACKed on copy {self.copies} of {MAX_ACK_COPIES} (every {self.spacing:g} s)"
        return (f"{self.copies} copies every {self.spacing:g} s, the last watched {self.window:g} s: "
                "none ACKed (MCP-ACK-1's observation)")


def retransmit_unanswered(target: Any, data: bytes, copies: int = MAX_ACK_COPIES) -> Retransmitted:
    """Retransmit ``data`` (whose first copy went unanswered) every --rto as a manager would,
    until a reply is attributed to it or ``copies`` copies in all were sent; the last one is
    watched for the ACK window (D-6)."""
    drv = target.driver
    rto = target.rto
    tail = target.ack_window
    first = drv.send_raw(data)
    ex = drv.exchange(first, rto=rto, copies=max(1, copies - 1), tail=tail)
    return Retransmitted(ex.acked, 1 + len(ex.copies), rto, max(rto, tail), ex)

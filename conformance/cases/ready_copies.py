"""The startup's Mission_Ready copies counted by number, for the RTX and SEQ cases: the startup's
view of ``judge.copies_by_number`` (one judge with the manager role's cases, the fuzzer's
withheld-ACK oracle and the trace monitor).

"Retransmissions of the same message are identified by repeating sequence number": the copies of
the node's first Mission_Ready are the datagrams that repeat its number. A node that gave its
message up (its retry limit) and announced again under the next number sent a new message, not
a third copy: the Node.js drone's ``--retries 1 --reannounce`` (two copies of seq N, then seq
N+1) passed MCP-RTX-1 on three "copies" and failed MCP-SEQ-2 ("1 of 2 copies differ"), where the
texts make it MCP-RTX-1's fault (two copies while the ACK was withheld) and keep MCP-SEQ-2 (every
copy of N repeats its number and bytes).

A node never seen to repeat its first number, that sends the same message again under a new
one while the first is unACKed (the ``rtx-new-seq`` fault: one copy of each number), has
renumbered its retransmissions (MCP-SEQ-2), as the trace monitor judges it
(``judge._monitor_rtx``'s ``_renumbered``): its copies count for no rule that counts copies of
one message (MCP-RTX-1, MCP-RTX-3), which then does not pass on them.
"""

from __future__ import annotations

from typing import Any

from mcp_conform.judge import copies_by_number as _by


def by_number(st: Any) -> list[Any]:
    """The startup's copies of its first Mission_Ready: those that repeat its number (all of
    them when headers cannot be read)."""
    return _by.by_number(st.copies)


def new_numbers(st: Any) -> list[Any]:
    """The Mission_Ready datagrams the startup read under another number than its first's."""
    return _by.new_numbers(st.copies)


def renumbered(st: Any) -> bool:
    """The first Mission_Ready sent once under its number, then again -- the same bytes past the
    header -- under a new number while its ACK was withheld: a retransmission renumbered
    (MCP-SEQ-2), not a new message after a give-up (which follows copies that repeat it)."""
    return _by.renumbered(st.copies)


def describe_new(st: Any, limit: int = 3) -> str:
    """The numbers the startup's other Mission_Ready datagrams took, for a case's verdict."""
    return _by.describe_new(st.copies, limit)

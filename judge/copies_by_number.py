"""A withheld message's copies counted by number: one judge for the drone suite's startup, the
manager suite's withheld Start_Mission and the fuzzer's withheld Mission_Ready (MCP-RTX-1,
MCP-RTX-3, MCP-SEQ-2), as the trace monitor counts them (``judge._monitor_rtx``'s
``_renumbered``).

"Retransmissions of the same message are identified by repeating sequence number": the copies
of a sender's first message, its ACK withheld, are the datagrams that repeat its number. A
sender that gave the message up (its retry limit) and sent the same again under the next
number sent a new message, not a third copy: two copies of seq N then seq N+1 are MCP-RTX-1's
fault (two copies while the ACK was withheld), and every copy of N repeats its number and
bytes (MCP-SEQ-2 kept) -- the Node.js drone's ``--retries 1 --reannounce``.

A sender never seen to repeat its first number, that sends the same message again -- the same
bytes past the header -- under a new one while the first is unACKed (the ``rtx-new-seq``
fault: one copy of each number), has renumbered its retransmissions (MCP-SEQ-2): its copies
count for no rule that counts copies of one message (MCP-RTX-1, MCP-RTX-3).

Sans-I/O: the functions read a datagram's ``header`` (``(dst, src, seq, action)`` or None
where unreadable) and ``data``, as ``harness.driver.Datagram`` carries them.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, TypeVar

from mcp_conform.spec.codec import HEADER_SIZE

__all__ = ["by_number", "describe_new", "new_numbers", "renumbered"]


class Copy(Protocol):
    @property
    def header(self) -> tuple[int, int, int, int] | None: ...

    @property
    def data(self) -> bytes: ...


D = TypeVar("D", bound=Copy)


def _seq(d: Copy) -> int | None:
    return d.header[2] if d.header is not None else None


def by_number(copies: Sequence[D]) -> list[D]:
    """The copies of the first message: those that repeat its number (all of them when headers
    cannot be read)."""
    if not copies:
        return []
    seq = _seq(copies[0])
    return [d for d in copies if _seq(d) == seq]


def new_numbers(copies: Sequence[D]) -> list[D]:
    """The datagrams under another number than the first's."""
    seq = _seq(copies[0]) if copies else None
    return [d for d in copies if _seq(d) != seq]


def renumbered(copies: Sequence[Copy]) -> bool:
    """The first message sent once under its number, then again -- the same bytes past the header
    -- under new numbers while its ACK was withheld: a retransmission renumbered (MCP-SEQ-2),
    not a new message after a give-up (which follows copies that repeat it)."""
    same, other = by_number(copies), new_numbers(copies)
    return (len(same) == 1 and bool(other)
            and all(d.data[HEADER_SIZE:] == same[0].data[HEADER_SIZE:] for d in other))


def describe_new(copies: Sequence[Copy], limit: int = 3) -> str:
    """The numbers the other datagrams took, for a verdict."""
    seqs = [_seq(d) for d in new_numbers(copies)]
    more = f", ... ({len(seqs)} in all)" if len(seqs) > limit else ""
    return ", ".join(f"seq {s}" for s in seqs[:limit]) + more

"""The model of :mod:`judge.explain` built from the datagrams a monitor sees (issue 38, item 1:
the same algorithm for cases, the live monitor, ``mcp-capture check`` and the fuzzer).

Input: datagrams in capture order, anything with ``t_ns`` and ``data`` (a
``traceio.reader.Datagram``, a ``tests.judge.monitor_scripts.Record``); the MCP header names
each one's sender and destination, so addresses are not needed. Output: one
:class:`judge.explain.Trace` per direction ``(S, R)`` of unicast seen:

- a copy: a well-formed unicast message other than an ACK from ``S`` to ``R`` (MCP-ACK-1);
  copies of one message share its sequence number and bytes. Judged for MCP-ACK-1 while ``R``
  receives (D-6): a node that sent a Mission_Ready is a drone, receiving from its first
  Mission_Ready until its ACK of an End_Mission; any other node always;
- not to be ACKed (:attr:`Copy.ackable` false), in the model because an ACK may name it: an
  ACK from ``S`` to ``R`` (its number, D-5: MCP-ACK-6), a broadcast from ``S`` (MCP-ACK-4),
  a datagram from ``S`` to ``R`` whose payload or preamble is malformed (MCP-ROB-2..4);
- an ACK to ``S``: from ``R`` or any other node (MCP-RTX-2's "from the message's
  destination"), naming the 2-byte payload's number, or None for a payload of another size;
  and ``R``'s ACKs to other nodes (:attr:`Ack.dst`: it may have answered ``S``'s copy to the
  wrong ID, MCP-ACK-3).
- ``S``'s run delay (D-7, :attr:`Trace.run_delay`): read off each datagram ``S`` sent that
  carries one (a ``run_delay`` in ns, ``harness.run_delay``), and from ``samples``, read
  without a datagram (at its view's end, as the runner stopped it).

Sans-I/O like :mod:`judge.explain`; imports ``spec`` only.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from mcp_conform.judge.explain import (
    Ack,
    Bounds,
    Copy,
    Trace,
    Verdict,
    decide_receiver,
    decide_sender,
)
from mcp_conform.spec.codec import (
    BROADCAST_ID,
    HEADER_SIZE,
    PREAMBLE,
    Action,
    DecodeError,
    decode,
    peek_header,
)

__all__ = ["node_verdicts", "traces_from_datagrams"]

NS = 1e9
SAME_MESSAGE_S = 60.0  # a copy this long after the last with its number is a new message


@dataclass
class _Direction:
    copies: list[Copy] = field(default_factory=list)


def _ack_named(data: bytes) -> int | None:
    """The number an ACK's payload names, None unless it is 2 bytes (MCP-ACK-2, D-2)."""
    payload = data[HEADER_SIZE:]
    return int.from_bytes(payload, "big") if len(payload) == 2 else None


def traces_from_datagrams(datagrams: Iterable[Any], *, complete: bool = True,
                          broadcast_id: int = BROADCAST_ID,
                          tester: Callable[[Any], bool] | None = None,
                          samples: Mapping[int, Iterable[tuple[int, int]]] | None = None
                          ) -> dict[tuple[int, int], Trace]:
    """Each direction's trace (see the module docstring); times in seconds from the first
    datagram. Datagrams without a whole header are left out (nothing to attribute).
    ``tester(datagram)`` says the runner sent it (in its own name or a node's): what its
    sender did with it is not judged (:attr:`Copy.own`). ``samples``: per node ID, its run
    delay read without a datagram, ``(t_ns, ns)``."""
    # one number per message, trace-wide: a sender's numbers do not repeat within a window,
    # so copies with its number are copies of it (MCP-SEQ-2 judges whether their bytes agree)
    msgs: dict[tuple[int, int, int], tuple[int, float]] = {}
    n_msgs = 0
    dirs: dict[tuple[int, int], _Direction] = {}
    broadcasts: dict[int, list[Copy]] = {}
    acks_to: dict[int, list[Ack]] = {}  # every ACK to a node, from whichever node
    acks_from: dict[int, list[Ack]] = {}  # every ACK from a node, with its dst
    ready_at: dict[int, float] = {}  # a drone's first Mission_Ready
    end_seqs: dict[tuple[int, int], set[int]] = {}  # End_Mission numbers S sent R
    deaf_at: dict[tuple[int, int], float] = {}  # R's ACK of S's End_Mission
    t0: float | None = None
    last = 0.0
    raw: list[tuple[float, int, int, int, int, bytes, bool, bool]] = []
    readings: dict[int, list[tuple[float, float]]] = {}  # per sender, its run delay (s)
    for d in datagrams:
        data = bytes(d.data)
        head = peek_header(data, require_preamble=False)
        if head is None:
            continue
        t0 = d.t_ns if t0 is None else t0
        t = (d.t_ns - t0) / NS
        last = max(last, t)
        dst, src, seq, action = head
        try:
            decode(data)
            ok = True
        except DecodeError:
            ok = False
        own = tester is None or not tester(d)
        raw.append((t, dst, src, seq, action, data, ok, own))
        rd = getattr(d, "run_delay", None)
        if rd is not None and own:
            readings.setdefault(src, []).append((t, rd / NS))
        if ok and action == Action.MISSION_READY:
            ready_at.setdefault(src, t)
        if ok and action == Action.END_MISSION:
            end_seqs.setdefault((src, dst), set()).add(seq)
        if ok and action == Action.ACK:
            named = _ack_named(data)
            if named in end_seqs.get((dst, src), ()):
                deaf_at.setdefault((dst, src), t)
    latest: dict[tuple[int, int], tuple[int, bytes]] = {}  # (src, dst) -> its latest message
    for t, dst, src, seq, action, data, ok, own in raw:
        if dst == broadcast_id:
            broadcasts.setdefault(src, []).append(Copy(seq, -1, t, ackable=False, judged=False))
            continue
        if action == Action.ACK and data.startswith(PREAMBLE):  # its payload may be malformed
            named = _ack_named(data)
            acks_to.setdefault(dst, []).append(Ack(t, named, src))
            acks_from.setdefault(src, []).append(Ack(t, named, src, dst))
            # and a datagram R may wrongly ACK in turn, by its number (D-5, MCP-ACK-6)
            dirs.setdefault((src, dst), _Direction()).copies.append(
                Copy(seq, -1, t, ackable=False, judged=False))
            continue
        way = dirs.setdefault((src, dst), _Direction())
        if not ok:
            way.copies.append(Copy(seq, -1, t, ackable=False, judged=False))
            continue
        key = (src, dst, seq)
        known = msgs.get(key)
        if known is None or (t - known[1] > SAME_MESSAGE_S and (
                latest.get((src, dst)) != (seq, data))):
            # new, or the number came round -- not a copy of the sender's latest message to
            # that receiver, same number and bytes, however late (MCP-DUP-1; the monitor's
            # ``_late_copy``): a lossy link held a no-ack drone's fifth copy of Start_Mission
            # 60.02 s after its fourth, and taken for a new message it hid MCP-ACK-1
            known = (n_msgs, t)
            n_msgs += 1
        msg = known[0]
        msgs[key] = (msg, t)
        latest[(src, dst)] = (seq, data)
        receiving = (dst not in ready_at or ready_at[dst] <= t) and t <= deaf_at.get(
            (src, dst), float("inf"))
        way.copies.append(Copy(seq, msg, t, judged=receiving, own=own))
    for node, extra in (samples or {}).items():
        readings.setdefault(node, []).extend(((t_ns - (t0 or 0)) / NS, rd / NS) for t_ns, rd in extra)
    for got in readings.values():
        got.sort()
    out = {}
    for (s, r), way in dirs.items():
        if not any(c.ackable for c in way.copies):
            continue  # ACKs only: nothing S sent R to explain them by
        elsewhere = [c for (s2, r2), w in dirs.items() if s2 == s and r2 != r
                     for c in w.copies if c.ackable]
        out[(s, r)] = Trace(sorted(way.copies + broadcasts.get(s, []), key=lambda c: c.t),
                            sorted(acks_to.get(s, []) + [a for a in acks_from.get(r, [])
                                                         if a.dst != s], key=lambda a: a.t),
                            last, s, r, complete, sorted(elsewhere, key=lambda c: c.t),
                            tuple(readings.get(s, ())))
    return out


def node_verdicts(traces: dict[tuple[int, int], Trace], bounds: Bounds,
                  nodes: Iterable[int] | None = None) -> dict[int, dict[str, Verdict]]:
    """Each node's verdicts (of ``nodes`` only, when given: not the runner's, whose faults
    are on purpose) over every direction it took part in: MCP-ACK-1/2 as a receiver,
    MCP-RTX-1/2 as a sender; a rule is proven where one direction proves it, consistent where
    one keeps it and none proves it."""
    judged = None if nodes is None else set(nodes)
    rank = {"proven": 2, "consistent": 1, "unobservable": 0}
    out: dict[int, dict[str, Verdict]] = {}
    for (s, r), trace in sorted(traces.items()):
        for node, decide in ((r, decide_receiver), (s, decide_sender)):
            if judged is not None and node not in judged:
                continue
            found = decide(trace, bounds)
            mine = out.setdefault(node, {})
            for rule, v in found.items():
                old = mine.get(rule)
                if old is None or rank[v.status] > rank[old.status]:
                    mine[rule] = v
    return out

"""Receiver-side rules of :mod:`judge.explain`: MCP-ACK-1 and MCP-ACK-2 of ``R``, decided over
every assignment of ``R``'s ACKs to what ``S`` sent it."""

from __future__ import annotations

from mcp_conform.judge.explain_ack1 import ack1
from mcp_conform.judge.explain_model import (
    CONSISTENT,
    EITHER_ACK,
    PROVEN,
    UNOBSERVABLE,
    Bounds,
    Trace,
    Verdict,
    _answers,
    _explain,
    _fmt_ack,
    _fmt_copy,
    _hall,
    _match,
    _some,
)

# ------------------------------------------------------------------ receiver: ACK-1, ACK-2


def decide_receiver(trace: Trace, b: Bounds) -> dict[str, Verdict]:
    """MCP-ACK-1 and MCP-ACK-2 of the receiver ``trace.receiver``, and their disjunction: a
    copy left unanswered unless a wrong ACK answered it violates one of them in every
    explanation though neither alone."""
    out = {"MCP-ACK-1": ack1(trace, b), "MCP-ACK-2": _ack2(trace, b)}
    if out["MCP-ACK-2"].status == PROVEN:
        v = out["MCP-ACK-2"]
        out[EITHER_ACK] = Verdict(EITHER_ACK, PROVEN, v.evidence, v.explanation)
    else:
        out[EITHER_ACK] = ack1(trace, b, right_only=True)
    return out


def _own_acks(trace: Trace) -> list[int]:
    return [j for j, a in enumerate(trace.acks) if a.src == trace.receiver]


def _ack2(trace: Trace, b: Bounds) -> Verdict:
    rule = "MCP-ACK-2"
    own = [j for j in _own_acks(trace) if trace.acks[j].dst in (None, trace.sender)]
    if not own:
        return Verdict(rule, UNOBSERVABLE, f"no ACK from ID {trace.receiver} to ID {trace.sender}")
    if not trace.complete:
        return Verdict(rule, CONSISTENT, "the trace may miss the copy each ACK answers")
    acks = [trace.acks[j] for j in own]
    copies = list(trace.copies)

    naming: dict[int | None, list[int]] = {}
    for j, a in enumerate(acks):
        naming.setdefault(a.named, []).append(j)
    cands: list[list[int]] = [[] for _ in acks]  # an ACK's copies: the number it names
    for ci, c in enumerate(copies):
        for j in naming.get(c.seq, ()):
            if _answers(c, acks[j], b, b.horizon):
                cands[j].append(ci)
    owner, held = _match(len(acks), cands, [b.copy_capacity] * len(copies))
    pairs = tuple((own[j], owner[j]) for j in range(len(acks)))
    homeless = [j for j, c in enumerate(owner) if c is None]
    if not homeless:
        return Verdict(rule, CONSISTENT, "every ACK answers a copy of the number it names: "
                       + _explain(pairs, copies, trace.acks), pairs)
    lefts, rights = _hall(homeless[0], cands, held)
    wrong = acks[homeless[0]]
    if not rights:
        why = (f"{_fmt_ack(wrong)} names no copy sent to ID {trace.receiver} before it"
               if wrong.named is not None else f"{_fmt_ack(wrong)} names no number")
    else:  # only with a bounded copy_capacity, which D-9 gives no node of the spec's
        why = (f"{len(lefts)} ACKs ({_some([_fmt_ack(acks[j]) for j in sorted(lefts)])}) "
               f"and {len(rights)} datagrams they name "
               f"({_some([_fmt_copy(copies[r]) for r in sorted(rights)])}), each answered "
               f"at most {b.copy_capacity} time(s)")
    # the explanation as a whole: the right matching, the rest answering any copy it can
    return Verdict(rule, PROVEN, f"{why}: in every explanation an ACK answers a copy whose "
                   f"number it does not name; nearest explanation: "
                   f"{_explain(pairs, copies, trace.acks)}", pairs)

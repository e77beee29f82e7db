"""MCP-ACK-1 of :mod:`judge.explain`: is there an explanation in which ``R`` answered every copy
the rule asks it to?

The rule as observed (spec/mcp.yaml, D-6): a node may be deaf while busy, so it may miss the
first copies of a message -- at most ``max_ack_copies - 1`` of them -- but once it answered
one, it answers every later copy. An explanation therefore picks, for each message, the copy
``f`` it first answered: the copies before ``f`` went unanswered (had one of them been
answered, ``f`` would be earlier), ``f`` and every copy after it are answered, and ``f`` is
among the first ``max_ack_copies`` copies (or, for a message sent fewer times, no copy need be
answered). Every ACK of ``R``'s to ``S`` that could answer anything answers something: a copy
in its window (any payload: a wrong one is MCP-ACK-2's business), or a datagram a node must
not ACK whose number it names (MCP-ACK-4/6's).

Given the choices, the question is a matching that covers two sets at once -- the copies that
must be answered, the ACKs that must have a home -- and by the Mendelsohn-Dulmage theorem one
exists exactly when each set can be covered on its own: two maximum matchings. The choices
are searched per connected part of the trace (copies tied by a message or by an ACK that
could answer both), the natural explanation first (each message answered from the first
copy an ACK naming it could answer), then depth first with a check of the choices so far at
each step. A search that outgrows its budget leaves the rule undecided (never on a guess).
"""

from __future__ import annotations

from collections.abc import Sequence

from mcp_conform.judge.explain_model import (
    CONSISTENT,
    EITHER_ACK,
    PROVEN,
    UNOBSERVABLE,
    Ack,
    Bounds,
    Copy,
    Trace,
    Verdict,
    _candidates,
    _explain,
    _fmt_ack,
    _fmt_copy,
    _hall,
    _match,
    _some,
)

BUDGET = 4096  # feasibility checks per trace before the rule is left undecided

_Pairs = tuple[tuple[int, int | None], ...]


class _Part:
    """One connected part: its copies (trace indexes), its ACKs (indexes into ``acks``), its
    messages (each a list of copy indexes in time order, the copies the rule judges) and the
    range of each message's first answered copy."""

    def __init__(self) -> None:
        self.copies: list[int] = []
        self.acks: list[int] = []
        self.msgs: list[list[int]] = []
        self.lo: list[int] = []
        self.hi: list[int] = []
        self.natural: list[int] = []  # the first copy an ACK naming it could answer


def _find(parent: list[int], x: int) -> int:
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


def ack1(trace: Trace, b: Bounds, right_only: bool = False) -> Verdict:
    """MCP-ACK-1; with ``right_only``, whether an explanation keeps MCP-ACK-2 too (every ACK
    answers a copy whose number it names): "MCP-ACK-1 or MCP-ACK-2" is proven when none does."""
    rule = EITHER_ACK if right_only else "MCP-ACK-1"
    if not trace.complete:
        return Verdict(rule, UNOBSERVABLE, "the trace may miss ACKs (not complete)")
    copies = trace.copies
    own = [j for j, a in enumerate(trace.acks) if a.src == trace.receiver]
    acks = [trace.acks[j] for j in own]
    # the ACKs that could answer each copy: in its window, and naming it if it is not to be ACKed
    near = _candidates(copies, acks, b.copy_early + b.ack_late,
                       b.ack_window + b.copy_late + b.ack_early)
    cands = [[j for j in js if (c.ackable and not right_only) or acks[j].named == c.seq]
             for c, js in zip(copies, near, strict=True)]
    by_ack: list[list[int]] = [[] for _ in acks]
    for ci, js in enumerate(cands):
        for j in js:
            by_ack[j].append(ci)
    # an ACK to S naming a datagram it could answer answers something (one naming nothing it
    # could answer may answer nothing: MCP-ACK-2's business, or ACK-5/6's)
    homed = [acks[j].dst in (None, trace.sender)
             and any(copies[ci].seq == acks[j].named for ci in by_ack[j]) for j in range(len(acks))]
    # judged: a copy of a message sent while R receives, whose window closed within the trace
    closed = [c.ackable and c.judged and c.t + b.copy_late + b.ack_window + b.ack_early <= trace.end
              for c in copies]
    if not any(closed):
        return Verdict(rule, UNOBSERVABLE, "no copy whose ACK window closed within the trace")
    parts = _parts(copies, acks, cands, closed, b)
    checks = [0]
    pairs: list[tuple[int, int | None]] = []
    for part in parts:
        status, found = _search(part, cands, by_ack, homed, b, checks)
        if status == "budget":
            return Verdict(rule, UNOBSERVABLE, f"left undecided: more than {BUDGET} choices "
                           "of first answered copies tried")
        if status == "none":
            text, shown = _evidence(part, copies, acks, cands, by_ack, homed, b, trace)
            return Verdict(rule, PROVEN, text, tuple((own[j], c) for j, c in shown))
        pairs += [(own[j], c) for j, c in found]
    shown_pairs = tuple(sorted(pairs, key=lambda p: p[0]))
    return Verdict(rule, CONSISTENT, "every copy the rule asks for answered within the window: "
                   + _explain(shown_pairs, copies, trace.acks), shown_pairs)


def _parts(copies: Sequence[Copy], acks: Sequence[Ack], cands: Sequence[Sequence[int]],
           closed: Sequence[bool], b: Bounds) -> list[_Part]:
    """The connected parts that hold a judged copy: copies joined by an ACK that could answer
    both, and the copies of one message."""
    n, n_acks = len(copies), len(acks)
    parent = list(range(n + n_acks))
    first_of: dict[int, int] = {}
    for ci, c in enumerate(copies):
        for j in cands[ci]:
            parent[_find(parent, ci)] = _find(parent, n + j)
        if c.ackable and c.judged:
            k = first_of.setdefault(c.msg, ci)
            parent[_find(parent, ci)] = _find(parent, k)
    parts: dict[int, _Part] = {}
    for ci in range(n):
        parts.setdefault(_find(parent, ci), _Part()).copies.append(ci)
    for j in range(n_acks):
        root = _find(parent, n + j)
        if root in parts:
            parts[root].acks.append(j)
    out = []
    for part in parts.values():
        msgs: dict[int, list[int]] = {}
        for ci in part.copies:  # trace order is time order
            if copies[ci].ackable and copies[ci].judged:
                msgs.setdefault(copies[ci].msg, []).append(ci)
        for seq_of in msgs.values():
            judged = [ci for ci in seq_of if closed[ci]]
            if not judged:
                continue
            # the first answered copy: among the first max_ack_copies, or none for a message
            # sent fewer times; past the judged ones (their window closed) when none of those
            kc = len(judged)
            hi = min(b.max_ack_copies - 1, kc) if len(seq_of) >= b.max_ack_copies else kc
            dead = [i for i, ci in enumerate(judged) if not cands[ci]]
            lo = dead[-1] + 1 if dead else 0
            named = [i for i, ci in enumerate(judged)
                     if i >= lo and any(acks[j].named == copies[ci].seq for j in cands[ci])]
            part.msgs.append(judged)
            part.lo.append(lo)
            part.hi.append(hi)
            part.natural.append(min(named[0] if named else lo, hi))
        if part.msgs:
            out.append(part)
    return out


class _Checked:
    """What :func:`_check` found: ``ok``, the copies asked answered with their ACK (``owner_r``
    indexes ``acks``), the ACKs that must have a home with theirs (``home``: a copy's index)."""

    def __init__(self, required: list[int], req_cands: list[list[int]],
                 owner_r: list[int | None], must: list[int], home: list[int | None]) -> None:
        self.required, self.req_cands, self.owner_r = required, req_cands, owner_r
        self.must, self.home = must, home
        self.ok = None not in owner_r and None not in home

    def pairs(self) -> list[tuple[int, int | None]]:
        """The explanation's (ACK, copy) pairs: every homed ACK, then the copies asked for."""
        out = {j: c for j, c in zip(self.must, self.home, strict=True) if c is not None}
        for ci, j in zip(self.required, self.owner_r, strict=True):
            if j is not None and j not in out:
                out[j] = ci
        return sorted(out.items())


def _check(part: _Part, choice: Sequence[int | None], cands: Sequence[Sequence[int]],
           by_ack: Sequence[Sequence[int]], homed: Sequence[bool], b: Bounds) -> _Checked:
    """Whether the choices so far (None: undecided, no constraint) leave an explanation: the
    copies they ask answered can each have an ACK, and every ACK that must have a home has one
    among the copies they leave open (Mendelsohn-Dulmage: then one matching does both)."""
    forbidden: set[int] = set()
    required: list[int] = []
    for m, f in enumerate(choice):
        if f is None:
            continue
        forbidden.update(part.msgs[m][:f])
        required += part.msgs[m][f:]
    req_cands = [list(cands[ci]) for ci in required]
    owner_r, _ = _match(len(required), req_cands, [1] * len(by_ack))
    must = [j for j in part.acks if homed[j]]
    open_copies = sorted({ci for j in must for ci in by_ack[j]} - forbidden)
    pos = {ci: k for k, ci in enumerate(open_copies)}
    home_cands = [[pos[ci] for ci in by_ack[j] if ci in pos] for j in must]
    owner_h, _ = _match(len(must), home_cands, [b.copy_capacity] * len(open_copies))
    home = [None if o is None else open_copies[o] for o in owner_h]
    return _Checked(required, req_cands, owner_r, must, home)


def _search(part: _Part, cands: Sequence[Sequence[int]], by_ack: Sequence[Sequence[int]],
            homed: Sequence[bool], b: Bounds, checks: list[int]
            ) -> tuple[str, list[tuple[int, int | None]]]:
    """("found", an explanation's pairs), ("none", []) when none exists, ("budget", [])."""
    n = len(part.msgs)
    if any(lo > hi for lo, hi in zip(part.lo, part.hi, strict=True)):
        return "none", []

    natural: list[int | None] = list(part.natural)
    checks[0] += 1
    first = _check(part, natural, cands, by_ack, homed, b)
    if first.ok:
        return "found", first.pairs()
    choice: list[int | None] = [None] * n

    def dfs(m: int) -> bool | None:
        if m == n:
            return True
        for f in range(part.lo[m], part.hi[m] + 1):
            checks[0] += 1
            if checks[0] > BUDGET:
                return None
            choice[m] = f
            if _check(part, choice, cands, by_ack, homed, b).ok:
                got = dfs(m + 1)
                if got is not False:
                    return got
        choice[m] = None
        return False

    got = dfs(0)
    if got is None:
        return "budget", []
    return ("found", _check(part, choice, cands, by_ack, homed, b).pairs()) if got else ("none", [])


def _evidence(part: _Part, copies: Sequence[Copy], acks: Sequence[Ack],
              cands: Sequence[Sequence[int]], by_ack: Sequence[Sequence[int]],
              homed: Sequence[bool], b: Bounds, trace: Trace
              ) -> tuple[str, list[tuple[int, int | None]]]:
    """For a person: the messages of the part that no explanation keeps, and why under the
    natural choice (each message answered from the first copy an ACK naming it could answer;
    every other choice fails too, the search found)."""
    c = _check(part, part.natural, cands, by_ack, homed, b)
    shown = c.pairs()
    msgs = _some([f"seq {copies[m[0]].seq} ({len(m)} copies from {copies[m[0]].t:.3f} s)"
                  for m in part.msgs])
    head = (f"no explanation answers every copy MCP-ACK-1 asks for (D-6: a node may miss "
            f"at most the first {b.max_ack_copies - 1} copies of a message, none after one it "
            f"answered) among {msgs} and ACKs from ID {trace.receiver} "
            f"({_some([_fmt_ack(acks[j]) for j in part.acks]) or 'none'})")
    missing = [k for k, o in enumerate(c.owner_r) if o is None]
    if missing:
        held: list[list[int]] = [[] for _ in acks]
        for k, o in enumerate(c.owner_r):
            if o is not None:
                held[o].append(k)
        lefts, rights = _hall(missing[0], c.req_cands, held)
        why = (f"answered from the first copy an ACK naming it could answer (other choices "
               f"fail too), "
               f"{len(lefts)} copies ({_some([_fmt_copy(copies[c.required[k]]) for k in lefts])}) "
               f"must be answered and only {len(rights)} ACKs could answer them within "
               f"{b.ack_window:g} s ({_some([_fmt_ack(acks[r]) for r in rights]) or 'none'})")
    elif not c.ok:
        j = next(j for j, h in zip(c.must, c.home, strict=True) if h is None)
        where = {ci: (m, i) for m, msg in enumerate(part.msgs) for i, ci in enumerate(msg)}
        later = sorted({ci2 for ci in by_ack[j] if ci in where
                        for ci2 in part.msgs[where[ci][0]][where[ci][1] + 1:]})
        dead = [ci for ci in later if not cands[ci]]
        then = (f"{_some([_fmt_copy(copies[ci]) for ci in dead])} has no ACK that could answer "
                f"it within {b.ack_window:g} s" if dead else
                f"the later copies ({_some([_fmt_copy(copies[ci]) for ci in later])}) cannot all "
                f"be answered")
        why = (f"{_fmt_ack(acks[j])} can answer only "
               f"{_some([_fmt_copy(copies[ci]) for ci in by_ack[j]])}; a node that answered it "
               f"answers the later copies of its message (D-6), and {then}")
    else:  # the least-asking choice holds; the search failed elsewhere (several parts)
        why = "every choice of first answered copies leaves a copy or an ACK without a partner"
    return f"{head}: {why}; nearest explanation: {_explain(shown, copies, acks) or 'none'}", shown

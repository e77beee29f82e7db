"""The Nsqd stateful engine: programs of clients of a backend (issue 21 item 1, issue 36 item 4).

A program (``fuzz.nsqd_programs``: drawn by a seeded random) is a list of :class:`Op` over
connections to the backend, its moves derived from ``spec/nsqd.yaml``: open a connection (in
one of two client slots: a second client while the first is served, NSQD-CON-2, D-4), a
valid command (the messages table's effect is judged, NSQD-MSG-3), a mutated case of any kind
of ``fuzz.nsqd_mutators``, a frame cut by FIN or RST (NSQD-ROB-2) and a new connection
after it (NSQD-ROB-3), a close. :class:`Player` plays ops on a backend
(``fuzz.nsqd_backend.Backend``) and judges them with the stateless engine's oracles (death,
sanitizer report, the backend's own frames by ``Conn.violation``, a close after frames a
backend handles, a command's effect, a stream that stopped), plus what only several
connections show: a first client closed or disturbed when a second connects, a waiting client
never served once the first leaves (NSQD-CON-2), a command lost on a new connection after a
cut frame (NSQD-ROB-3).

Two ways to play (issue 36 item 5: cases per second against a slow-updating backend come from
overlapping cases, not from waiting out each UPDATE period):

- **careful** (triage's replays, ``--replay``): each op judged as it is played, waiting for
  what shows it: a command's effect in the next UPDATE, the backend's loop gone round
  (``LOOP_UPDATES``) when a second client connects;
- **pipelined** (the campaign, ``Player(fast=True)``): ops written back to back, what is
  there read after each (death, reports, frames, closes), and the waits done once, at the
  program's end (:meth:`Player.finish`): the first client's next UPDATE once a second one
  connected, the promoted client's first, and a turnover -- every client's FIN, then a new
  connection, whose UPDATE on accept shows the flight state all their bytes left (the backend
  has read each stream to its end before it serves the next client): the last command's
  effect judged by it in one round trip instead of an UPDATE period.

The player is ``fuzz.nsqd_player``'s, the programs and the engine that runs them
``fuzz.nsqd_programs``'s; this module replays and triages. A pipelined program's failure is triaged by careful replays (``fuzz.nsqd_triage.StreamTriage.add_program``):
replayed in a fresh process, delta-debugged over its ops, confirmed N of N, deduplicated by
signature; a confirmed program is saved in the example database (``--db``) and played first
by every worker of the next campaign.
"""

from __future__ import annotations

from typing import Any

from mcp_conform.fuzz.confirm import confirm_n
from mcp_conform.fuzz.ddmin import ddmin
from mcp_conform.fuzz.finding_files import TrafficLog
from mcp_conform.fuzz.nsqd_backend import REPLAY_DEATH_S, _passing, end_log
from mcp_conform.fuzz.nsqd_oracles import same_finding
from mcp_conform.fuzz.nsqd_player import Hit, Op, Player

__all__ = ["play_program", "triage_program"]


def play_program(backend: Any, ops: list[Op], log: Any = None, want: Any = None) -> Hit | None:
    """Play ``ops`` on ``backend`` (a fresh one for a replay): the first hit, if any.
    ``log`` (a ``fuzz.nsqd_repro.TrafficLog``): the replay's traffic, for the finding's
    repro.mcap and repro.pcap, as a stateless finding's confirming replay keeps it. ``want``
    (a death's signature): a non-fatal sanitizer report on the way is not the verdict, the
    program goes on to the death (``fuzz.nsqd_backend._passing``, halt_on_error=0)."""
    backend.session.recorder = log
    p = Player(backend)
    passed: Hit | None = None
    try:
        for op in ops:
            try:
                p.play(op)
            except Hit as hit:
                if want is None or not _passing(hit, want):
                    raise
                passed = hit
        # a replay after a death waits for it as long as a stateless replay does, whatever it
        # saw on the way: a loaded host's backend may not have read the last ops yet
        died = backend.death_hit(REPLAY_DEATH_S if passed is not None or want is not None else 0.3)
        if died is not None:
            return Hit(died.signature, died.detail, died.stderr)
        p._judge()
        return passed
    except Hit as hit:
        # without the death it wanted, the first report it saw is the verdict, also when that
        # report is first seen at the end (it returned None then: a loaded host, CI run 6)
        return (passed or hit) if want is not None and _passing(hit, want) else hit
    finally:
        end_log(backend, log, p.close)


def triage_program(campaign: Any, backend: Any, hit: Hit, ops: list[Op]) -> Any:
    """A failing program: deduplicated, replayed in a fresh process, delta-debugged over its
    ops, confirmed ``campaign.n_of_n`` of as many times, then a finding
    (``campaign.add_program_finding``; ``campaign``: the worker's ``StreamTriage``, whose
    ``HitTriage.again`` counts a known finding's hit and ``HitTriage.fresh`` each replay's process).
    The first careful replay names the finding: a pipelined program's verdict (``hit``) is
    what led to it, read at the program's end, where a close or a lost command may have more
    than one cause in view (a second client, a cut frame before it); played op by op, the
    replay sees which op it followed. A lost stream (``desync``: after a frame cut by a closed
    connection, NSQD-ROB-3, or after mutated frames) is the cut's or the frames' only if the
    minimal program without its ``send`` ops shows nothing: else the finding is what that
    program shows (a backend that ignores every command loses the command without any cut:
    NSQD-MSG-3, the command's own effect). The backend to go on with."""

    sig = hit.signature
    known = next((f for f in campaign.findings if f.signature.key == sig.key), None)
    if campaign.again(known):
        return backend.fresh() if sig.oracle in ("crash", "hang", "sanitizer") else backend
    box: dict[str, Any] = {"b": backend, "stderr": hit.stderr, "traffic": []}

    def play(o: list[Op], log: TrafficLog | None = None) -> Hit | None:
        # a careful replay on a fresh process (HitTriage.fresh: a "triage replay" restart),
        # counted by hand: HitTriage.replay would also end it past the deadline (Late), which
        # this triage's replays have never done
        box["b"] = campaign.current = campaign.fresh(box["b"].fresh)
        campaign.replays += 1
        return play_program(box["b"], o, log, want=sig)

    def reproduces(o: list[Op], log: TrafficLog | None = None) -> bool:
        h = play(o, log)
        if h is not None and h.stderr:
            box["stderr"] = h.stderr
        ok = h is not None and same_finding(h.signature, sig)
        if ok and log is not None:
            box["traffic"] = log.records  # the last confirming replay's: repro.mcap, repro.pcap
        return ok

    first = play(ops)
    if first is None:
        campaign.count_unconfirmed(sig.rule)
        return box["b"].fresh()
    if not same_finding(first.signature, sig):
        sig, hit = first.signature, first
        known = next((f for f in campaign.findings if f.signature.key == sig.key), None)
        if campaign.again(known):
            return box["b"].fresh()
    box["stderr"] = first.stderr or box["stderr"]
    if len(ops) > 1:
        ops = ddmin(list(ops), reproduces, budget=16)
    if sig.oracle == "desync" and any(o.what == "send" for o in ops):
        # blame: a stream lost to a cut frame (NSQD-ROB-3) or to the frames before it
        # (``desync_rule``) only if the program without them keeps it: the same failure
        # without them (a backend that ignores every command: NSQD-MSG-3) is the program's own
        plain = [o for o in ops if o.what != "send"]
        own = play(plain) if plain else None
        if own is not None:
            sig, hit, ops = own.signature, own, plain
            box["stderr"] = own.stderr or box["stderr"]
            known = next((f for f in campaign.findings if f.signature.key == sig.key), None)
            if campaign.again(known):
                return box["b"].fresh()
            if len(ops) > 1:
                ops = ddmin(list(ops), reproduces, budget=16)
    conf = confirm_n(lambda: reproduces(ops, TrafficLog()) or None, campaign.n_of_n, until_miss=False)
    if not conf.confirmed:
        campaign.count_unconfirmed(sig.rule)
        return box["b"].fresh()
    campaign.add_program_finding(sig, hit.detail, conf.replays, tuple(box["stderr"]),
                                 "stateful: " + "; ".join(op.describe() for op in ops), [op.to_json() for op in ops],
                                 box["traffic"])
    return box["b"].fresh()

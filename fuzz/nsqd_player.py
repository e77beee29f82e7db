"""The Nsqd stateful engine's player: ops on connections to a backend, judged (issue 21
item 1, issue 36 items 4-5). ``fuzz.nsqd_stateful`` says what a program is and how the
careful and the pipelined ways of playing differ; this module is the player of both.
"""

from __future__ import annotations

import random
import time
from dataclasses import dataclass, field
from typing import Any

from mcp_conform.fuzz.nsqd_backend import violation_hit
from mcp_conform.fuzz.nsqd_mutators import Write, valid_values
from mcp_conform.fuzz.nsqd_oracles import CLOSE_RULE, Hit, Signature, desync_rule
from mcp_conform.fuzz.target_core import read_until
from mcp_conform.harness.nsqd_session import Conn
from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd_codec import encode

__all__ = ["COMMANDS", "Client", "Hit", "Op", "Player", "command_bytes"]

SLOTS = 2  # client slots: a first client and a second one at once
#: UPDATEs to the first client, counted from a second's connect, that show the backend has
#: gone round its loop with the second waiting (Player._settle): one may come from the turn
#: under way when it connected, one from the next turn, which saw it (a backend that kicks
#: the first may send that UPDATE just before it closes it), and a third only on a first kept
LOOP_UPDATES = 3
#: Pipelined: how long after a second client's connect a first one is watched for a kick at
#: most (its next UPDATE or the second's first frame end it sooner). A backend that accepts
#: within its loop turn (Main.cpp's 50 Hz: 20 ms) kicks well within it; a later kick escapes
#: this program (the turnover's FIN comes first), never misjudged: ``LOOP_UPDATES`` is the
#: careful replay's proof, this only the search's chance
KICK_WATCH_S = 0.1
#: the commands whose effect UPDATE shows (NSQD-MSG-3), and every message a client sends
COMMANDS = tuple(m.name for m in NSQD.messages if m.sent_by in ("client", "any") and m.effect.to)
CLIENT_MSGS = tuple(m.name for m in NSQD.messages if m.sent_by in ("client", "any") and not m.effect.unobserved)


def command_bytes(name: str) -> bytes:
    """A valid command with the same field values every time (a fixed seed)."""
    msg = NSQD.message(name)
    return encode(NSQD, name, **valid_values(NSQD, msg, random.Random(0)))


@dataclass(frozen=True)
class Op:
    """One move of a program: ``open`` (a new connection in ``slot``, the old one closed),
    ``send`` (a case's writes, the last maybe ending by FIN or RST), ``cmd`` (a valid
    command, its effect judged) or ``close`` (``how``: fin or rst)."""

    what: str
    slot: int
    writes: tuple[Write, ...] = ()
    kind: str = ""  # send: the case's kind; cmd: the message
    valid: bool = False  # send: every frame one a backend handles
    in_sync: bool = True  # send: the stream is still in step after it (Case.probe)
    how: str = "fin"  # close
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        return {"what": self.what, "slot": self.slot, "writes": [{"hex": w.data.hex(), "end": w.end} for w in self.writes],
                "kind": self.kind, "valid": self.valid, "in_sync": self.in_sync, "how": self.how, "note": self.note}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Op:
        return cls(d["what"], int(d["slot"]), tuple(Write(bytes.fromhex(w["hex"]), w.get("end", "")) for w in d.get("writes", [])),
                   d.get("kind", ""), bool(d.get("valid")), bool(d.get("in_sync", True)), d.get("how", "fin"), d.get("note", ""))

    def describe(self) -> str:
        if self.what == "open":
            return f"client {self.slot}: connect"
        if self.what == "close":
            return f"client {self.slot}: close ({self.how.upper()})"
        if self.what == "cmd":
            return f"client {self.slot}: {self.kind}"
        return f"client {self.slot}: {self.kind} ({self.note})"


@dataclass
class Client:
    """A slot's connection and what the judge knows of it."""

    conn: Conn
    second: bool  # another client was served when it connected: not served yet (D-4)
    after_cut: str = ""  # the kind of cut (fin/rst-mid-frame) of the connection before it
    clean: bool = True  # only frames a backend handles were sent on it
    in_sync: bool = True
    others: bool = False  # another client connected while it was served
    kinds: list[str] = field(default_factory=list)  # the mutated cases sent on it
    last_kind: str = "valid"
    others_at: float = 0.0  # when another client connected while it was served
    promoted: bool = False  # pipelined: served once the first left, its first UPDATE not yet judged
    sent: bool = False  # anything was sent on it
    pending: tuple[Op, float] | None = None  # pipelined: its last command, judged at the end


class Player:
    """Plays ops on a backend's session, careful or pipelined (``fast``; see the module
    docstring). ``spare``: a connection already served (the last pipelined program's turnover
    left it), the first client's when the first op opens one."""

    def __init__(self, backend: Any, *, fast: bool = False, spare: Conn | None = None) -> None:
        self.b = backend
        backend._drop()
        self.fast, self.spare = fast, spare
        #: clients that sent bytes while waiting and were not served since: a one-client
        #: backend reads them once the first leaves, even of a client closed meanwhile
        self.queued = 0
        self.clients: dict[int, Client] = {}
        self.cut = ""  # a client left mid-frame since the last new connection
        self.window = float(NSQD.params["effect_window_s"])
        self.gap = float(NSQD.params["update_gap_max_s"])

    # -- playing ------------------------------------------------------------------------
    def play(self, op: Op) -> None:
        """One op; :class:`Hit` when an oracle fires."""
        self.b.session.sent_log.clear()  # the session's record of what the current op sent
        if op.what == "open":
            self._open(op.slot)
        elif op.what == "close":
            c = self.clients.pop(op.slot, None)
            if c is not None:
                c.conn.close(rst=op.how == "rst")
                self._forget(c)
        else:
            c = self.clients.get(op.slot) or self._open(op.slot)
            if c is None:
                return
            if op.what == "cmd":
                self._command(c, op)
            else:
                self._send(c, op)
        self._judge()

    def close(self) -> None:
        for c in self.clients.values():
            c.conn.close()
            self._forget(c)
        self.clients.clear()
        if self.spare is not None:
            self.spare.close()
            self._forget_conn(self.spare)
            self.spare = None

    def _forget(self, c: Client) -> None:
        self._forget_conn(c.conn)

    def _forget_conn(self, conn: Conn) -> None:
        if conn in self.b.session.conns:
            self.b.session.conns.remove(conn)

    def _open(self, slot: int) -> Client | None:
        old = self.clients.pop(slot, None)
        if old is not None:
            old.conn.close()
            self._forget(old)
            self._promote()  # a client waiting behind the old one is served before the new one
        served = [c for c in self.clients.values() if not c.second and c.conn.closed_at is None]
        conn, self.spare = (self.spare, None) if self.spare is not None and not self.clients else (None, self.spare)
        conn = conn or self.b.session.connect(timeout=float(NSQD.params["connect_timeout_s"]))
        if conn is None:
            if served:
                return None  # a second client may be refused (D-4)
            self._dead()
            raise Hit(Signature("hang", "not accepting", (), "NSQD-ROB-1"), "a new connection was not accepted")
        self.b.connections += 1
        c = Client(conn, second=bool(served), after_cut=self.cut)
        self.cut = ""
        for o in served:
            o.others, o.others_at = True, time.monotonic()
            if not self.fast:
                self._settle(o.conn)
        self.clients[slot] = c
        return c

    def _settle(self, first: Conn) -> None:
        """A second client has just connected: wait until ``first`` shows what that did to it
        (NSQD-CON-2), the backend's close or ``LOOP_UPDATES`` UPDATEs sent to it since (its
        loop gone round with the second waiting). What it had sent before is read first: a
        frame is stamped when read, and one waiting unread proves nothing (the old wait, 0.15 s
        or until such a frame, let a loaded host's backend kick the first after the judgement:
        a finding a replay missed). The backend's own progress, so load makes the wait longer,
        never wrong; it ends early only on a stream that stopped (no UPDATE within
        update_gap_max_s, NSQD-MSG-1: a command on it judges that). The verdict comes at this
        op every time, as hypothesis's shrinking and its replay of a saved program need."""
        first.pump(0)
        have = len(first.updates())
        proof = have + LOOP_UPDATES
        while first.closed_at is None and have < proof:
            if not first.wait_for(lambda n=have: first.closed_at is not None or len(first.updates()) > n, self.gap):
                return
            have = len(first.updates())

    def _send(self, c: Client, op: Op) -> None:
        c.clean = c.clean and op.valid
        c.in_sync = c.in_sync and op.in_sync
        if not op.valid or not op.in_sync:
            c.kinds.append(op.kind)
        c.last_kind = op.kind if op.valid else c.last_kind
        self._sent(c)
        c.pending = None
        for w in op.writes:
            if not c.conn.send(w.data):
                break
            if w.end:
                c.conn.close(rst=w.end == "rst")
                self._gone(c)
                if not _whole_frames(b"".join(x.data for x in op.writes)):
                    self.cut = f"{w.end}-mid-frame"  # the next connection served is a new stream
                    for o in self.clients.values():  # a waiting client may be that one
                        o.after_cut = o.after_cut or (self.cut if o.second else "")
                return
        c.conn.pump(0 if self.fast else 0.003)

    def _sent(self, c: Client) -> None:
        if c.second and not c.sent:
            self.queued += 1
        c.sent = True

    def _gone(self, c: Client) -> None:
        for slot, o in list(self.clients.items()):
            if o is c:
                del self.clients[slot]
        self._forget(c)

    def _command(self, c: Client, op: Op) -> None:
        msg = NSQD.message(op.kind)
        conn = c.conn
        judged = not c.second and c.in_sync and conn.closed_at is None
        self._sent(c)
        if self.fast:  # judged at the program's end, if nothing follows it (finish)
            c.pending = (op, time.monotonic()) if judged else None
            conn.send(op.writes[0].data)
            c.last_kind = "valid"
            conn.pump(0)
            return
        if judged and not conn.updates():  # the state before the command, from the stream
            conn.wait_for(lambda: bool(conn.updates()), self.gap)
            if not conn.updates() and conn.closed_at is None:
                self._dead()
                raise Hit(Signature("hang", "no UPDATE on a new connection", (), "NSQD-MSG-1"),
                          f"no UPDATE within {self.gap:g} s of connecting")
        ups = conn.updates()
        judged = judged and bool(ups) and ups[-1].values["state"] not in msg.effect.to  # type: ignore[index]
        since = time.monotonic()
        conn.send(op.writes[0].data)
        c.last_kind = "valid"
        if not judged:
            conn.pump(0.003)
            return
        ok = conn.wait_for(lambda: any(u.values["state"] in msg.effect.to for u in conn.updates(since))  # type: ignore[index]
                           or (msg.effect.or_error and bool(conn.errors(since))), self.window)
        if ok:
            c.after_cut, c.kinds = "", []  # the stream proved in sync: a later loss is not theirs
            return
        if conn.closed_at is not None:
            return  # a close is judged with the others' (_judge)
        self._judge()  # a death or the backend's own frames first
        raise self._lost(c, op, [u.values["state"] for u in conn.updates(since)])  # type: ignore[index]  # an UPDATE has values

    def _lost(self, c: Client, op: Op, states: list[int]) -> Hit:
        """The finding of a command whose effect did not show (``states``: what UPDATE showed):
        named by what the connection had been through."""
        msg = NSQD.message(op.kind)
        seen = sorted({NSQD.state_name(s) for s in states})
        what = (f"{op.kind}: UPDATE.state {' or '.join(NSQD.state_name(s) for s in msg.effect.to)} expected "
                f"within {self.window:g} s, saw {', '.join(seen) or 'no UPDATE'}")
        if not seen:
            sig = (Signature("hang", "UPDATE stream stopped with a second client", (), "NSQD-CON-2") if c.others
                   else Signature("hang", "UPDATE stream stopped", (), "NSQD-MSG-1"))
        elif c.others:
            sig = Signature("effect", "command lost with a second client", (), "NSQD-CON-2")
            what += " (a second client had connected)"
        elif c.after_cut and not c.kinds:
            sig = Signature("desync", f"stream lost after {c.after_cut}", (), "NSQD-ROB-3")
            what += f" (a new connection after a frame cut by {c.after_cut[:3].upper()})"
        elif c.kinds:
            sig = Signature("desync", f"stream lost after {c.kinds[-1]}", (), desync_rule(c.kinds[-1]))
        else:
            sig = Signature("effect", op.kind, (), "NSQD-MSG-3")
        return Hit(sig, what)

    # -- judging ------------------------------------------------------------------------
    def _dead(self) -> None:
        hit = self.b.death_hit(0.3)
        if hit is not None:
            raise hit

    def _judge(self) -> None:
        for c in self.clients.values():
            c.conn.pump(0)
        # a death closes the socket as the process exits: a moment to tell the two apart
        # (pipelined: only where a close would be a finding, as the stateless engine does)
        closed = any(c.conn.closed_at is not None and (not self.fast or (c.clean and not c.second))
                     for c in self.clients.values())
        hit = self.b.end_hit(0.03 if closed else 0.0)
        if hit is not None:
            raise Hit(hit.signature, hit.detail, hit.stderr)
        hit = violation_hit(c.conn for c in self.clients.values())
        if hit is not None:
            raise hit
        for slot, c in list(self.clients.items()):
            if c.conn.closed_at is None:
                continue
            self._gone(c)
            if c.second or not c.clean:
                continue  # a second client may be closed (D-4); after a bad frame it may (D-3)
            if c.others:  # before a cut: the second client is what happened to it last
                raise Hit(Signature("close", "first client closed by a second", (), "NSQD-CON-2"),
                          f"client {slot} was closed by the backend when a second client connected")
            if c.after_cut and not c.kinds:
                raise Hit(Signature("desync", f"stream lost after {c.after_cut}", (), "NSQD-ROB-3"),
                          f"client {slot}'s new connection, after a frame cut by {c.after_cut[:3].upper()}, "
                          "was closed after frames a backend handles")
            raise Hit(Signature("close", c.last_kind, (), CLOSE_RULE.get(c.last_kind, "NSQD-FRM-5")),
                      f"the backend closed client {slot}'s connection after frames it handles")
        self._promote()

    def _promote(self) -> None:
        """A waiting second client is served once no first one is left (NSQD-CON-2, D-4)."""
        if any(not c.second for c in self.clients.values()):
            return
        for slot, c in self.clients.items():
            if not c.second:
                continue
            c.second = False
            self.queued -= c.sent  # what it sent is read now, before anything sent after
            conn = c.conn
            if conn.updates():
                continue
            if self.fast:  # its first UPDATE is waited for at the program's end (finish)
                c.promoted = True
                return
            bound = self.gap + 0.5
            if not conn.wait_for(lambda conn=conn: bool(conn.updates()), bound) and conn.closed_at is None:
                self._dead()
                raise Hit(Signature("hang", "waiting client not served", (), "NSQD-CON-2"),
                          f"client {slot}, waiting while another was served, got no UPDATE within {bound:g} s "
                          "of the other leaving")
            return


    # -- the end of a pipelined program ---------------------------------------------------
    def finish(self) -> Conn | None:
        """A pipelined program's waits, once (see the module docstring): a first client that
        saw a second connect watched until its next UPDATE (the backend's loop gone round with
        the second waiting; a backend that kicks the first does so on accepting the second:
        ``_judge`` then names it), a promoted client's first UPDATE (NSQD-CON-2), then the
        turnover: every client's FIN, the served one's first, and a new connection, whose
        first UPDATE shows the state all their bytes left; the served client's last command (``pending``, when nothing was sent
        after it on any connection) is judged by it. :class:`Hit` when an oracle fires; the
        new connection, served, when the backend is live (the next program's first client),
        else None (the caller restarts the backend: as a careful replay, not a finding)."""
        waiting = [c.conn for c in self.clients.values() if c.second]
        for c in list(self.clients.values()):
            conn, t = c.conn, c.others_at
            if c.others and not c.second and conn.closed_at is None:
                read_until([conn, *waiting], lambda conn=conn, t=t: conn.closed_at is not None or bool(conn.updates(t))
                          or any(w.frames for w in waiting), t + KICK_WATCH_S - time.monotonic())
        self._judge()
        for slot, c in self.clients.items():
            conn = c.conn
            bound = self.gap + 0.5
            if c.promoted and not conn.wait_for(lambda conn=conn: bool(conn.updates()), bound) and conn.closed_at is None:
                self._dead()
                raise Hit(Signature("hang", "waiting client not served", (), "NSQD-CON-2"),
                          f"client {slot}, waiting while another was served, got no UPDATE within {bound:g} s "
                          "of the other leaving")
        self._judge()
        order = sorted(self.clients.values(), key=lambda c: c.second)  # the served one first
        served = order[0] if order and not order[0].second else None
        pending = served.pending if served is not None and not self.queued else None
        for c in order:
            c.conn.shutdown()
        observer = self.b.session.connect(timeout=float(NSQD.params["connect_timeout_s"]))
        if observer is not None:
            self.b.connections += 1
        nxt = observer  # a waiting client, FIN'd before it is served, is dropped before its first UPDATE
        conns = [c.conn for c in order] + ([observer] if observer is not None else [])

        def shown() -> bool:
            if pending is not None and served is not None:
                old, (op, since) = served.conn, pending
                to = NSQD.message(op.kind).effect
                if any(u.values["state"] in to.to for u in old.updates(since)):  # type: ignore[index]
                    return True
                if to.or_error and old.errors(since):
                    return True
                if old.closed_at is None:
                    return False  # the next client's UPDATE proves nothing before the backend closed this one
            return nxt is not None and bool(nxt.updates())

        read_until(conns, shown, self.window)
        died = self.b.death_hit(0.0)  # the backend's record of a death, raised as the player's Hit
        hit = Hit(died.signature, died.detail, died.stderr) if died is not None else None
        hit = hit or violation_hit(conns)
        if hit is None and pending is not None and served is not None and served.conn.closed_at is not None \
                and not served.conn.reset:
            op, since = pending
            effect = NSQD.message(op.kind).effect
            old = served.conn
            states = [u.values["state"] for u in old.updates(since)]  # type: ignore[index]
            first = nxt.updates()[:1] if nxt is not None else []
            if not (any(s in effect.to for s in states) or (effect.or_error and old.errors(since))
                    or (first and first[0].values["state"] in effect.to)):  # type: ignore[index]
                hit = self._lost(served, op, states + [u.values["state"] for u in first])
        for c in order:
            c.conn.close()
            self._forget(c)
        self.clients.clear()
        if hit is not None:
            if observer is not None:
                observer.close()
                self._forget_conn(observer)
            raise hit
        if observer is not None and not observer.wait_for(lambda: bool(observer.updates()), self.gap):
            observer.close()
            self._forget_conn(observer)
            self._dead()
            return None
        return observer


def _whole_frames(data: bytes) -> bool:
    """``data`` is whole frames by their length prefixes (nothing cut)."""
    off = 0
    while off + 4 <= len(data):
        n = int.from_bytes(data[off:off + 4], "big", signed=True)
        if n < 5:
            return False
        off += n
    return off == len(data)

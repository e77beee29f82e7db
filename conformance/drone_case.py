"""The per-case context (the ``node`` fixture): sends, and the verify helpers.

A case sends, then calls ONE verify helper (h2spec's shape). The helper owns the waiting,
treats a timeout as an observation, and raises ``CaseFailure(rule, expected, actual,
evidence)`` or ``Inconclusive(reason)``; the plugin maps those onto outcomes. "No reply"
is judged over the ACK window, never the 100 ms ACK deadline (D-6); "a reply" is awaited
across the runner's own retransmissions, every --rto, as a manager would (MCP-ACK-1).
"""

from __future__ import annotations

import contextlib
import socket
import statistics
import time
import weakref
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from mcp_conform.conformance._case_base import DatagramCaseBase
from mcp_conform.harness.driver import Datagram, Exchange, Sent, read_header
from mcp_conform.harness.errors import CaseFailure, Inconclusive, NodeLost, SilenceUnproven
from mcp_conform.harness.liveness import NOT_LIVE
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action

if TYPE_CHECKING:
    from mcp_conform.harness.drone_session import Session

MAX_ACK_COPIES = int(SPEC.params["max_ack_copies"])
DELIVERED = -1  # expect_delivered: reached the autopilot at least once (a node may forward twice: PAY-8's business)
NOT_AGAIN = 0  # expect_delivered: not delivered (again)
_UNFORWARDED: weakref.WeakKeyDictionary[Any, str] = weakref.WeakKeyDictionary()


@dataclass(frozen=True)
class Probe:
    """A Mav_Passthrough message carrying a vehicle-recognisable frame (a token)."""

    token: str
    frame: bytes


@dataclass(frozen=True)
class Altered:
    """Bytes that reached the autopilot instead of a probe's frame (MCP-PAY-8)."""

    raw: bytes  # what arrived (as much as the vehicle kept)
    how: str  # how it differs from the frame sent (judge.monitor.alteration)
    why: str  # why it did not parse, as the vehicle's parser said


@dataclass
class Delivery:
    """A probe sent and what the vehicle counted of its token before and after."""

    probe: Probe
    exchange: Exchange
    before: int
    after: int = -1
    waited: float = 0.0  # how long ``settle`` waited for it (s), and the node's pending action seen
    pending: str | None = None

    @property
    def delivered(self) -> int:
        return self.after - self.before


@dataclass
class Attempt:
    """One malformed or unexpected input and the liveness probe that followed it."""

    label: str
    input: Sent
    probe: Exchange | None
    died: bool = False
    rule: str | None = None  # the rule a death on this input breaks, when not the case's


def _hex(data: bytes, limit: int = 48) -> str:
    h = data[:limit].hex(" ")
    return h + (f" ... ({len(data)} bytes)" if len(data) > limit else f" ({len(data)} bytes)")


class CaseContext(DatagramCaseBase):
    """What a case sees of the node under test."""

    session: Session

    def __init__(self, session: Session, case_id: str, rules: tuple[str, ...]) -> None:
        assert session.driver is not None
        super().__init__(session, case_id, rules)
        self.driver = session.driver
        self.mark = self.driver.mark()
        self._probe_n = 0
        #: beside other cases (the schedule's batch): holds their sends back (``in_a_row``)
        self.hold_others: Any = None

    # ------------------------------------------------------------------ facts
    @property
    def target_id(self) -> int:
        return self.session.target_id if self.session.target_id is not None else 1

    @property
    def vehicle(self) -> Any:
        return self.session.vehicle

    @property
    def startup(self) -> Any:
        return self.session.startup

    def other_id(self) -> int:
        """An MCP ID that is neither the node's, the manager's nor the broadcast ID."""
        for cand in (self.target_id + 1, self.target_id + 2, 0x0ABC):
            cand &= 0xFFFF
            if cand not in (0, self.target_id, self.broadcast_id):
                return cand
        return 0x0ABD

    def fresh_node_after(self) -> None:
        """This case leaves the node in a state later cases must not inherit (spawn mode
        restarts it; attach mode cannot)."""
        self.restart_if_failed = True

    # ------------------------------------------------------------------ skips
    def require_observable(self, rule: str) -> None:
        """SKIP with the spec's reason when ``rule`` cannot be observed for this role."""
        obs = SPEC.rule(rule).observe.get(self.role)
        if obs is None:
            raise Inconclusive(f"{rule} does not apply to a {self.role} node")
        if obs.observable == "none":
            raise Inconclusive(f"{rule} is not observable on a {self.role} node: {obs.reason}")
        if obs.observable == "vehicle":
            self.require_vehicle(rule)

    def require_vehicle(self, rule: str) -> None:
        if self.vehicle is None:
            mode = self.session.cfg.mode
            why = ("attach mode has no view of the node's autopilot" if mode == "attach"
                   else "the run has no simulated vehicle (use --mavlink)")
            raise Inconclusive(f"{rule} is observed on the node's MAVLink link: {why}")
        if not self.vehicle.connections:
            raise Inconclusive(f"{rule}: the node never connected to the simulated vehicle "
                               "(does its command line use {mavlink}?)")

    def require_startup(self, rule: str) -> Any:
        st = self.startup
        if not st.observed:
            raise Inconclusive(f"{rule} is judged on the node's startup: {st.reason or 'not observed'}")
        return st

    def require_passthrough(self, rule: str, *, altered: bool = False) -> None:
        """SKIP unless the node forwards Mav_Passthrough frames to its autopilot (learnt once).
        A node whose frames reach the autopilot altered (``altered_arrival``) forwards no
        intact frame, so delivery stays unobservable, except (``altered``) to MCP-PAY-8,
        which judges exactly that."""
        self.require_vehicle(rule)
        with self.session.capability_lock:  # learnt once, whichever case asks first (cases may run together)
            self.learn_passthrough(rule)
        if self.session.passthrough_forwarded or (altered and self.session.passthrough_altered):
            return
        if self.session.passthrough_altered:
            raise Inconclusive(f"{rule}: the node's Mav_Passthrough frames reach its autopilot altered "
                               "(MCP-PAY-8), so delivery to its application is unobservable")
        raise Inconclusive(f"{rule}: the node forwarded no Mav_Passthrough frame to its autopilot"
                           f"{_UNFORWARDED.get(self.session, '')}, so delivery to its application is unobservable")

    def learn_passthrough(self, rule: str) -> None:
        """Whether the node forwards Mav_Passthrough frames (``session.passthrough_forwarded``,
        learnt once by a probe); Inconclusive when the probe was not ACKed (not learnt).
        An incomplete frame the vehicle still holds (an altered frame a moment ago) is waited
        out first, so the probe's bytes are not read as its tail."""
        if self.session.passthrough_forwarded is None:
            self._wait_held_reported()
            d = self.deliver(self.probe())
            self.session.passthrough_forwarded = d.exchange.acked and d.delivered > 0
            if not d.exchange.acked:
                self.session.passthrough_forwarded = None
                raise Inconclusive(f"{rule}: the passthrough capability probe was not ACKed")
            if not self.session.passthrough_forwarded:
                self.session.passthrough_altered = self.altered_arrival(d) is not None
                busy = (f"; the vehicle showed an earlier command still in progress meanwhile ({d.pending}): "
                        "the node may have been busy" if d.pending else "")
                _UNFORWARDED[self.session] = (f" within {d.waited:.1f} s of the capability probe's ACK "
                                              f"(probe {d.probe.token}, seq {d.exchange.seq}){busy}")

    def _wait_held_reported(self) -> None:
        """Until the vehicle holds no incomplete frame (it reports one as unparsed ``STALE``
        after its last byte); at most 2 x STALE + 2 s, a loaded host delaying its tick thread."""
        from mcp_conform.vehicle.codec import STALE

        v = self.vehicle
        v.wait_for(lambda: v.holding() == 0, 2 * STALE + 2.0)

    def altered_arrival(self, d: Delivery) -> Altered | None:
        """MCP-PAY-8: bytes that reached the autopilot since ``d``'s probe was sent, did not
        parse, and are an altered form of its frame (truncated, bits changed; the trace
        monitor's comparison, ``judge.monitor.alteration``); None when nothing like it came.
        An incomplete frame the vehicle still holds is waited for (``_wait_held_reported``: 0.5 s
        was a thin margin beside ten busy test workers); the wait ends at once when nothing is
        held."""
        from mcp_conform.judge.monitor import alteration

        self._wait_held_reported()
        for u in self.vehicle.unparsed(since=d.exchange.first.t):
            how = alteration(d.probe.frame, u.raw)
            if how is not None:
                return Altered(u.raw, how if u.length == len(u.raw) else f"{how}; {u.length} bytes, "
                               f"the first {len(u.raw)} kept", u.reason)
        return None

    # ------------------------------------------------------------------ sending
    def send(self, action: Action, payload: Any = None, dst: int | None = None, **kw: Any) -> Sent:
        return self.driver.send(action, payload, self.target_id if dst is None else dst, **kw)

    def send_raw(self, data: bytes) -> Sent:
        return self.driver.send_raw(data)

    def resend(self, sent: Sent) -> Sent:
        return self.driver.resend(sent)

    def in_a_row(self) -> contextlib.AbstractContextManager[Any]:
        """A block whose messages reach the node with nothing of other cases' between them,
        as when the case runs alone (beside the batch's cases, conformance._batch.InARow)."""
        return self.hold_others() if self.hold_others is not None else contextlib.nullcontext()

    def await_ack(self, sent: Sent, copies: int = MAX_ACK_COPIES) -> Exchange:
        """Await the ACK of ``sent``, retransmitting it every --rto (a manager's behaviour)."""
        return self.driver.exchange(sent, rto=self.rto, copies=copies, tail=self.ack_window)

    def command(self, action: Action, payload: Any = None, dst: int | None = None, **kw: Any) -> Exchange:
        return self.await_ack(self.send(action, payload, dst, **kw))

    def probe(self) -> Probe:
        from mcp_conform.vehicle import make_probe

        self._probe_n += 1
        token = f"{self.case_id[-24:]}-{self._probe_n}-{self.driver.peek_seq()}"
        token = "".join(c if 33 <= ord(c) <= 126 else "_" for c in token)[-41:]
        return Probe(token, make_probe(token))

    def deliver(self, probe: Probe, *, seq: int | None = None, src: int | None = None,
                dst: int | None = None, wait_delivery: bool = True) -> Delivery:
        """Send ``probe`` in a Mav_Passthrough command, await its ACK and the vehicle's count."""
        before = self.vehicle.probe_count(probe.token)
        ex = self.command(Action.MAV_PASSTHROUGH, probe.frame, dst, seq=seq, src=src)
        d = Delivery(probe, ex, before)
        if wait_delivery:
            self.settle(d)
        return d

    def settle(self, *deliveries: Delivery, expect_more: bool = False) -> None:
        """Let the vehicle's counts settle: until each probe arrived (or the window ends);
        with ``expect_more`` the whole window is watched (to see a count that must not grow)."""
        v = self.vehicle
        if expect_more:  # a count that must not grow: watched over the ACK window (D-6)
            self.driver.pause(self.ack_window)
        else:  # a count that must grow: returns as soon as it did; patient, since a node may queue
            # the forward behind slow autopilot work after its ACK (a take-off it waits out)
            waited, pending = self.await_past_pending(
                lambda: all(v.probe_count(d.probe.token) > d.before for d in deliveries),
                max(2 * self.ack_window, 1.0, self.rto))
            for d in deliveries:
                d.waited, d.pending = waited, pending
        for d in deliveries:
            d.after = v.probe_count(d.probe.token)

    def await_past_pending(self, done: Callable[[], bool], window: float,
                           pause: Callable[[float], object] | None = None) -> tuple[float, str | None]:
        """Until ``done()``, at most ``window`` s past the node's pending actions as the vehicle
        shows them (``SimVehicle.wait_past_pending``: a take-off short of its altitude, an AUTO
        mission flying; a node may be busy, D-6, and acts once they are done, MCP-BLK-7), for
        that never past half the case's limit. (s waited, first pending action seen)."""
        bound = self.start_t + float(self.session.cfg.per_case_limit()) / 2
        return self.vehicle.wait_past_pending(done, window, bound, pause or self.driver.pause)

    def quiet_count(self, token: str) -> int:
        """The vehicle's count of ``token`` once it has not changed for half the ACK window
        (at most one ACK window in all)."""
        v = self.vehicle
        stable = max(self.ack_window / 2, 0.1)
        deadline = self.session.clock.monotonic() + max(self.ack_window, 2 * stable)
        count, since = v.probe_count(token), self.session.clock.monotonic()
        while self.session.clock.monotonic() < deadline:
            self.driver.pause(0.02)
            now_count = v.probe_count(token)
            if now_count != count:
                count, since = now_count, self.session.clock.monotonic()
            elif self.session.clock.monotonic() - since >= stable:
                break
        return count

    def redeliver(self, d: Delivery, sent: Sent, *, watch: bool = True) -> Delivery:
        """Send a copy of ``sent`` (same bytes, same seq) and await its ACK and (``watch``;
        else the caller's ``settle``) the count. The baseline is taken once the earlier
        delivery's count has stopped moving, so a node that forwards each frame twice
        (MCP-PAY-8's business) is not taken for one that delivers the copy again (MCP-DUP-1)."""
        before = self.quiet_count(d.probe.token)
        ex = self.await_ack(self.resend(sent))
        out = Delivery(d.probe, ex, before)
        if watch:
            self.settle(out, expect_more=True)
        return out

    def liveness(self) -> Exchange:
        """Is the node still there? A fresh WP_Off awaited across retransmissions; ANY reply
        attributable to it counts (MCP-ROB-5). Its form is judged by the ACK cases alone, so
        a malformed ACK is reported once, under its own rule."""
        return self.command(Action.WP_OFF)

    # ------------------------------------------------------------------ proof of life
    def _not_live(self, ex: Exchange | None, exc: NodeLost | None) -> list[str]:
        """Evidence that the node did not answer a proof-of-life probe; the session learns
        the node is gone (attach: the remaining cases are errors; spawn: a restart)."""
        self.session.declare_not_live("the node did not answer a liveness probe in an earlier case")
        if exc is not None:
            return list(exc.evidence)
        ev = []
        if ex is not None:
            ev.append(f"liveness probe WP_Off seq {ex.seq}: {len(ex.copies)} copies "
                      f"{self.rto:g} s apart, unanswered")
        return ev + self.session.node_evidence()

    def prove_live(self, why: str = NOT_LIVE) -> Exchange:
        """Proof of life: a fresh WP_Off must be ACKed, or the case is an ``error`` (never a
        verdict): right after a "no reply" window (silence from a dead node proves nothing),
        before a verdict on a missing reply, before an input whose effect is judged. A node
        whose process ended is named as such (``NodeLost``, its exit status), not as silent."""
        try:
            ex = self.liveness()
        except NodeLost as exc:
            ev = self._not_live(None, exc)
            if exc.process_exited:  # dead, not silent: the case ends naming the exit
                raise
            raise SilenceUnproven(why, ev) from None
        if not ex.acked:
            raise SilenceUnproven(why, self._not_live(ex, None))
        return ex

    def probe_after_input(self) -> tuple[Exchange | None, bool]:
        """The liveness probe that follows an input: (its exchange, the process died).
        A loss declared meanwhile is the input's consequence here, not an error."""
        try:
            probe: Exchange | None = self.liveness()
        except NodeLost as exc:
            ex = exc.exchange
            return (ex if isinstance(ex, Exchange) else None), (exc.process_exited or not self.session.alive())
        return probe, not self.session.alive()

    def try_inputs(self, inputs: Iterable[tuple[str, bytes] | tuple[str, bytes, str]]) -> list[Attempt]:
        """Send each raw input, each followed by a liveness probe; stop at the first death
        or silence (the node is then restarted or lost, and later inputs are moot). An input
        may name the rule a death on it breaks (label, data, rule). The node is proven live
        just before the first input, so a death is blamed on an input only when it follows it."""
        out: list[Attempt] = []
        self.prove_live("node not live before this case's first input: nothing to judge")
        for label, data, *rule in inputs:
            sent = self.send_raw(data)
            if not self.session.alive():
                out.append(Attempt(label, sent, None, died=True, rule=rule[0] if rule else None))
                break
            probe, died = self.probe_after_input()
            out.append(Attempt(label, sent, probe, died, rule[0] if rule else None))
            if died or probe is None or not probe.acked:
                self.node_silent = not died
                if probe is None and not died:
                    out[-1].died = True  # lost before its probe could even be sent
                break
        return out

    # ------------------------------------------------------------------ verify helpers
    def fail(self, rule: str, expected: str, actual: str, evidence: Sequence[str] = (), *,  # type: ignore[override]
             relies_on: tuple[str, ...] | None = None) -> CaseFailure:
        """The failure of ``rule``; ``relies_on``: see ``CaseFailure`` (default: the spec's)."""
        ev = list(evidence)
        if self.session.node is not None and (not self.session.alive() or self.node_silent):
            ev += self.session.node_evidence()
        return CaseFailure(rule, expected, actual, ev, relies_on)

    def expect_acked(self, exchanges: Sequence[tuple[str, Exchange]], rule: str = "MCP-ACK-1") -> None:
        """Each command was answered: a reply attributable to it (judge.attribution)
        arrived within MAX_ACK_COPIES copies, one every --rto. Its form is not judged here."""
        missing = [(label, ex) for label, ex in exchanges if not ex.acked]
        if missing:
            self.prove_live("node lost during this case: it answers no liveness probe either")
            label, ex = missing[0]
            if not self.session.alive():
                self.node_silent = False
            raise self.fail(rule, f"an ACK of seq {ex.seq} for {label}",
                            f"nothing attributable to it after {len(ex.copies)} copies sent {self.rto:g} s apart",
                            [f"{lbl}: seq {e.seq}, {len(e.copies)} copies, unanswered" for lbl, e in missing]
                            + self._stray_replies(ex))

    def _stray_replies(self, ex: Exchange, limit: int = 3) -> list[str]:
        """ACK-like datagrams that arrived while ``ex`` waited but were not tied to it."""
        out: list[str] = []
        for d in self.driver.received(self.driver.mark_before(ex.first)):
            if d.is_ack_like and len(out) < limit:
                a = self.driver.attribution(d)
                where = a.describe() if a is not None else "attributable to no command awaiting an answer"
                out.append(f"reply {d.describe()}: {where}")
        return out

    def expect_ack_format(self, exchanges: Sequence[Exchange], rule: str) -> None:
        """ACK form, judged on replies attributed to their command (judge.attribution):
        MCP-ACK-2 payload = 2-byte big-endian seq; MCP-ACK-3 dst/src. A reply whose
        attribution is ambiguous is not judged (the ambiguity is noted)."""
        acked = [ex for ex in exchanges if ex.ack is not None]
        if not acked:
            raise Inconclusive(f"{rule}: the node answered none of the commands, so no ACK could be judged")
        clear = [ex for ex in acked if ex.attribution is None or not ex.attribution.ambiguous]
        for ex in acked:
            if ex not in clear:
                assert ex.attribution is not None
                self.not_judged(f"the reply to seq {ex.seq} was not judged: {ex.attribution.describe()}")
        if not clear:
            raise Inconclusive(f"{rule}: which command each reply answers is ambiguous, so no ACK's "
                               f"form could be judged ({len(acked)} replies)")
        for ex in clear:
            d = ex.ack
            assert d is not None and d.header is not None
            dst, src, _, _ = d.header
            how = [f"reply: {d.describe()}", f"to: seq {ex.seq}, {_hex(ex.first.data)}"]
            if ex.attribution is not None:
                how.append(ex.attribution.describe())
            if rule == "MCP-ACK-2":
                payload = d.data[17:]
                if len(payload) != 2 or int.from_bytes(payload, "big") != ex.seq:
                    named = (f"names seq {int.from_bytes(payload, 'big')} (0x{payload.hex()})" if len(payload) == 2
                             else f"is {len(payload)} bytes ({payload[:8].hex(' ') or 'empty'})")
                    raise self.fail(rule, f"payload {ex.seq.to_bytes(2, 'big').hex(' ')} (seq {ex.seq}, big-endian, 2 bytes)",
                                    f"payload {named}, the command's seq is {ex.seq} (0x{ex.seq:04x})", how)
            elif rule == "MCP-ACK-3":
                if dst != ex.first.src or src != self.target_id:
                    raise self.fail(rule, f"dst={ex.first.src} (the acknowledged message's src), src={self.target_id} (the node)",
                                    f"dst={dst}, src={src}", how)

    def expect_silence(self, sents: Sequence[Sent], rule: str, *, also_not_delivered: Sequence[Probe] = (),
                       within: float | None = None) -> None:
        """No reply attributable to any of ``sents`` over the ACK window (D-6); probes not
        forwarded."""
        window = self.ack_window if within is None else within
        since = min(self.driver.mark_before(s) for s in sents)
        self.driver.pause(max(0.0, sents[-1].t + window - self.session.clock.monotonic()))
        answers = self.driver.answers(sents, since)
        for _, a in answers:
            if a.ambiguous:
                self.not_judged(f"a reply was not judged: {a.describe()}")
        answers = [(d, a) for d, a in answers if not a.ambiguous]
        if answers:
            d, a = answers[0]
            which = next(s for s in sents if s.command == a.command)
            raise self.fail(rule, f"no ACK of seq {which.seq} within {window:g} s",
                            f"ACK received {d.t - which.t:.3f} s after it",
                            [f"sent: {_hex(which.data)}", f"reply: {d.describe()}", a.describe()])
        for p in also_not_delivered:
            if self.vehicle.probe_count(p.token) > 0:  # tokens are fresh: any arrival is a delivery
                raise self.fail(rule, f"the frame of probe {p.token} not forwarded to the autopilot",
                                "the node forwarded it", [f"token {p.token}"])
        self.prove_live()  # silence is a verdict only from a node shown alive after the window

    def expect_each_copy_acked(self, first: Exchange, copies: Sequence[Exchange], rule: str = "MCP-ACK-1") -> None:
        if not first.acked or not all(ex.acked for ex in copies):
            self.prove_live("node lost during this case: it answers no liveness probe either")
        if not first.acked:
            raise self.fail(rule, f"an ACK of seq {first.seq}", "no ACK of the first copy")
        for n, ex in enumerate(copies, start=2):
            if not ex.acked:
                raise self.fail(rule, f"copy #{n} of seq {ex.seq} (same bytes) ACKed again",
                                f"no ACK after it ({len(ex.copies)} copies, {self.rto:g} s apart)")

    def expect_discarded(self, attempts: Sequence[Attempt], rule: str, *, died_rule: str | None = None,
                         live_rule: str = "MCP-ROB-5", silent: bool = True) -> None:
        """Every input was dropped silently (no ACK naming its seq) and the node stayed live;
        with ``silent=False`` only survival is judged."""
        if not attempts:
            raise Inconclusive(f"{rule}: no input was sent")
        last = attempts[-1]
        if last.died:
            raise self.fail(last.rule or died_rule or rule, f"the node survives input {last.label!r}",
                            f"the node exited after it (code {self.session.node.returncode if self.session.node else '?'})",
                            [f"input: {_hex(last.input.data)}"], relies_on=())
        if last.probe is not None and not last.probe.acked:
            raise self.fail(live_rule, f"an ACK of the next valid unicast after input {last.label!r}",
                            f"no ACK of seq {last.probe.seq} after {len(last.probe.copies)} copies",
                            [f"input: {_hex(last.input.data)}"])
        if not silent:
            return
        since = self.driver.mark_before(attempts[0].input)
        self.driver.pause(max(0.0, attempts[-1].input.t + self.ack_window - self.session.clock.monotonic()))
        for a in attempts:
            hdr = read_header(a.input.data)
            if hdr is None:
                continue
            dst, src, seq, _ = hdr
            probe_seqs = {x.probe.seq for x in attempts if x.probe is not None}
            if seq in probe_seqs:
                continue
            replies = [(d, self.driver.attribution(d)) for d in self.driver.received(since)]
            replies = [(d, att) for d, att in replies
                       if (att is not None and att.command == a.input.command and not att.ambiguous)
                       or (att is None and d.names_seq(seq) and d.header is not None and d.header[0] == src)]
            if replies:
                d, att = replies[0]
                raise self.fail(rule, f"input {a.label!r} (seq {seq}) discarded without ACK",
                                "the node ACKed it", [f"input: {_hex(a.input.data)}", f"reply: {d.describe()}"]
                                + ([att.describe()] if att is not None else []), relies_on=())
        self.prove_live()  # "no ACK" is a verdict only from a node shown alive after the window

    def expect_delivered(self, deliveries: Sequence[tuple[Delivery, int]], rule: str) -> None:
        """Each probe reached the autopilot the expected number of times (0: not delivered).
        Under MCP-PAY-8 ("A drone linked to an autopilot forwards each delivered
        Mav_Passthrough frame to it exactly once."), a probe that never arrived intact but
        arrived altered (``altered_arrival``) fails, with the frame sent and what arrived."""
        for d, want in deliveries:
            if not d.exchange.acked:
                raise Inconclusive(f"{rule}: probe {d.probe.token} (seq {d.exchange.seq}) was not ACKed, "
                                   "so its delivery cannot be judged")
            got = d.delivered
            ok = (got == want) if want >= 0 else got > 0
            if not ok and got == 0 and rule == "MCP-PAY-8":
                self._expect_intact(d, rule)
            if not ok:
                what = {NOT_AGAIN: "not delivered (again)", DELIVERED: "delivered",
                    1: "delivered exactly once"}.get(want, f"delivered {want} times")
                raise self.fail(rule, f"probe {d.probe.token} (src {d.exchange.first.src}, seq {d.exchange.seq}) {what}",
                                f"the vehicle received its frame {got} more time(s)")
        if any(want == NOT_AGAIN for _, want in deliveries):
            self.prove_live()  # "not delivered again" is silence: proven only by a live node

    def _expect_intact(self, d: Delivery, rule: str) -> None:
        """Fail ``rule`` when ``d``'s probe reached the autopilot altered; SKIP when nothing
        of it arrived from a node never seen forwarding a frame intact (delivery is then
        unobservable)."""
        from mcp_conform.judge.monitor import frame_hex

        alt = self.altered_arrival(d)
        if alt is None:
            if self.session.passthrough_forwarded:
                return  # it forwards frames, not this one: judged as not delivered
            raise Inconclusive(f"{rule}: nothing of probe {d.probe.token} (seq {d.exchange.seq}) reached "
                               "the autopilot, intact or altered: the node forwarded no frame")
        raise self.fail(rule, f"the frame of probe {d.probe.token} (seq {d.exchange.seq}) forwarded as sent: "
                        f"{frame_hex(d.probe.frame)}",
                        f"{frame_hex(alt.raw)} arrived instead ({alt.how})",
                        [f"the vehicle's parser: {alt.why}", f"token {d.probe.token}"])

    def expect_monitor_clean(self, rule: str) -> None:
        """The trace monitor, which watches every datagram of the run, found no violation of
        ``rule`` by the node (judge.run_monitor); its first violation fails the case
        with the monitor's expected, actual and evidence."""
        mon = self.session.monitor
        if mon is None:
            return
        found = mon.violations(rule, self.target_id)
        if found:
            v = found[0]
            ev = [f"datagram #{i} of the run at {time.strftime('%H:%M:%S', time.localtime(t / 1e9))}"
                  f".{t // 1_000_000 % 1000:03d}" for i, t in v.evidence[:4]]
            raise self.fail(rule, v.expected, v.actual + (f" (and {len(found) - 1} more)" if len(found) > 1 else ""),
                            ["trace monitor: " + e for e in ev])

    def expect_median_latency(self, samples: Sequence[float], limit: float, rule: str) -> None:
        if len(samples) < int(SPEC.params["ack_latency_samples"]):
            raise Inconclusive(f"{rule}: only {len(samples)} unambiguous ACK latency samples")
        med = statistics.median(samples)
        self.info(f"ACK latency: median {med * 1000:.2f} ms over {len(samples)} samples "
                  f"(max {max(samples) * 1000:.2f} ms)")
        if med > limit:
            raise self.fail(rule, f"median ACK latency <= {limit * 1000:.0f} ms",
                            f"median {med * 1000:.1f} ms over {len(samples)} samples",
                            [f"samples (ms): {', '.join(f'{s * 1000:.1f}' for s in samples)}"])

    # ------------------------------------------------------------------ other paths
    def command_from(self, sock: socket.socket, action: Action, payload: Any = None) -> tuple[Sent, Datagram | None]:
        """Send a command from another socket (another source port, MCP-TRN-2) and await an
        ACK arriving at either socket, retransmitting every --rto."""
        first = self.driver.send(action, payload, self.target_id, sock=sock)
        match = self.driver.answered(first)
        for n in range(MAX_ACK_COPIES):
            deadline = self.session.clock.monotonic() + self.rto
            since = self.driver.mark_before(first)
            while self.session.clock.monotonic() < deadline:
                got = self.driver.wait_for(match, 0.02, since)
                if got is not None:
                    return first, got
                try:
                    data, addr = sock.recvfrom(65535)
                except (TimeoutError, BlockingIOError):
                    continue
                d = Datagram(-1, self.session.clock.monotonic(), self.session.clock.time_ns(), data, addr, None, None, read_header(data))
                a = self.driver.attribute_external(d)
                if a is not None and a.command == first.command:
                    return first, d
            if n < MAX_ACK_COPIES - 1:
                self.driver.resend(first, sock=sock)
        return first, None

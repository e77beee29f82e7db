"""ACK — the manager acknowledging the drones' messages.

"Unicast MCP messages should be replied to with an MCP acknowledgement message."
"ACK: The payload is a sequence number for a previously received message, which is being
acknowledged." Observed on the drones' Mission_Ready (the first of each drone, a second
one with a new seq, liveness probes) and on inputs the runner sends on purpose.
"""

from __future__ import annotations

import math

from mcp_conform.conformance._batch import owes_ack
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.judge.monitor import late_ack_wait_s
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import MANAGER_ID, Action

_ACK = int(Action.ACK)
#: how far apart in time the runner's records of two datagrams may be ordered (D-9, MCP-SEQ-1)
_GRACE_S = float(SPEC.params["seq_reorder_grace_s"])


def _exchanges(m):
    out = [(f"Mission_Ready of drone {d}", ex) for d, ex in m.ready.items()]
    if m.duplicate is not None:
        out.append(("a second Mission_Ready (new seq)", m.duplicate))
    out += [(f"the probe after {i.label!r}", i.probe) for i in m.inputs if i.probe is not None]
    return out


def _went_on(m):
    """What the manager sent the drones during the mission: the evidence that it heard the
    Mission_Ready it did not ACK (a manager that sends nothing at all never answered)."""
    from mcp_conform.conformance.manager_case import messages

    msgs = messages(m)
    if not msgs:
        return []
    names = [f"{Action(x.action).name if 0 <= x.action <= 9 else x.action} to {x.dst} (seq {x.seq})"
             for x in msgs[:4]]
    return [f"meanwhile the manager went on with the mission: {len(msgs)} message(s) to the drones, "
            + ", ".join(names) + (", ..." if len(msgs) > 4 else "")]


def _runner_sent(node, m):
    """Every datagram the runner sent the manager during mission ``m``, copies included, in
    order (the driver's log: the mission keeps each number's first datagram only)."""
    drv = getattr(node.session, "driver", None)
    end = m.t_end or math.inf
    sent = [s for s in (drv.sent() if drv is not None else []) if m.t0 <= s.t <= end]
    return sent or sorted(m.sent_by_drones.values(), key=lambda s: s.t)


def _unanswered_copies(node, m, acks):
    """The copies of messages the drones sent the manager that drew no ACK naming their number
    within ``late_ack_wait_s`` (``acks``: the manager's ACKs), as (drone, time, Sent)."""
    wait = late_ack_wait_s(node.rto, node.ack_window)
    named = {}
    for d in acks:
        named.setdefault((d.header[0], d.acked_seq()), []).append(d.t)
    return [(s.src, s.t, s) for s in _runner_sent(node, m) if owes_ack(s, MANAGER_ID)
            and not any(s.t <= t <= s.t + wait for t in named.get((s.src, s.seq), ()))]


@rules("MCP-ACK-1")
def test_every_mission_ready_is_acked(node):
    """Each drone's Mission_Ready, a second one with a new seq, a copy of one (same seq and
    bytes), and the probes are ACKed (awaited across the runner's retransmissions). A manager
    that ACKs none but goes on with the mission fails here, with what it sent as evidence."""
    m = node.mission()
    missing = [(label, ex) for label, ex in _exchanges(m) if not ex.acked]
    copies = [i for i in m.inputs if i.rule == "MCP-ACK-1"]
    first = missing[0] if missing else None
    node.expect_true(first is None, "MCP-ACK-1", f"an ACK of {first[0] if first else ''}",
                     f"no ACK of seq {first[1].seq} after {len(first[1].copies)} copies {node.rto:g} s apart"
                     if first else "",
                     [f"{lbl}: seq {ex.seq}, {len(ex.copies)} copies, no ACK" for lbl, ex in missing[:3]]
                     + (_went_on(m) if first else []))
    bad = [i for i in copies if i.reply is None]
    node.expect_true(not bad, "MCP-ACK-1", "a copy of an ACKed Mission_Ready (same seq and bytes) ACKed again",
                     f"no ACK within {late_ack_wait_s(node.rto, node.ack_window):g} s",
                     [f"copy: {i.sent.data.hex(' ')}" for i in bad])


def _acks_of_nothing(node, m):
    """The manager's well-formed ACKs that name a number no datagram carried by the time they
    came (D-9: "MCP-ACK-2 is observed where an ACK names a number that no datagram to the node
    carried by the time it was sent"), with the records' reorder grace (``seq_reorder_grace_s``),
    on a complete trace (the runner's link not ``--impair``ed): each acknowledges no message,
    whatever copy it answered. A number any datagram carried -- the runner's, before or during
    the mission, or the manager's own -- is not proven so."""
    if not node.session.trace_complete:
        return []
    drv = getattr(node.session, "driver", None)
    carried = {}  # seq -> when a datagram first carried it
    for seq, t in ([(s.seq, s.t) for s in (drv.sent() if drv is not None else [])]
                   + [(s.seq, s.t) for s in m.sent_by_drones.values()]
                   + [(d.header[2], d.t) for d in m.from_manager() if d.header is not None]):
        carried[seq] = min(carried.get(seq, math.inf), t)
    return [(d, carried.get(d.msg.payload, math.inf)) for d in m.from_manager()
            if d.msg is not None and d.msg.action == _ACK and carried.get(d.msg.payload, math.inf) > d.t + _GRACE_S]


@rules("MCP-ACK-2")
def test_ack_payload_is_the_seq_big_endian(node):
    """The ACK attributed to each Mission_Ready and probe names its seq, 2 bytes big-endian; and
    no ACK names a number no datagram carried by then (D-9: it acknowledges no message). A
    manager whose every ACK names a wrong number has no ACK attributed to a Mission_Ready: the
    second part judges it (the C++ manager whose ACKs name the copy's seq + 1 was skipped
    "the manager ACKed nothing" after 148 ACKs)."""
    m = node.mission()
    acked = [ex for _, ex in _exchanges(m) if ex.ack is not None]
    for ex in acked:
        payload = ex.ack.data[17:]
        node.expect_true(len(payload) == 2 and int.from_bytes(payload, "big") == ex.seq, "MCP-ACK-2",
                         f"payload {ex.seq.to_bytes(2, 'big').hex(' ')} (seq {ex.seq}, 2 bytes big-endian)",
                         f"payload {payload.hex(' ') or '(empty)'} ({len(payload)} bytes)", [ex.ack.describe()])
    nothing = _acks_of_nothing(node, m)
    if nothing:
        d, when = nothing[0]
        before = [s for s in _runner_sent(node, m) if s.t <= d.t and s.src == d.msg.dst and s.action != _ACK]
        names = sorted({x.msg.payload for x, _ in nothing})
        raise node.fail("MCP-ACK-2", "each ACK names the acknowledged message's seq, 2 bytes big-endian (D-2)",
                        f"{len(nothing)} ACK(s) name a number no datagram carried by then: "
                        + ", ".join(map(str, names[:5])) + (", ..." if len(names) > 5 else ""),
                        [f"manager: {d.describe()}",
                         f"no datagram carried seq {d.msg.payload} "
                         + (f"until {when - d.t:.3f} s after it" if when < math.inf else "in the run")]
                        + ([f"it came {(d.t - before[-1].t) * 1000:.1f} ms after drone {before[-1].src}'s "
                            f"{Action(before[-1].action).name if 0 <= before[-1].action <= 9 else before[-1].action} "
                            f"seq {before[-1].seq}"] if before else []))
    if not acked:
        if any(d.is_ack_like for d in m.from_manager()):
            raise Inconclusive("MCP-ACK-2: no ACK of the manager named a Mission_Ready's or probe's seq in either "
                               "byte order, and each names a number some datagram carried before it (what it "
                               "answered is not proven: D-9)" if node.session.trace_complete else
                               "MCP-ACK-2: no ACK of the manager named a Mission_Ready's or probe's seq, and the "
                               "runner's link is impaired (--impair): a number no datagram carried proves nothing")
        raise Inconclusive("MCP-ACK-2: the manager ACKed nothing")


@rules("MCP-ACK-3")
def test_ack_is_addressed_to_the_drone_from_the_manager(node):
    """The ACK attributed to each Mission_Ready and probe goes to its drone, from ID 0. A manager
    whose ACKs are attributed to none (each names a wrong number: MCP-ACK-2's) is skipped
    saying so: which drone's message each answers is unknown (the C++ manager whose ACKs name
    the copy's seq + 1 was skipped "the manager ACKed nothing" after 148 ACKs)."""
    m = node.mission()
    acked = [ex for _, ex in _exchanges(m) if ex.ack is not None]
    if not acked:
        n = sum(1 for d in m.from_manager() if d.is_ack_like)
        raise Inconclusive(f"MCP-ACK-3: none of the manager's {n} ACK(s) was attributed to a drone's Mission_Ready "
                           "or a probe (by the seq it names or by its timing): which message, and so which drone, "
                           "each answers is unknown (see MCP-ACK-2)" if n else "MCP-ACK-3: the manager ACKed nothing")
    for ex in acked:
        dst, src, _, _ = ex.ack.header
        node.expect_true(dst == ex.first.src and src == MANAGER_ID, "MCP-ACK-3",
                         f"dst={ex.first.src} (the drone), src={MANAGER_ID}", f"dst={dst}, src={src}",
                         [ex.ack.describe()])


@rules("MCP-ACK-4")
def test_broadcast_is_not_acked(node):
    node.expect_not_acked(node.inputs("MCP-ACK-4"), "MCP-ACK-4")


@rules("MCP-ACK-5")
def test_message_to_another_id_is_not_acked(node):
    node.expect_not_acked(node.inputs("MCP-ACK-5"), "MCP-ACK-5")


@rules("MCP-ACK-6")
def test_an_ack_is_never_acked(node):
    """No ACK of the manager names the seq of an ACK a drone sent before it (the runner's drones
    number ACKs and messages from one counter each, so every seq names one datagram). An ACK
    that came after a copy of a drone's message that drew no ACK naming its number (within the
    wait of a late ACK) may be that copy's answer with a wrong number (MCP-ACK-2) as well as an
    ACK of the ACK: each explanation breaks another rule, so it proves neither (D-9's
    principle); the node's other ACKs judge it. The C++ manager whose ACKs name the copy's seq
    + 1 was failed on "80 ACK(s) of an ACK", every one sent before the drone's ACK took the
    number it named; and a later one, 0.2 ms after a Mission_Ready copy, may answer that copy."""
    m = node.mission()
    ours = {k: s for k, s in m.sent_by_drones.items() if s.action == _ACK}
    if not ours:
        raise Inconclusive("MCP-ACK-6: the drones sent no ACK")
    acks = [d for d in m.from_manager() if d.is_ack_like and d.header is not None and d.acked_seq() is not None]
    named = [(d, ours[k]) for d in acks for k in [(d.header[0], d.acked_seq())] if k in ours and ours[k].t <= d.t]
    wait = late_ack_wait_s(node.rto, node.ack_window)
    copies = _unanswered_copies(node, m, acks) if named else []
    bad, doubt = [], []
    for d, a in named:
        c = next((c for src, t, c in reversed(copies) if src == d.header[0] and t <= d.t <= t + wait), None)
        (bad if c is None else doubt).append((d, a, c))
    if not bad and doubt:
        d, a, c = doubt[0]
        raise Inconclusive(f"MCP-ACK-6: {len(doubt)} ACK(s) of the manager name the seq of an ACK a drone sent "
                           f"before them, each after a copy of a drone's message that drew no ACK naming its "
                           f"number: the copy's answer with a wrong number (MCP-ACK-2) or an ACK of the ACK, "
                           f"neither proven (D-9); first: {d.describe()}, {(d.t - c.t) * 1000:.1f} ms after a "
                           f"copy of seq {c.seq} from drone {c.src}, {(d.t - a.t) * 1000:.1f} ms after the ACK")
    first = bad[0] if bad else None
    node.expect_true(first is None, "MCP-ACK-6", f"none of the {len(ours)} ACKs of the drones ACKed",
                     f"{len(bad)} ACK(s) of an ACK" if bad else "",
                     [f"drone's ACK: {first[1].data.hex(' ')}",
                      f"manager: {first[0].describe()}, {(first[0].t - first[1].t) * 1000:.1f} ms after it"]
                     + ([f"{len(doubt)} more name an ACK's seq right after a copy of a drone's message that "
                         "drew no ACK naming its number (each also that copy's wrong ACK: not counted, D-9)"]
                        if doubt else [])
                     if first is not None else [])


@rules("MCP-ACK-7")
def test_ack_latency(node):
    m = node.mission()
    limit = float(SPEC.params["ack_deadline_s"])
    samples = m.ack_latencies()
    if len(samples) < int(SPEC.params["ack_latency_samples"]):
        raise Inconclusive(f"MCP-ACK-7: only {len(samples)} unambiguous ACK latency samples")
    import statistics

    med = statistics.median(samples)
    node.info(f"ACK latency: median {med * 1000:.2f} ms over {len(samples)} samples (max {max(samples) * 1000:.2f} ms)")
    node.expect_true(med <= limit, "MCP-ACK-7", f"median ACK latency <= {limit * 1000:.0f} ms",
                     f"median {med * 1000:.1f} ms over {len(samples)} samples")

"""ACK — the manager acknowledging the drones' messages.

"Unicast MCP messages should be replied to with an MCP acknowledgement message."
"ACK: The payload is a sequence number for a previously received message, which is being
acknowledged." Observed on the drones' Mission_Ready (the first of each drone, a second
one with a new seq, liveness probes) and on inputs the runner sends on purpose.
"""

from __future__ import annotations

from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.judge.monitor import late_ack_wait_s
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import MANAGER_ID, Action


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


@rules("MCP-ACK-2")
def test_ack_payload_is_the_seq_big_endian(node):
    m = node.mission()
    acked = [ex for _, ex in _exchanges(m) if ex.ack is not None]
    if not acked:
        raise Inconclusive("MCP-ACK-2: the manager ACKed nothing")
    for ex in acked:
        payload = ex.ack.data[17:]
        node.expect_true(len(payload) == 2 and int.from_bytes(payload, "big") == ex.seq, "MCP-ACK-2",
                         f"payload {ex.seq.to_bytes(2, 'big').hex(' ')} (seq {ex.seq}, 2 bytes big-endian)",
                         f"payload {payload.hex(' ') or '(empty)'} ({len(payload)} bytes)", [ex.ack.describe()])


@rules("MCP-ACK-3")
def test_ack_is_addressed_to_the_drone_from_the_manager(node):
    m = node.mission()
    acked = [ex for _, ex in _exchanges(m) if ex.ack is not None]
    if not acked:
        raise Inconclusive("MCP-ACK-3: the manager ACKed nothing")
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
    """No ACK of the manager names the seq of an ACK a drone sent (the runner's drones
    number ACKs and messages from one counter each, so every seq names one datagram)."""
    m = node.mission()
    ours = {k: s for k, s in m.sent_by_drones.items() if s.action == int(Action.ACK)}
    if not ours:
        raise Inconclusive("MCP-ACK-6: the drones sent no ACK")
    bad = [d for d in m.from_manager() if d.is_ack_like and d.header is not None
           and (d.header[0], d.acked_seq()) in ours]
    d = bad[0] if bad else None
    node.expect_true(d is None, "MCP-ACK-6", f"none of the {len(ours)} ACKs of the drones ACKed",
                     f"{len(bad)} ACK(s) of an ACK" if bad else "",
                     [f"drone's ACK: {ours[(d.header[0], d.acked_seq())].data.hex(' ')}", f"manager: {d.describe()}"]
                     if d is not None else [])


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

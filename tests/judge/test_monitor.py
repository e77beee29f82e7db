"""The trace monitor on scripted whole missions: clean ones raise nothing, each faulty one
raises exactly its rule (tests/judge/monitor_faults.py), on complete and lossy traces.
"""

from __future__ import annotations

import pytest

from mcp_conform.judge.monitor import MONITORED_RULES, TESTER, Monitor, Violation
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action, DecodeError, Message, decode, encode
from tests.judge.monitor_faults import FAULTY
from tests.judge.monitor_scripts import Script, clean_script


def _rules(violations: list[Violation]) -> list[tuple[str, int, str]]:
    return [(v.rule, v.node, v.actual) for v in violations]


# ---------------------------------------------------------------- clean missions
@pytest.mark.parametrize("complete", [True, False], ids=["complete", "lossy"])
@pytest.mark.parametrize("challenge", [1, 2, 3])
@pytest.mark.parametrize("drones", [(1, 2), (1, 2, 3), (7, 300, 4242)])
def test_a_clean_mission_raises_nothing(challenge, drones, complete):
    s = clean_script(challenge, drones=drones, seed=challenge * 10 + len(drones))
    assert _rules(s.judge(complete=complete)) == []
    verdicts = s.last_monitor.verdicts()
    assert set(verdicts) == {0, *drones}
    for node, table in verdicts.items():
        assert not {r: v for r, v in table.items() if v in ("failed", "warned")}, node


@pytest.mark.parametrize("complete", [True, False], ids=["complete", "lossy"])
@pytest.mark.parametrize("kw", [
    {"lost_acks": 1},  # every command's first ACK lost: a retransmission after an ACK
    {"deaf": 2},  # every command's receiver misses two copies
    {"deaf": 1, "lost_acks": 2},
], ids=["lost-acks", "deaf", "both"])
def test_retransmissions_and_lost_acks_are_normal(kw, complete):
    for challenge in (1, 2, 3):
        s = Script((1, 2), challenge=challenge, seed=challenge)
        s.mission(**kw)
        assert _rules(s.judge(complete=complete)) == [], challenge


@pytest.mark.parametrize("ack_numbers", [True, False], ids=["acks-numbered", "acks-unnumbered"])
def test_sequence_numbers_wrap_and_start_anywhere(ack_numbers):
    for start in (65530, 65535, 0, 12345):
        s = Script((1, 2), challenge=2, seqs={0: start, 1: 65535, 2: start ^ 0x5555},
                   ack_numbers=ack_numbers)
        s.mission()
        assert _rules(s.judge()) == [], start
        assert s.last_monitor.verdicts()[0]["MCP-SEQ-1"] == "passed"


def test_a_clean_mission_is_observed_rule_by_rule():
    s = Script((1, 2, 3), challenge=1)
    s.mission(lost_acks=1)
    s.judge()
    v = s.last_monitor.verdicts()
    for rule in ("MCP-HDR-1", "MCP-HDR-5", "MCP-SEQ-1", "MCP-SEQ-2", "MCP-BLK-1", "MCP-BLK-2",
                 "MCP-RTX-1", "MCP-PAY-1", "MCP-PAY-3", "MCP-PAY-6", "MCP-PAY-7", "MCP-FLOW-2",
                 "MCP-FLOW-3", "MCP-FLOW-4", "MCP-ACK-1", "MCP-ACK-5"):
        if SPEC.rule(rule).applies_to("manager"):
            assert v[0][rule] == "passed", rule
    for rule in ("MCP-ACK-1", "MCP-ACK-2", "MCP-ACK-3", "MCP-ACK-7", "MCP-FLOW-1", "MCP-PAY-2",
                 "MCP-BLK-4", "MCP-BLK-5", "MCP-BLK-7", "MCP-PAY-8"):
        assert v[2][rule] == "passed", rule
    assert v[1]["MCP-SEQ-4"] == "info"
    assert v[1]["MCP-ROB-7"] == "not_observed"  # liveness is the runner's
    assert "MCP-PAY-3" not in v[1] and "MCP-BLK-4" not in v[0]


# ---------------------------------------------------------------- faulty missions
@pytest.mark.parametrize("name", sorted(FAULTY))
def test_a_faulty_mission_raises_exactly_its_rule(name):
    fault = FAULTY[name]
    s = fault.build()
    violations = s.judge(complete=fault.complete)
    assert {v.rule for v in violations} == {fault.rule}, _rules(violations)
    for v in violations:
        rule = SPEC.rule(v.rule)
        assert v.level == rule.level and v.text == rule.text
        assert v.evidence and all(0 <= i < s.last_monitor.count for i, _ in v.evidence)
        assert s.last_monitor.verdicts()[v.node][v.rule] == {"MUST": "failed", "SHOULD": "warned"}[v.level]


def test_faulty_missions_cover_every_rule_group():
    groups = {FAULTY[n].rule.split("-")[1] for n in FAULTY}
    assert groups >= {"HDR", "ACK", "SEQ", "RTX", "BLK", "PAY", "ROB", "FLOW", "DUP", "TRN"}
    assert len(FAULTY) >= 15
    assert {f.rule for f in FAULTY.values()} <= MONITORED_RULES


# ---------------------------------------------------------------- what the trace proves
def test_a_list_sent_malformed_is_its_payload_rules_not_a_missing_list():
    """One fault, one rule: an Obstacles_List whose count is little-endian is MCP-PAY-3's; the
    End_Mission after it is not "End_Mission without any Obstacles_List" (MCP-FLOW-6)."""
    import struct

    from mcp_conform.spec.codec import ITEM, build_datagram
    from tests.judge.monitor_faults import _runner_drones

    s = Script((1,), vehicle=False, challenge=3)
    kw = _runner_drones(s)
    s.exchange(0, 1, Action.START_MISSION, **kw)
    s.tick(0.01)
    payload = struct.pack("<H", len(s.items)) + b"".join(ITEM.pack(*it) for it in s.items)
    seq = s.next_seq(0)
    s.raw(0, build_datagram(1, 0, seq, int(Action.OBSTACLES_LIST), payload), to=1)
    s.tick(0.004)
    s.ack(1, 0, seq, origin=TESTER)
    s.tick(0.01)
    s.exchange(0, 1, Action.END_MISSION, **kw)
    assert {v.rule for v in s.judge()} == {"MCP-PAY-3"}


@pytest.mark.parametrize("unheard", [0, 8])
def test_copies_sent_before_a_late_starting_node_showed_itself_went_unheard(unheard):
    """A manager started by the runner may not listen yet while the runner retransmits the
    first Mission_Ready: the copies before its first datagram but the last went unheard.
    Its ACK of a later copy is no MCP-ACK-1 failure; a manager that then leaves the heard
    copies unACKed is (counted from the last unheard one)."""
    from tests.judge.monitor_faults import _manager_finishes

    s = Script((1, 2), vehicle=False)
    kw = {"acker_origin": TESTER}
    s.exchange(1, 0, Action.MISSION_READY, origin=TESTER, deaf=unheard)
    s.tick(0.02)
    s.exchange(2, 0, Action.MISSION_READY, origin=TESTER)
    s.tick(0.02)
    for d in s.drones:
        s.exchange(0, d, Action.START_MISSION, **kw)
        s.tick(0.01)
    _manager_finishes(s, kw)
    assert _rules(s.judge()) == []
    assert s.last_monitor.verdicts()[0]["MCP-ACK-1"] == "passed"
    # the same manager, late, that ACKs nothing of drone 1's Mission_Ready once it is up
    s = Script((1, 2), vehicle=False)
    seq, data = s.send(1, 0, Action.MISSION_READY, origin=TESTER)
    for k in range(unheard + 6):
        if k == unheard:
            s.tick(0.005)
            s.ack(0, 2, 7)  # the manager's first datagram (to another drone)
        s.tick(s.rto)
        s.raw(1, data, origin=TESTER)
    s.tick(0.02)
    s.exchange(2, 0, Action.MISSION_READY, origin=TESTER)
    s.tick(0.02)
    s.exchange(0, 2, Action.START_MISSION, **kw)
    assert {v.rule for v in s.judge()} >= {"MCP-ACK-1"}


@pytest.mark.parametrize("ignored", [True, False])
def test_a_manager_seen_ignoring_wrong_acks_that_never_waits_is_blk_3s(ignored):
    """The runner's wrong ACKs while drone 1's Start_Mission awaits its ACK (the wrong seq from
    drone 1, drone 1's seq from drone 2) and a manager that retransmits after them: it ignores
    both kinds. Drone 2's wrong-source ACK is still unanswered when drone 2's Start_Mission
    goes out, and 20 ms later, before its ACK, the manager sends drone 2 its WP_List. It never
    waits for Start_Mission's ACK (MCP-BLK-3); it is not taken for a manager that took drone
    2's stale ACK for it (MCP-RTX-2: a side-by-side run's false alarm on the sample manager's
    no-wait-start-ack, whose serial run gave BLK-3). A manager that was not seen ignoring a
    wrong seq from the destination (it took drone 1's: no copy after it) still is RTX-2's."""
    from tests.judge.monitor_faults import withheld_start_and_wrong_acks

    s, kw, seq, data = withheld_start_and_wrong_acks(wrong_seq=True)
    if ignored:
        s.tick(s.rto - 0.01)
        s.raw(0, data, to=1)  # retransmitted after both wrong ACKs
        s.tick(0.004)
    else:
        s.tick(0.0005)  # taken: no copy after the wrong seq from drone 1
    s.ack(1, 0, seq, origin=TESTER)
    s.tick(0.01)
    s.exchange(0, 1, Action.WP_LIST, tuple(s.items), **kw)
    s.tick(0.2)
    seq2, _ = s.send(0, 2, Action.START_MISSION)
    s.tick(0.02)
    s.send(0, 2, Action.WP_LIST, tuple(s.items))  # before Start_Mission's ACK
    s.tick(0.002)
    s.ack(2, 0, seq2, origin=TESTER)
    s.tick(0.002)
    s.ack(2, 0, s.seq[0] - 1, origin=TESTER)
    s.tick(0.05)
    for d in s.drones:
        s.exchange(0, d, Action.END_MISSION, **kw)
    rules = {v.rule for v in s.judge()}
    assert rules == ({"MCP-BLK-3"} if ignored else {"MCP-RTX-2"}), rules


@pytest.mark.parametrize("start2_ack_ms", [1, 25])
def test_a_manager_seen_moving_on_with_no_ack_is_not_taken_for_one_that_takes_a_stale_ack(start2_ack_ms):
    """The sample manager's no-wait-start-ack, as a loaded CI run's serial run recorded it: each
    drone's WP_List 20 ms after its Start_Mission, whatever came. Drone 1's went out with no
    ACK at all to take (MCP-BLK-3, proven); the runner's wrong ACKs came after it, while drone
    1's WP_List (ACKed) was the manager's latest unicast. Drone 2's wrong-source ACK is still
    unanswered when drone 2's Start_Mission goes out, and its WP_List follows 20 ms later,
    before the ACK when the runner is slow to send it (25 ms). A manager seen moving on with
    no ACK is not taken for one that took drone 2's stale ACK (MCP-RTX-2: the serial run's
    false alarm; its side-by-side run, ACKed at once, said not_observed): MCP-BLK-3 only."""
    from tests.judge.monitor_faults import _runner_drones

    s = Script((1, 2), vehicle=False)
    kw = _runner_drones(s)
    seq, data = s.send(0, 1, Action.START_MISSION)
    s.tick(0.02)
    s.exchange(0, 1, Action.WP_LIST, tuple(s.items), **kw)  # no ACK of Start_Mission yet
    for _ in range(3):
        s.tick(s.rto - 0.02 if _ == 0 else s.rto)
        s.raw(0, data, to=1)
    s.tick(0.001)
    s.ack(1, 0, (seq + 0x8000) & 0xFFFF, origin=TESTER)  # the wrong seq from drone 1
    s.ack(2, 0, seq, origin=TESTER)  # its seq, from drone 2
    s.tick(s.rto - 0.001)
    s.raw(0, data, to=1)  # retransmitted after both
    s.tick(0.001)
    s.ack(1, 0, seq, origin=TESTER)
    s.tick(0.001)
    seq2, _ = s.send(0, 2, Action.START_MISSION)
    t_start2 = s.t
    if start2_ack_ms < 20:  # ACKed before the WP_List (the side-by-side run)
        s.tick(start2_ack_ms / 1000)
        s.ack(2, 0, seq2, origin=TESTER)
    s.t = t_start2 + 0.02
    wp_seq, _ = s.send(0, 2, Action.WP_LIST, tuple(s.items))
    if start2_ack_ms > 20:  # after it (the serial run, loaded)
        s.t = t_start2 + start2_ack_ms / 1000
        s.ack(2, 0, seq2, origin=TESTER)
    s.tick(0.001)
    s.ack(2, 0, wp_seq, origin=TESTER)
    s.tick(0.05)
    for d in s.drones:
        s.exchange(0, d, Action.END_MISSION, **kw)
    rules = {v.rule for v in s.judge()}
    assert rules == {"MCP-BLK-3"}, rules


@pytest.mark.parametrize("tail", [0.0, 10.0])
def test_a_unicast_acked_is_rtx_1_observed_however_soon_the_trace_ends(tail):
    """MCP-RTX-1 is observed on a unicast retransmitted until its ACK as the ACK comes, not at
    the deadline that would judge it unACKed: a trace that ends before that deadline gives the
    same verdict as a longer one (a side-by-side run and the serial run of the same manager
    disagreed, "passed" against "not_observed")."""
    from tests.judge.monitor_faults import _runner_drones

    s = Script((1,), vehicle=False)
    kw = _runner_drones(s)
    s.exchange(0, 1, Action.START_MISSION, **kw)
    assert _rules(s.judge(tail=tail)) == []
    assert s.last_monitor.verdicts()[0]["MCP-RTX-1"] == "passed"


def test_the_harness_probing_a_drone_it_plays_mid_mission_is_no_restart():
    """``mcp-conform --role manager`` sends a fresh Mission_Ready of a drone it plays after
    that drone's Start_Mission (a liveness probe, or an input to a manager that starts
    early): no restart of the drone's mission, so its WP_List after it is no MCP-FLOW-2."""
    from tests.judge.monitor_faults import _manager_finishes, _runner_drones

    s = Script((1, 2), vehicle=False)
    kw = _runner_drones(s)
    for d in s.drones:
        s.exchange(0, d, Action.START_MISSION, **kw)
        s.tick(0.01)
    s.exchange(1, 0, Action.MISSION_READY, origin=TESTER)  # the probe
    s.tick(0.01)
    _manager_finishes(s, kw)
    assert _rules(s.judge()) == []
    assert s.last_monitor.verdicts()[0]["MCP-FLOW-2"] == "passed"


def test_an_unanswered_command_at_the_end_is_not_a_violation():
    s = Script((1,), challenge=1)
    s.ready(1)
    s.start(1)
    s.send(0, 1, Action.WP_LIST, tuple(s.items))  # the trace ends before any ACK
    assert _rules(s.judge(tail=0.0)) == []


def test_absences_are_not_judged_on_a_lossy_trace():
    for name in ("ack1-unanswered", "rtx1-gives-up", "flow3-no-end-mission", "ack6-acks-ack"):
        assert FAULTY[name].build().judge(complete=False) == [], name


def test_a_late_copy_of_an_older_message_delivered_again_is_only_reported():
    """MCP-DUP-4 is not specified: A, B, then A's copy delivered again is no DUP-1."""
    from mcp_conform.spec.mavframe import heartbeat_frame
    s = Script((1,), challenge=2)
    s.ready(1)
    s.start(1)
    a = heartbeat_frame(seq=1)
    seq_a = s.passthrough(1, a)
    s.passthrough(1, heartbeat_frame(seq=2))
    s.tick(1.0)
    s.raw(0, encode(Message(1, 0, seq_a, Action.MAV_PASSTHROUGH, a)), to=1)
    s.tick(0.004)
    s.ack(1, 0, seq_a)
    s.tick(0.01)
    s.vehicle(1, "frame", frame=a)
    s.tick(0.1)
    s.challenge_steps()  # challenge 2's every waypoint (MCP-FLOW-5)
    s.end(1)
    assert _rules(s.judge()) == []
    assert s.last_monitor.verdicts()[1]["MCP-DUP-4"] == "info"


def test_a_malformed_datagram_from_an_unknown_sender_blames_nobody():
    s = clean_script(1)
    s.records.append(s.records[-1]._replace(src_addr=("127.0.0.99", 9), data=b"XXXXXXXXX" + bytes(8)))
    assert _rules(s.judge()) == []


def test_an_address_shared_by_two_ids_names_no_sender():
    s = Script((1, 2))
    s.mission()
    shared = s.addr(1)
    s.records = [r._replace(src_addr=shared) if r.src_addr == s.addr(2) else r for r in s.records]
    s.raw(1, b"\x00" * 20)
    assert _rules(s.judge()) == []


def test_the_harness_is_never_blamed():
    s = Script((1,), vehicle=False)
    s.exchange(1, 0, Action.MISSION_READY, acker_origin=TESTER)
    for data in (b"", b"\x01", b"NCSU-CM\x01\x02" + bytes(8), b"NCSU-CM\x01\x01" + bytes(6) + b"\x00\x0c"):
        s.raw(0, data, to=1, origin=TESTER)
    s.ack(0, 1, 4321, origin=TESTER, hdr_src=0x101)
    s.send(0, 0xFFFF, Action.START_MISSION, origin=TESTER)
    s.send(0, 1, Action.WP_OFF, origin=TESTER)
    assert _rules(s.judge()) == []
    assert [n.id for n in s.last_monitor.nodes()] == [1]


def test_origin_names_the_sender_of_a_wrong_src():
    m = Monitor(complete=True)
    out = m.datagram(1, ("127.0.0.1", 9), None, encode(Message(0, 2, 5, Action.MISSION_READY)), origin=1)
    assert [(v.rule, v.node) for v in out] == [("MCP-HDR-4", 1)]


def test_a_header_written_little_endian_is_hdr2_not_its_misread_fields():
    """One fault, one rule (issue 18): a node's datagram whose header fields read right only
    byte-swapped breaks MCP-HDR-2 (network byte order); the src and action code network
    order reads (MCP-HDR-4, MCP-HDR-3 / ROB-3) are not faults of their own. A src that is
    wrong but not swapped is still MCP-HDR-4."""
    import struct

    from mcp_conform.judge.monitor import byte_order_fault
    from mcp_conform.spec.codec import PREAMBLE

    def little(dst: int, src: int, seq: int, action: int, payload: bytes = b"") -> bytes:
        return PREAMBLE + struct.pack("<4H", dst, src, seq, action) + payload

    m = Monitor(complete=True)
    out = m.datagram(1, ("127.0.0.1", 9), None, little(0, 1, 0x1234, Action.MISSION_READY), origin=1)
    out += m.datagram(2, ("127.0.0.1", 9), None, little(0, 1, 0x1235, Action.ACK, b"\x03\xe8"), origin=1)
    assert [(v.rule, v.node) for v in out] == [("MCP-HDR-2", 1)] * 2, _rules(out)
    assert "src 256 (0x0100) is ID 1 byte-swapped" in out[0].actual
    assert "action code 1792 (0x0700) is ACK byte-swapped" in out[1].actual
    m.finish()
    assert m.verdicts()[1]["MCP-HDR-2"] == "failed"
    assert m.verdicts()[1]["MCP-HDR-3"] != "failed" and m.verdicts()[1]["MCP-HDR-4"] != "failed"
    assert byte_order_fault(1, 2, 0) is None  # wrong, not swapped: MCP-HDR-4's
    assert byte_order_fault(0x0101, 0x0101, 7) is None  # swapping changes nothing
    assert byte_order_fault(1, 1, 9) is None  # 'Any' on the wire: MCP-HDR-3's
    assert byte_order_fault(1, 1, 0x0800) is not None


# ---------------------------------------------------------------- bytes
EDGE = {
    "empty": b"",
    "short": b"NCSU-CM\x01\x01\x00\x01\x00",
    "bad-preamble": b"NCSU-CX\x01\x01\x00\x00\x00\x01\x00\x05\x00\x07\x00\x05",
    "unknown-action": b"NCSU-CM\x01\x01\x00\x00\x00\x01\x00\x05\x00\x0a",
    "wrong-length": b"NCSU-CM\x01\x01\x00\x00\x00\x01\x00\x05\x00\x00\x00\x01\x02",
    "huge": b"NCSU-CM\x01\x01\x00\x00\x00\x01\x00\x05\x00\x08" + bytes(65507 - 17),
}
SENDER_RULE = {"short": "MCP-HDR-2", "bad-preamble": "MCP-HDR-1", "unknown-action": "MCP-HDR-3",
               "wrong-length": "MCP-PAY-2", "huge": "MCP-HDR-5", "empty": "MCP-HDR-2"}


@pytest.mark.parametrize("name", sorted(EDGE))
def test_byte_level_edge_cases_blame_the_sender_by_its_rule(name):
    s = Script((1,), vehicle=False)
    s.exchange(1, 0, Action.MISSION_READY)  # address 127.0.0.11 is drone 1's
    s.raw(1, EDGE[name])
    assert {v.rule for v in s.judge()} == {SENDER_RULE[name]}


def test_every_prefix_and_trailing_garbage():
    """Cut anywhere, with or without garbage after: a framed datagram blames its header's
    src by the rule it breaks (as the codec classifies it); an unframed one from no known
    address blames nobody."""
    whole = encode(Message(0, 1, 77, Action.MISSION_READY, 1))
    sender_rule = {"MCP-ROB-3": {"MCP-HDR-3"}, "MCP-ROB-4": {"MCP-PAY-2"}}
    for cut in range(len(whole) + 1):
        for data in (whole[:cut], whole[:cut] + b"\xff" * 3):
            try:
                decode(data)
                want: set[str] = set()
            except DecodeError as exc:
                want = sender_rule.get(exc.rule, set())
            m = Monitor()
            got = {v.rule for v in m.datagram(1, None, None, data) + m.finish(10)}
            assert got == want, (cut, data.hex(), got)


def test_waypoints_are_compared_on_the_fields_a_waypoint_file_holds_in_order():
    """MCP-FLOW-4 with --waypoints: target_system/component are not in a QGC WPL file, so a
    manager that fills them its own way carries the mission; the items' order does count."""
    from mcp_conform.spec.codec import Action, Message, encode

    from .monitor_faults import _finish, _started

    def judged(items):
        s = _started()
        seq = s.next_seq(0)
        s.exchange(0, 1, Action.WP_LIST, tuple(items), seq=seq)
        s.tick(0.01)
        s.exchange(0, 2, Action.WP_LIST, tuple(s.items))
        return {v.rule for v in _finish(s, steps=False).judge()}

    s = _started()
    retargeted = [i._replace(target_system=42, target_component=190) for i in s.items]
    assert "MCP-FLOW-4" not in judged(retargeted)
    assert "MCP-FLOW-4" in judged(list(reversed(s.items)))
    wire = decode(encode(Message(1, 0, 1, Action.WP_LIST, tuple(retargeted))))  # well-formed items
    assert [(i.seq, i.target_system, i.target_component) for i in wire.payload] == [
        (i.seq, 42, 190) for i in s.items]


def test_an_ack_read_after_the_message_it_took_a_number_before_explains_the_gap():
    """CI (slow suite): a manager ACKed drone 1's ACK with seq N (MCP-ACK-6's fault) and then
    sent drone 2 a message with seq N+1; the recorder read the message first. The gap is
    explained by the number the ACK carried, read within SEQ_GAP_GRACE_NS; a number no ACK
    carries within the grace is still MCP-SEQ-1 (the seq1-skips fault)."""
    from tests.judge.monitor_faults import _finish, _started

    def script(ack_after: float | None, ack_seq_offset: int = 0) -> Script:
        s = _started()
        own = s.next_seq(0)  # the ACK's number, taken before the next message
        s.exchange(0, 1, Action.WP_LIST, tuple(s.items))  # sent with own + 1
        if ack_after is not None:
            s.tick(ack_after)
            s.raw(0, encode(Message(2, 0, (own + ack_seq_offset) & 0xFFFF, Action.ACK, 77)), to=2)
        return _finish(s)

    rules = lambda s: [v.rule for v in s.judge()]  # noqa: E731
    assert "MCP-SEQ-1" not in rules(script(0.05))
    assert "MCP-SEQ-1" in rules(script(None))  # no ACK at all: a skipped number
    assert "MCP-SEQ-1" in rules(script(1.5))  # read too late to count
    assert "MCP-SEQ-1" in rules(script(0.05, ack_seq_offset=7))  # its number is not the one skipped


def test_an_ack_read_before_the_message_numbered_before_it_explains_the_gap():
    """CI (start-early, side by side and --serial alike): the manager's main thread took seq
    N for a Start_Mission, its receive thread then took N+1 for the ACK of a drone's
    Mission_Ready and sent it first; the next Start_Mission took N+2. The ACK numbered N+1
    was read 22 us before the message numbered N: it explains the gap between N and N+2 as
    one read just after would (the reorder works both ways; the manager case
    test_each_new_message_takes_the_next_seq judges on the numbers within the grace on both
    sides). A number no ACK carries within the grace is still MCP-SEQ-1."""
    from tests.judge.monitor_faults import _finish, _started

    def script(ack_before: float | None, ack_seq_offset: int = 0) -> Script:
        s = _started()
        n = s.next_seq(0)  # the message's number, taken first
        own = s.next_seq(0)  # the ACK's, taken after it
        if ack_before is not None:
            s.raw(0, encode(Message(2, 0, (own + ack_seq_offset) & 0xFFFF, Action.ACK, 77)), to=2)
            s.tick(ack_before)
        s.exchange(0, 1, Action.WP_LIST, tuple(s.items), seq=n)
        s.tick(0.01)
        s.exchange(0, 2, Action.WP_LIST, tuple(s.items))  # own + 1
        return _finish(s, steps=False)

    rules = lambda s: [v.rule for v in s.judge()]  # noqa: E731
    assert "MCP-SEQ-1" not in rules(script(0.00002))
    assert "MCP-SEQ-1" not in rules(script(0.5))  # within the grace
    assert "MCP-SEQ-1" in rules(script(None))  # no ACK at all: a skipped number
    assert "MCP-SEQ-1" in rules(script(1.5))  # read too long before to count
    assert "MCP-SEQ-1" in rules(script(0.00002, ack_seq_offset=7))  # its number is not the one skipped
    assert "MCP-SEQ-1" in rules(script(0.00002, ack_seq_offset=-1))  # the message's own number


def test_an_altered_form_of_a_frame_is_told_from_unrelated_bytes():
    """MCP-PAY-8's comparison of what arrived with the frame sent (judge.monitor.alteration)."""
    from mcp_conform.judge.monitor import alteration
    from mcp_conform.spec.mavframe import heartbeat_frame

    f = heartbeat_frame()
    assert alteration(f, f) is None
    assert alteration(f, f[:-3]) == f"truncated to {len(f) - 3} of {len(f)} bytes"
    assert alteration(f, f[:4]) is None  # not even its header: nothing says it is this frame
    flipped = f[:12] + bytes([f[12] ^ 1]) + f[13:]
    assert alteration(f, flipped) == f"1 of {len(f)} bytes differ (the first at offset 12)"
    assert alteration(f, b"\x00" + f[1:]) == f"1 of {len(f)} bytes differ (the first at offset 0)"
    assert alteration(f, f[:-2] + b"\x00\x00\x00") == f"{len(f) + 1} bytes instead of {len(f)}: " \
        f"the first {len(f) - 2} and the last 0 as sent"
    assert alteration(f, bytes(len(f))) is None and alteration(f, heartbeat_frame(seq=9)[:5]) is None


def test_passthrough_forwarded_intact_or_not_a_frame_is_no_alteration():
    """No false alarm: a payload that is no MAVLink frame, forwarded as it came, arrives as
    unparsed bytes; a frame forwarded intact after unrelated bad bytes is delivered."""
    from mcp_conform.spec.mavframe import heartbeat_frame

    s = Script((1, 2))
    for d in s.drones:
        s.ready(d)
    for d in s.drones:
        s.start(d)
    s.challenge_steps()
    junk = b"\xfd\x05" + bytes(8)
    s.exchange(0, 1, Action.MAV_PASSTHROUGH, junk,
               on_delivery=lambda: s.vehicle(1, "unparsed", frame=junk + b"\xfd\x09\x00", detail="bad CRC"))
    s.vehicle(2, "unparsed", frame=b"\x01\x02\x03", detail="Bad prefix")
    s.passthrough(2, heartbeat_frame(seq=3))
    for d in s.drones:
        s.end(d)
    found = s.judge()
    assert "MCP-PAY-8" not in {v.rule for v in found}  # the junk is the manager's (MCP-PAY-6)
    assert s.last_monitor.verdicts()[2]["MCP-PAY-8"] == "passed"
    assert s.last_monitor.verdicts()[1]["MCP-PAY-8"] != "warned"


@pytest.mark.parametrize("copy_ack, acks_other, want", [
    ("plus-one", False, set()),  # ack-copies-wrong-seq: the copy's ACK names the next seq
    ("right", True, {"MCP-ACK-5"}),      # the copy ACKed right; the message to ID 2 ACKed by drone 1
    ("right", False, set()),
], ids=["copy-acked-wrong", "other-id-acked", "clean"])
def test_an_ack_naming_the_next_message_while_a_copy_sent_before_the_first_ack_waits(copy_ack, acks_other, want):
    """CI under load (test_mutants[ack-copies-wrong-seq]): the manager's copy of seq N left
    before drone 1's ACK of N came back (200 ms, a loaded host); the manager went on to send
    N+1 to drone 2; drone 1's ACK of the copy named N+1 (its fault, MCP-ACK-2) and was judged
    an ACK of a message to another ID (MCP-ACK-5): a consequence of the wrong number, not a
    second violation. The copy still owed its ACK: an ACK naming something else then is
    ambiguous. The copy's ACK coming decides it (an ACK of what it named); its not coming
    proves neither (the node's other copies prove its MCP-ACK-2 in a run): a loaded run's
    manager that ACKs ACKs (MCP-ACK-6) was late with a copy's ACK and got a false MCP-ACK-2
    when its absence was taken for proof."""
    from tests.judge.monitor_faults import _finish, _started

    s = _started(challenge=2)
    seq, data = s.send(0, 1, Action.WP_OFF)
    s.tick(0.2)
    s.raw(0, data, to=1)  # the copy, before any ACK
    s.tick(0.01)
    s.ack(1, 0, seq)  # the ACK of the first
    s.tick(0.005)
    other, _ = s.send(0, 2, Action.WP_OFF)
    assert other == (seq + 1) & 0xFFFF
    s.tick(0.002)
    s.ack(1, 0, other if copy_ack == "plus-one" else seq)  # the copy's ACK
    s.tick(0.002)
    s.ack(2, 0, other)
    if acks_other:
        s.tick(0.002)
        s.ack(1, 0, other)
    s.tick(0.5)
    rules = {v.rule for v in _finish(s, steps=False).judge()}
    assert rules & {"MCP-ACK-2", "MCP-ACK-5"} == want, rules


@pytest.mark.parametrize("other_src_message", [True, False], ids=["misaddressed-or-swapped", "swapped"])
def test_an_ack_whose_number_names_another_senders_message_is_no_byte_swap(other_src_message):
    """A drone's ACK to the manager naming 516 (0x0204), while the manager's WP_Off 1026
    (0x0402, 516 byte-swapped) waits for its ACK: alone, a byte swap (MCP-ACK-2). But when the
    runner sent the drone a message numbered 516 from src 2 (MCP-ACK-3's probe), the ACK is as
    well that message's ACK sent to the wrong ID (MCP-ACK-3): each explanation breaks another
    rule, neither breaks both, so the ACK proves neither (D-9's principle). The sample node's
    ack-to-manager through ``--impair`` drew a false MCP-ACK-2 beside its true MCP-ACK-3 (the
    case's) this way in 7 of 20 simulated seeds."""
    from tests.judge.monitor_faults import _finish, _started

    s = _started(challenge=2)
    if other_src_message:
        s.send(2, 1, Action.WP_OFF, seq=516, origin=TESTER)
        s.tick(0.002)
    s.send(0, 1, Action.WP_OFF, seq=1026)
    s.tick(0.004)
    s.ack(1, 0, 516)
    s.tick(0.5)
    acks = [v for v in _finish(s, steps=False).judge() if v.rule == "MCP-ACK-2" and "byte-swapped" in v.actual]
    assert bool(acks) != other_src_message, acks

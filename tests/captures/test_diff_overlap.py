"""mcp-capture diff where cases ran side by side (captures.overlap): the interleaving of
overlapping cases' traffic is not compared; their own order, and everything outside, is.

Issue 35: two whole-suite runs of the reference drone differed by 19–37 divergences every
time, the schedule's batch (four MCP-ROB cases, the DUP and ACK silence cases) interleaving
its threads' datagrams differently in each run. The runs here are small models of that
batch: a ROB-like case sending malformed datagrams, each followed by a liveness WP_Off, and a
DUP-like case sending passthrough probes, all from the runner's one socket and one seq
counter, with the runner's case marks around them.
"""

from __future__ import annotations

import argparse
import io

from mcp_conform.captures.diff import (
    DiffOptions,
    diff_sides,
    print_report,
    register,
    side_from_datagrams,
)
from mcp_conform.captures.overlap import Span, lane, overlap_spans
from mcp_conform.spec.codec import Action, Message, build_datagram, decode, encode
from mcp_conform.traceio.recorder import McapRecorder
from mcp_conform.traceio.records import CaseMark
from mcp_conform.vehicle.probe import make_probe
from tests.captures.scenario import D

MGR, DRONE = ("127.0.0.1", 7889), ("127.0.0.1", 7890)
T0 = 10**18
ROB, DUP = "ROB/test_bad_preamble_is_discarded", "DUP/test_same_seq_twice_is_delivered_once"


def _malformed(n: int, seq: int) -> bytes:
    """The ROB case's n-th input: a datagram with its preamble broken at byte n (MCP-ROB-2)."""
    data = bytearray(build_datagram(1, 0, seq, int(Action.WP_OFF)))
    data[n] ^= 0xFF
    return bytes(data)


def _run(batch: list[str], before: list[str] = (), after: list[str] = (), *, marks: bool = True,
         seq0: int = 100) -> tuple[list[D], list[CaseMark]]:
    """The runner's traffic to drone 1 in the order given, the batch's between its two cases'
    marks: ``robN`` the ROB case's N-th malformed input (no reply), ``wpoff`` a liveness
    WP_Off, ``dupN`` the DUP case's N-th probe (token ``…-N-<seq>``), each ACKed at once."""
    out: list[D] = []
    seq = [seq0, 7000]
    case_marks: list[CaseMark] = []

    def add(src, dst, data):
        out.append(D(len(out), T0 + len(out) * 1000, src, dst, data))

    def send(item: str) -> None:
        s = seq[0]
        seq[0] += 1
        if item.startswith("rob"):
            add(MGR, DRONE, _malformed(int(item[3:]), s))
            return
        if item == "wpoff":
            add(MGR, DRONE, encode(Message(1, 0, s, Action.WP_OFF)))
        else:
            token = f"_twice_is_delivered_once-{item[3:]}-{s}"
            add(MGR, DRONE, encode(Message(1, 0, s, Action.MAV_PASSTHROUGH, make_probe(token))))
        add(DRONE, MGR, encode(Message(0, 1, seq[1], Action.ACK, s)))
        seq[1] += 1

    for item in before:
        send(item)
    start = T0 + len(out) * 1000 - 500
    for item in batch:
        send(item)
    end = T0 + len(out) * 1000 - 500
    for item in after:
        send(item)
    if marks:
        case_marks = [CaseMark(start, ROB, "start", None, ()), CaseMark(start + 1, DUP, "start", None, ()),
                      CaseMark(end, ROB, "end", "passed", ()), CaseMark(end + 1, DUP, "end", "passed", ())]
    return out, case_marks


def decode_or_none(data: bytes):
    from mcp_conform.spec.codec import DecodeError

    try:
        return decode(data)
    except DecodeError:
        return None


def _diff(golden: tuple[list[D], list[CaseMark]], candidate: tuple[list[D], list[CaseMark]]):
    return diff_sides(side_from_datagrams("golden", golden[0], marks=golden[1]),
                      side_from_datagrams("candidate", candidate[0], marks=candidate[1]), DiffOptions())


def _report(result) -> str:
    buf = io.StringIO()
    print_report(result, buf)
    return buf.getvalue()


BATCH = ["rob1", "wpoff", "dup1", "rob2", "wpoff", "dup2", "rob3", "wpoff"]
#: the same cases' traffic as another run's threads interleaved it (each case's own order kept)
RACED = ["dup1", "rob1", "dup2", "wpoff", "rob2", "rob3", "wpoff", "wpoff"]


def test_a_reordering_across_overlapping_cases_compares_equal():
    result = _diff(_run(BATCH), _run(RACED, seq0=40000))
    assert result.same, _report(result)
    assert "1 span of cases run side by side (2 cases" in _report(result)
    # the same two runs without the runner's marks: the race reads as reorderings
    unmarked = _diff(_run(BATCH, marks=False), _run(RACED, marks=False))
    assert unmarked.divergences and {d.kind for d in unmarked.divergences} <= {"reordered", "changed"}


def _reordered(run: tuple[list[D], list[CaseMark]], order: list[int]):
    """The run's datagrams in another order (each index of ``order`` a datagram), timed anew."""
    data, marks = run
    return [data[i]._replace(t_ns=data[n].t_ns) for n, i in enumerate(order)], marks


def test_the_acks_of_overlapping_cases_may_leave_in_either_order():
    """The probe's ACK leaves after the WP_Off's ACK and after the next malformed input (the
    node's race, beyond what an ACK in flight together with the next one covers)."""
    golden = _run(["dup1", "wpoff", "rob2"])  # dup1, its ACK, wpoff, its ACK, rob2
    raced = _reordered(golden, [0, 2, 3, 4, 1])
    assert _diff(golden, raced).same, _report(_diff(golden, raced))
    unmarked = _diff((golden[0], []), (raced[0], []))
    assert [d.kind for d in unmarked.divergences] == ["reordered"], _report(unmarked)


def test_the_same_reordering_outside_the_overlap_still_differs():
    golden = _run(BATCH, before=["rob1", "dup1"], after=["wpoff", "dup3"])
    for before, after in ((["dup1", "rob1"], ["wpoff", "dup3"]), (["rob1", "dup1"], ["dup3", "wpoff"])):
        result = _diff(golden, _run(RACED, before=before, after=after))
        assert result.divergences, _report(result)
        assert {d.kind for d in result.divergences} == {"reordered"}, _report(result)


def test_one_cases_own_order_inside_the_overlap_still_differs():
    for own in (["rob2", "wpoff", "dup1", "rob1", "wpoff", "dup2", "rob3", "wpoff"],  # ROB's inputs
                ["rob1", "wpoff", "dup2", "rob2", "wpoff", "dup1", "rob3", "wpoff"]):  # DUP's probes
        result = _diff(_run(BATCH), _run(own))
        assert result.divergences, _report(result)
        assert {d.kind for d in result.divergences} == {"reordered"}, _report(result)


def test_a_datagram_missing_added_or_changed_inside_the_overlap_still_differs():
    golden = _run(BATCH)
    missing = _diff(golden, _run([x for x in RACED if x != "rob2"]))
    assert [d.kind for d in missing.divergences] == ["missing"], _report(missing)
    assert missing.divergences[0].golden.action is None
    one_less = _diff(golden, _run(RACED[:-1]))  # a liveness WP_Off (and its ACK) not sent
    assert {d.kind for d in one_less.divergences} == {"missing"}, _report(one_less)
    extra = _diff(golden, _run(RACED + ["dup3"]))
    assert {d.kind for d in extra.divergences} == {"extra"}, _report(extra)
    changed, marks = _run(RACED)
    n = next(k for k, d in enumerate(changed) if decode_or_none(d.data) is None)
    changed[n] = changed[n]._replace(data=changed[n].data[:-1] + b"\x09")
    result = _diff(golden, (changed, marks))
    assert [d.kind for d in result.divergences] == ["changed"], _report(result)



def test_a_message_that_moved_into_or_out_of_the_overlap_differs():
    result = _diff(_run(BATCH, after=["wpoff"]), _run(RACED + ["wpoff"]))
    assert result.divergences, _report(result)


def test_overlap_spans_are_cases_whose_times_overlap():
    def m(t, case, event, segment=None):
        return CaseMark(t, case, event, None, (), segment)
    marks = [m(0, "A", "start"), m(10, "A", "end"),  # alone
             m(20, "B", "start"), m(21, "C", "start"), m(30, "B", "end"), m(29, "D", "start"),
             m(40, "C", "end"), m(41, "D", "end"),  # B, C, D side by side
             m(50, "E", "start"), m(60, "E", "end"), m(55, "F", "start")]  # F never ended
    assert overlap_spans(sorted(marks)) == [Span(20, 41, ("B", "C", "D")),
                                            Span(50, 2**63 - 1, ("E", "F"))]
    assert overlap_spans([m(0, "A", "start"), m(5, "A", "end"), m(5, "B", "start"), m(9, "B", "end")]) \
        == [Span(0, 9, ("A", "B"))]  # one ends as the next starts: the same instant, overlapping
    assert overlap_spans([]) == []


def test_lanes_are_the_probes_case_the_malformed_rule_or_the_message():
    side = side_from_datagrams("s", _run(["rob1", "rob2", "wpoff", "dup1", "dup2"])[0])
    rob1, rob2, wpoff, its_ack, dup1, ack1, dup2, ack2 = (
        lane(e.key) for e in side.conversations[(0, 1)].entries)
    assert rob1 == rob2 == ("malformed", 0, 1, "MCP-ROB-2")
    assert wpoff == its_ack == (0, 1, int(Action.WP_OFF), None)
    assert dup1 == ack1 == dup2 == ack2 == ("probe", 0, 1, "_twice_is_delivered_once")


def _write(path, run: tuple[list[D], list[CaseMark]]) -> None:
    datagrams, marks = run
    events = [(d.t_ns, 0, d) for d in datagrams] + [(m.t_ns, 1, m) for m in marks]
    with McapRecorder(path) as rec:
        for _t, kind, r in sorted(events, key=lambda e: (e[0], e[1])):
            if kind:
                rec.case_mark(r.case, r.event, r.t_ns, r.outcome)
            else:
                tx = r.src_addr == MGR
                rec.datagram("tx" if tx else "rx", r.data, r.dst_addr if tx else r.src_addr, r.t_ns,
                             local=MGR)


def test_the_command_reads_the_runners_case_marks(tmp_path):
    golden, raced, own = tmp_path / "golden.mcap", tmp_path / "raced.mcap", tmp_path / "own.mcap"
    _write(golden, _run(BATCH))
    _write(raced, _run(RACED, seq0=3))
    _write(own, _run(["rob2", "wpoff", "dup1", "rob1", "wpoff", "dup2", "rob3", "wpoff"]))
    parser = argparse.ArgumentParser(prog="mcp-capture")
    register(parser.add_subparsers(dest="command", required=True))
    for cand, code in ((raced, 0), (own, 1)):
        args = parser.parse_args(["diff", str(golden), str(cand), "--json", str(tmp_path / "d.json")])
        out = io.StringIO()
        assert args.run(args, out, io.StringIO()) == code, out.getvalue()
        assert "1 span of cases run side by side (2 cases" in out.getvalue()
    import json

    report = json.loads((tmp_path / "d.json").read_text())
    assert report["golden"]["overlaps"][0]["cases"] == [ROB, DUP]
    from mcp_conform.captures.diff import diff_captures
    from mcp_conform.captures.diff_html import html_report

    assert "golden: 1 span of cases run side by side" in html_report(diff_captures(golden, raced))

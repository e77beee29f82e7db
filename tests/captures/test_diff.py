"""mcp-capture diff: conversations compared after seq normalisation; injected changes named."""

from __future__ import annotations

import argparse
import io
import json
import random

import pytest

from mcp_conform.captures.diff import (
    DiffOptions,
    diff_sides,
    print_report,
    register,
    side_from_datagrams,
)
from mcp_conform.spec.codec import Action, Message, decode, encode
from mcp_conform.traceio.recorder import McapRecorder
from tests.captures.scenario import D, challenge2, reindex


def _diff(golden: list[D], candidate: list[D], **opts):
    return diff_sides(side_from_datagrams("golden", golden), side_from_datagrams("candidate", candidate),
                      DiffOptions(**opts))


def _report(result) -> str:
    buf = io.StringIO()
    print_report(result, buf)
    return buf.getvalue()


def _find(datagrams: list[D], action: Action, nth: int = 0) -> int:
    hits = [i for i, d in enumerate(datagrams) if decode(d.data).action == action]
    return hits[nth]


def test_same_scenario_with_other_initial_seqs_and_ports_is_the_same():
    result = _diff(challenge2(), challenge2(seq0=(65530, 1, 40000), port=50000))
    assert result.same, _report(result)
    assert "same: every conversation matches" in _report(result)
    assert result.golden.messages == 36 and len(result.golden.conversations) == 2


def test_addresses_compared_only_when_asked():
    result = _diff(challenge2(), challenge2(port=50000), addresses=True)
    assert {d.kind for d in result.divergences} == {"address"}
    assert "vs 127.0.0.1:5000" in result.divergences[0].note


def test_a_dropped_ack_is_named():
    golden = challenge2()
    i = _find(golden, Action.ACK, 5)
    acked = decode(golden[i].data)
    result = _diff(golden, reindex(golden[:i] + golden[i + 1:]))
    assert [d.kind for d in result.divergences] == ["missing"]
    d = result.divergences[0]
    assert d.golden is not None and d.golden.action == Action.ACK and d.golden.src == acked.src
    text = _report(result)
    assert "first divergence (missing)" in text and "ACK" in text and "(missing)" in text


def test_a_changed_waypoint_field_is_named_field_by_field():
    golden = challenge2()
    cand = list(golden)
    i = _find(cand, Action.WP_ON, 2)
    msg = decode(cand[i].data)
    cand[i] = cand[i]._replace(data=encode(msg._replace(payload=msg.payload._replace(x=36.5))))
    result = _diff(golden, cand)
    assert [d.kind for d in result.divergences] == ["changed"]
    (field, before, after), = result.divergences[0].fields
    assert field == "payload.x" and before == pytest.approx(msg.payload.x, abs=1e-5) and after == pytest.approx(36.5)
    assert "payload.x" in _report(result)


def test_two_commands_swapped_are_one_reordering():
    golden = challenge2()
    cand = list(golden)
    a, b = _find(cand, Action.WP_ON, 0), _find(cand, Action.WP_ON, 2)  # both to drone 1
    ma, mb = decode(cand[a].data), decode(cand[b].data)
    assert ma.dst == mb.dst
    cand[a] = cand[a]._replace(data=encode(ma._replace(payload=mb.payload)))
    cand[b] = cand[b]._replace(data=encode(mb._replace(payload=ma.payload)))
    result = _diff(golden, cand)
    # [a, WP_Off, b] against [b, WP_Off, a]: the shortest edit moves two of the three
    assert {d.kind for d in result.divergences} == {"reordered"}, _report(result)
    assert 1 <= len(result.divergences) <= 2
    assert any(d.golden.action == Action.WP_ON for d in result.divergences)
    assert "first divergence (reordered)" in _report(result)


def test_two_adjacent_commands_swapped_are_one_reordering():
    golden = challenge2()
    i = _find(golden, Action.START_MISSION, 1)  # Start_Mission to drone 2, ACK, then WP_On to drone 1
    j = _find(golden, Action.WP_ON, 0)
    cand = reindex(golden[:i] + golden[j:j + 2] + golden[i:j] + golden[j + 2:])
    result = _diff(golden, cand)
    assert result.same  # they are in different conversations: no order between them to keep
    k = _find(golden, Action.WP_ON, 0)
    m = _find(golden, Action.WP_OFF, 0)  # to drone 1, after WP_On to drone 2 and its ACK
    msg_on, msg_off = decode(golden[k].data), decode(golden[m].data)
    assert msg_on.dst == msg_off.dst == 1
    cand = list(golden)
    cand[k] = cand[k]._replace(data=encode(msg_on._replace(action=Action.WP_OFF, payload=None)))
    cand[m] = cand[m]._replace(data=encode(msg_off._replace(action=Action.WP_ON, payload=msg_on.payload)))
    result = _diff(golden, cand)
    assert [d.kind for d in result.divergences] == ["reordered"], _report(result)
    assert "another place in the order" in result.divergences[0].note


def _with_retransmissions(datagrams: list[D], action: Action, extra: int) -> list[D]:
    i = _find(datagrams, action)
    return reindex(datagrams[:i + 1] + [datagrams[i]] * extra + datagrams[i + 1:])


def test_retransmissions_within_the_tolerance_pass_beyond_it_diverge():
    golden = challenge2()
    assert _diff(golden, _with_retransmissions(golden, Action.START_MISSION, 1)).same
    result = _diff(golden, _with_retransmissions(golden, Action.START_MISSION, 2))
    assert [d.kind for d in result.divergences] == ["copies"]
    assert result.divergences[0].fields == (("copies", 1, 3),)
    assert _diff(golden, _with_retransmissions(golden, Action.START_MISSION, 2), copies_tolerance=2).same


def test_one_message_more_shifts_nothing_after_it():
    golden = challenge2()
    i = _find(golden, Action.WP_OFF, 1)
    msg = decode(golden[i].data)
    extra = golden[i]._replace(data=encode(msg._replace(action=Action.WP_OFF, seq=(msg.seq + 999) & 0xFFFF)))
    result = _diff(golden, reindex(golden[:i] + [extra] + golden[i:]))
    assert [d.kind for d in result.divergences] == ["extra"], _report(result)


def test_timing_ignored_by_default_but_drift_reported():
    golden = challenge2(step_ns=1_000_000)
    slow = challenge2(step_ns=3_000_000)
    result = _diff(golden, slow)
    assert result.same and result.max_drift_ns == 2_000_000 * 33  # (0,2): from its first message to its last
    assert "largest timing drift +0.066 s" in _report(result)
    timed = _diff(golden, slow, time_tolerance=0.05)
    assert timed.divergences and {d.kind for d in timed.divergences} == {"timing"}


def _write_mcap(path, datagrams: list[D]) -> None:
    """A manager-side capture: the manager's messages are tx, the drones' rx."""
    with McapRecorder(path) as rec:
        for d in datagrams:
            tx = decode(d.data).src == 0
            rec.datagram("tx" if tx else "rx", d.data, d.dst_addr if tx else d.src_addr, d.t_ns,
                         local=d.src_addr if tx else d.dst_addr)


def _cli(*argv: str) -> tuple[int, str, str]:
    parser = argparse.ArgumentParser(prog="mcp-capture")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["diff", *argv])
    out, err = io.StringIO(), io.StringIO()
    return args.run(args, out, err), out.getvalue(), err.getvalue()


def test_cli_on_mcap_files_exit_codes_and_json(tmp_path):
    golden, cand = tmp_path / "golden.mcap", tmp_path / "cand.mcap"
    _write_mcap(golden, challenge2())
    _write_mcap(cand, challenge2(seq0=(1, 2, 3), port=41000))
    code, out, _ = _cli(str(golden), str(cand), "--json", str(tmp_path / "d.json"))
    assert code == 0, out
    assert json.loads((tmp_path / "d.json").read_text())["same"] is True
    dropped = [d for d in challenge2() if not (decode(d.data).action == Action.ACK and decode(d.data).src == 2)]
    _write_mcap(cand, reindex(dropped))
    code, out, _ = _cli(str(golden), str(cand), "--json", str(tmp_path / "d.json"))
    report = json.loads((tmp_path / "d.json").read_text())
    assert code == 1 and report["same"] is False and report["summary"]["missing"] == 8  # Start, 3 WP_On, 3 WP_Off, End
    assert report["divergences"][0]["golden"]["text"].startswith("2→0 ACK")
    code, _, err = _cli(str(golden), str(tmp_path / "nope.mcap"))
    assert code == 2 and err.count("\n") == 1 and "nope.mcap" in err


@pytest.mark.slow
def test_truncated_captures_are_read_up_to_the_last_whole_chunk(tmp_path):
    golden = tmp_path / "golden.mcap"
    big = challenge2()
    with McapRecorder(golden) as rec:  # several chunks: many datagrams
        for n in range(60):
            for d in big:
                rec.datagram("tx", d.data, d.dst_addr, d.t_ns + n * 10**9, local=d.src_addr)
    data = golden.read_bytes()
    rnd = random.Random(7)
    cuts = sorted({rnd.randrange(9, len(data)) for _ in range(12)} | {len(data) - 1, len(data) // 2})
    for cut in cuts:
        cand = tmp_path / f"cut{cut}.mcap"
        cand.write_bytes(data[:cut])
        code, out, err = _cli(str(golden), str(cand))
        assert code in (0, 1), (cut, err)
        assert "TRUNCATED" in out, (cut, out[:300])
        assert "Traceback" not in out + err


def test_html_shows_both_sides_side_by_side(tmp_path):
    golden, cand = tmp_path / "golden.mcap", tmp_path / "cand.mcap"
    _write_mcap(golden, challenge2())
    dropped = challenge2()
    i = _find(dropped, Action.ACK, 5)
    _write_mcap(cand, reindex(dropped[:i] + dropped[i + 1:]))
    code, _, _ = _cli(str(golden), str(cand), "--html", str(tmp_path / "d.html"))
    html = (tmp_path / "d.html").read_text()
    assert code == 1 and html.startswith("<!DOCTYPE html>")
    assert html.count("<svg") == 4  # two conversations, golden and candidate each
    assert "class='pair'" in html and "1 missing" in html
    assert 'class="arrow' in html and "missing" in html and "(not here)" in html


def test_unwritable_outputs_are_refused_before_any_work(tmp_path):
    from mcp_conform.captures.cli import main

    golden = tmp_path / "golden.mcap"
    _write_mcap(golden, challenge2())
    assert main(["diff", str(golden), str(golden), "--json", str(tmp_path / "no" / "d.json")]) == 2
    assert main(["diff", str(golden), str(golden)]) == 0


@pytest.mark.slow
def test_every_command_reads_a_cut_capture_up_to_its_last_whole_chunk(tmp_path, capsys):
    """show, check, diff and export on a file cut at arbitrary offsets: no traceback, the
    records before the cut are read, and each says the file was truncated."""
    from mcp_conform.captures.cli import main

    whole = tmp_path / "whole.mcap"
    base = challenge2()
    with McapRecorder(whole) as rec:  # enough traffic for several chunks
        for n in range(80):
            for d in base:
                tx = decode(d.data).src == 0
                rec.datagram("tx" if tx else "rx", d.data, d.dst_addr if tx else d.src_addr,
                             d.t_ns + n * 10**9)
    data = whole.read_bytes()
    rnd = random.Random(11)
    for cut in sorted({rnd.randrange(len(data) // 3, len(data)) for _ in range(4)}):
        part = tmp_path / f"cut{cut}.mcap"
        part.write_bytes(data[:cut])
        for argv in (["show", str(part)], ["check", str(part)], ["diff", str(whole), str(part)],
                     ["export", str(part), "--pcap", str(tmp_path / "o.pcap")]):
            code = main(argv)
            out, err = capsys.readouterr()
            assert code in (0, 1), (argv, err)
            assert "truncated" in (out + err).lower(), (argv, out[-500:], err)
            assert "Traceback" not in out + err


def test_html_gaps_are_placeholders_not_red_arrows_and_times_stay_in_order():
    """Issue 18 item 16: the row a missing message leaves on the candidate's side is a grey
    "(not here)" note with no line and no time (its time would be the golden capture's,
    out of order with the candidate's own), and each side's times run forward."""
    import re
    import xml.etree.ElementTree as ET

    from mcp_conform.captures.diff_html import html_report

    golden = challenge2()
    i = _find(golden, Action.ACK, 5)
    shifted = [d._replace(t_ns=d.t_ns + 100 * 10**9) for d in golden[:i] + golden[i + 1:]]  # recorded later
    html = html_report(_diff(golden, reindex(shifted)))
    ns = "{http://www.w3.org/2000/svg}"
    gaps = 0
    for svg in re.findall(r"<svg .*?</svg>", html, flags=re.S):
        root = ET.fromstring(svg)
        times = [float(t.text.strip("+s")) for t in root.iter(f"{ns}text") if t.get("class") == "time"]
        assert times == sorted(times), times
        for g in root.iter(f"{ns}g"):
            if "gap" in (g.get("class") or "").split():
                gaps += 1
                assert g.find(f"{ns}line") is None and g.find(f"{ns}path") is None
                assert [t.text for t in g.iter(f"{ns}text")] == ["(not here)"]
    assert gaps == 1


def test_the_harness_liveness_probes_are_not_compared(tmp_path):
    """The runner's liveness watcher probes the node (WP_Off from its own MCP ID) only when
    the node has been quiet for a while, which depends on the machine's load: a golden
    re-recorded on a loaded machine differed by that one exchange. A harness capture's
    probes and their ACKs are left out of the comparison; a node's or anyone's same-looking
    traffic is not."""
    from mcp_conform.captures.diff import load_side
    from mcp_conform.harness.liveness import PROBE_SRC

    plain = challenge2()
    probe = encode(Message(1, PROBE_SRC, 7, Action.WP_OFF))
    ack = encode(Message(PROBE_SRC, 1, 900, Action.ACK, 7))
    k = next(i for i, d in enumerate(plain) if decode(d.data).src == 0 and decode(d.data).dst == 1)
    m = plain[k]
    probed = reindex(plain[:k + 1] + [D(0, m.t_ns + 1, m.src_addr, m.dst_addr, probe),
                                      D(0, m.t_ns + 2, m.dst_addr, m.src_addr, ack)] + plain[k + 1:])
    for library, same in (("mcp-conform", True), ("someone-else", False)):
        paths = []
        for name, ds in (("plain", plain), ("probed", probed)):
            path = tmp_path / f"{library}-{name}.mcap"
            with McapRecorder(path, library=library) as rec:
                for d in ds:
                    tx = decode(d.data).src in (0, PROBE_SRC)
                    rec.datagram("tx" if tx else "rx", d.data, d.dst_addr if tx else d.src_addr, d.t_ns,
                                 local=d.src_addr if tx else d.dst_addr)
            paths.append(path)
        result = diff_sides(load_side(paths[0]), load_side(paths[1]), DiffOptions())
        assert result.same is same, (library, _report(result))


# ---------------------------------------------------------------- passthrough probe tokens
def _probe_run(tokens: list[str], seq0: int = 100, port: int = 7889, t0: int = 10**18,
               frame=None) -> list[D]:
    """The manager sends one Mav_Passthrough probe per token to drone 1, each ACKed."""
    from mcp_conform.vehicle.probe import make_probe

    frame = frame or make_probe
    mgr, drone = ("127.0.0.1", port), ("127.0.0.1", port + 1)
    out: list[D] = []
    for n, token in enumerate(tokens):
        s = (seq0 + n) & 0xFFFF
        out.append(D(len(out), t0 + len(out) * 1000, mgr, drone,
                     encode(Message(1, 0, s, Action.MAV_PASSTHROUGH, frame(token)))))
        out.append(D(len(out), t0 + len(out) * 1000, drone, mgr,
                     encode(Message(0, 1, 7 + n, Action.ACK, s))))
    return out


# tokens as conformance.drone_case.Case.probe names them: <case id tail>-<n>-<the driver's next seq>,
# the seq depending on how a batch's cases interleaved (issue 35: -1323 in one run, -1322 next)
RUN_A = ["ither_acked_nor_acted_on-1-1323", "delivered_once-1-1330", "delivered_once-1-1330",
         "delivered_once-2-1333"]
RUN_B = ["ither_acked_nor_acted_on-1-1322", "delivered_once-1-1329", "delivered_once-1-1329",
         "delivered_once-2-1334"]


def test_probe_tokens_that_differ_only_by_the_runners_seq_are_the_same():
    result = _diff(_probe_run(RUN_A), _probe_run(RUN_B, seq0=4000, port=50000))
    assert result.same, _report(result)
    e = result.golden.conversations[(0, 1)].entries[0]
    from mcp_conform.captures.conversation import describe, entry_fields

    assert describe(e) == "0→1 MAV_PASSTHROUGH seq+0 probe ither_acked_nor_acted_on-1 #1"
    fields = entry_fields(e)
    assert fields["payload.probe.stem"] == "ither_acked_nor_acted_on-1"
    assert fields["token"] == RUN_A[0]


def test_other_probe_namings_are_numbered_by_first_appearance():
    """Tokens without the runner's seq (a fuzzer's counters, a timestamp) are their order of
    first appearance: a token sent again is the same number."""
    assert _diff(_probe_run(["sent17", "sent99", "sent17"]), _probe_run(["x1", "y", "x1"])).same
    result = _diff(_probe_run(["sent17", "sent99", "sent17"]), _probe_run(["x1", "y", "z"]))
    assert [d.kind for d in result.divergences] == ["changed"], _report(result)
    assert ("payload.probe.ordinal", 1, 3) in result.divergences[0].fields


def test_a_probe_repeated_where_the_other_run_sent_a_new_one_differs():
    """DUP-2 sends one probe twice: a new token the second time is another message."""
    repeated = ["delivered_once-1-1330", "delivered_once-1-1330"]
    renamed = ["delivered_once-1-1330", "delivered_once-1-1331"]  # same stem, a new token
    result = _diff(_probe_run(repeated), _probe_run(renamed))
    assert [d.kind for d in result.divergences] == ["changed"], _report(result)
    d = result.divergences[0]
    assert ("payload.probe.ordinal", 1, 2) in d.fields
    assert not any(f == "token" for f, _, _ in d.fields)  # the token is shown, never compared
    assert "probe delivered_once-1 #1" in _report(result)


def test_another_cases_probe_or_two_probes_swapped_differ():
    result = _diff(_probe_run(RUN_A), _probe_run(RUN_A[:3] + ["other_case-2-1333"]))
    assert [d.kind for d in result.divergences] == ["changed"], _report(result)
    stem = ("payload.probe.stem", "delivered_once-2", "other_case-2")
    assert stem in result.divergences[0].fields
    swapped = [RUN_B[3], RUN_B[1], RUN_B[2], RUN_B[0]]
    result = _diff(_probe_run(RUN_A), _probe_run(swapped))
    kinds = {d.kind for d in result.divergences}
    assert result.divergences and kinds == {"reordered"}, _report(result)


def test_a_probe_frame_changed_otherwise_still_differs():
    """Only frames exactly as vehicle.make_probe builds them are read as probes: another
    header field or a v1 frame is a difference, and so is a frame make_probe would not build
    (another severity: compared byte for byte)."""
    from functools import partial

    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    from mcp_conform.spec.mavframe import pack_message
    from mcp_conform.vehicle.probe import PROBE_PREFIX, make_probe

    golden = _probe_run(RUN_A)
    for frame in (partial(make_probe, seq=9), partial(make_probe, srcsys=1),
                  partial(make_probe, version=1)):
        result = _diff(golden, _probe_run(RUN_B, frame=frame))
        assert [d.kind for d in result.divergences] == ["changed"] * 4, _report(result)

    def warning(token: str) -> bytes:
        text = (PROBE_PREFIX + token).encode()
        msg = mavlink2.MAVLink_statustext_message(mavlink2.MAV_SEVERITY_WARNING, text)
        return pack_message(msg)
    result = _diff(golden, _probe_run(RUN_A, frame=warning))
    assert [d.kind for d in result.divergences] == ["changed"] * 4, _report(result)
    fields = {f for f, _, _ in result.divergences[0].fields}
    assert "payload" in fields and "payload.probe.stem" in fields


def test_the_ack_of_a_probe_follows_its_probe():
    """An ACK is keyed by what it acknowledges: the ACK of probe #1 reads the same in both runs;
    with a probe changed, the ACK's move is that change's consequence, not a second report."""
    golden = _probe_run(RUN_A)
    assert _diff(golden, _probe_run(RUN_B, seq0=9)).same
    changed = RUN_B[:1] + ["something_else-1-1"] + RUN_B[2:]
    result = _diff(golden, _probe_run(changed))
    (d,) = result.divergences
    assert d.golden.action == Action.MAV_PASSTHROUGH, _report(result)


def _commands_and_acks(order: list[tuple[str, int]]) -> list[D]:
    """("cmd", n): the manager's n-th command to drone 1 (seq 500 + n: WP_Off, Start_Mission,
    End_Mission, told apart by their ACKs' keys); ("ack", n): its ACK."""
    mgr, drone = ("127.0.0.1", 7889), ("127.0.0.1", 7890)
    out: list[D] = []
    acks = 0
    for what, n in order:
        if what == "cmd":
            action = (Action.WP_OFF, Action.START_MISSION, Action.END_MISSION)[n]
            data = encode(Message(1, 0, 500 + n, action))
            out.append(D(len(out), 10**18 + len(out) * 1000, mgr, drone, data))
        else:
            data = encode(Message(0, 1, 80 + acks, Action.ACK, 500 + n))
            acks += 1
            out.append(D(len(out), 10**18 + len(out) * 1000, drone, mgr, data))
    return out


def test_acks_of_commands_in_flight_together_read_in_the_commands_order():
    """Two of the batch's cases sent a command each within a fraction of a millisecond; the
    reference drone ACKed the second first in one run of four (issue 35). ACKs of messages
    sent before either ACK are compared in those messages' order; an ACK that came after
    a later command (not in flight together with it) still reorders."""
    golden = _commands_and_acks([("cmd", 0), ("ack", 0), ("cmd", 1), ("ack", 1), ("cmd", 2),
                                 ("ack", 2)])
    raced = _commands_and_acks([("cmd", 0), ("cmd", 1), ("ack", 1), ("ack", 0), ("cmd", 2),
                                ("ack", 2)])
    assert _diff(golden, raced).same, _report(_diff(golden, raced))
    late = _commands_and_acks([("cmd", 0), ("cmd", 1), ("ack", 1), ("cmd", 2), ("ack", 0),
                               ("ack", 2)])
    result = _diff(golden, late)
    assert result.divergences and {d.kind for d in result.divergences} == {"reordered"}, \
        _report(result)


def test_a_header_cut_short_is_compared_without_its_seq():
    """MCP-ROB-1 sends a header cut at 16 bytes numbered from the runner's counter, whose
    value depends on how the batch's cases drew from it: two runs differ only by that seq.
    Any other byte of it still differs."""
    from mcp_conform.spec.codec import HEADER_SIZE, build_datagram

    def run(cut: bytes) -> list[D]:
        mgr, drone = ("127.0.0.1", 7889), ("127.0.0.1", 7890)
        return [D(0, 10**18, mgr, drone, cut)]

    def cut(seq: int, dst: int = 1) -> bytes:
        return build_datagram(dst, 0, seq, int(Action.WP_OFF))[:HEADER_SIZE - 1]
    assert _diff(run(cut(0x533)), run(cut(0x532))).same
    result = _diff(run(cut(0x533)), run(cut(0x533, dst=2)))
    assert [d.kind for d in result.divergences] == ["changed"], _report(result)
    assert result.divergences[0].fields[0][0] == "bytes"


def test_an_ack_naming_an_acks_number_names_nothing_as_one_naming_no_message():
    """MCP-ACK-6's probe, an ACK naming a number the runner never sent: an ACK is never ACKed,
    so one that happens to name one of the node's ACKs (their numbers share the node's space)
    names nothing ackable, as one naming no message at all. Two whole-suite captures of the
    reference node differed only there (a fresh-clone CI run: "ACK of seq+71 (ACK)" against
    "ACK of seq+11526 (no such message)")."""
    golden = challenge2()
    drone_ack = next(decode(d.data) for d in golden if decode(d.data).action == Action.ACK and decode(d.data).src == 1)
    last = golden[-1]

    def probe(named: int) -> list[D]:
        data = encode(Message(1, 0, 60000, Action.ACK, named))
        return reindex([*golden, last._replace(t_ns=last.t_ns + 1_000_000, src_addr=last.dst_addr,
                                               dst_addr=last.src_addr, data=data)])
    result = _diff(probe(drone_ack.seq), probe((drone_ack.seq + 0x4000) & 0xFFFF))
    assert result.same, _report(result)

"""``mcp-capture check|show|diff --protocol mavlink`` (issue 39 item 4) on a MAVProxy ``.tlog``
and on our captures, judged by the MAVLink trace monitor (``judge.mavlink_monitor``).

``data/mavproxy-vehicle.tlog`` is the telemetry log MAVProxy 1.8.75 wrote (``--master
tcp:... --streamrate 1``, its console driven: ``param set WPNAV_SPEED 500``, ``mode GUIDED``,
``wp load`` of three items, ``wp list``, ``arm throttle``) against our vehicle
(``mcp-vehicle``): 164 records, 6 KB. It is checked clean; the same log with one record taken
out or doubled fails exactly the rule of that fault. The slow tests write a fresh one with a
real MAVProxy, run ``mcp-conform --protocol mavlink --capture`` against our vehicle and the
faulty ones (tests/mavlink/faulty_vehicle.py) and compare the capture's verdicts with the
run's cases: the same traffic, the same rule failed offline as live.
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
import time
from pathlib import Path

import pytest

from mcp_conform.captures.cli import main
from mcp_conform.captures.mavlink import judge_trace
from mcp_conform.judge.mavlink_monitor import ORDER_SLACK_S, MavlinkMonitor
from mcp_conform.spec import MAVLINK
from mcp_conform.traceio.mavlink import MavFrame, is_mavlink_capture, open_trace

DATA = Path(__file__).with_name("data")
TLOG = DATA / "mavproxy-vehicle.tlog"
FAULTY = Path(__file__).parents[1] / "mavlink" / "faulty_vehicle.py"
MAV = MAVLINK.dialect
VEHICLE = (1, 1)


def check(tmp_path: Path, path: Path | str, *extra: str) -> tuple[int, dict, str, str]:
    """``mcp-capture check --protocol mavlink PATH --json``: (exit code, JSON, stdout, stderr)."""
    out = tmp_path / "check.json"
    out.unlink(missing_ok=True)
    import contextlib
    import io

    so, se = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
        rc = main(["check", "--protocol", "mavlink", str(path), "--json", str(out), *extra])
    doc = json.loads(out.read_text()) if out.exists() else {}
    return rc, doc, so.getvalue(), se.getvalue()


def bad_rules(doc: dict) -> set[str]:
    return {r for r, v in doc["rules"].items() if v in ("failed", "warned")}


def records(path: Path) -> list[tuple[MavFrame, bytes]]:
    """Each frame of a tlog with its record's bytes as they are in the file (a tlog's records
    follow one another: 8 bytes of time, then the frame)."""
    data = path.read_bytes()
    out, at = [], 0
    for f in open_trace(path):
        assert isinstance(f, MavFrame)
        out.append((f, data[at:at + 8 + len(f.raw)]))
        at += 8 + len(f.raw)
    assert at == len(data)
    return out


# ---------------------------------------------------------------- MAVProxy's tlog
def test_mavproxy_tlog_is_checked_clean(tmp_path):
    rc, doc, out, err = check(tmp_path, TLOG)
    assert rc == 0 and doc["verdict"] == "OK" and not bad_rules(doc), out + err
    passed = {r for r, v in doc["rules"].items() if v == "passed"}
    assert passed >= {"MAV-HB-1", "MAV-HB-2", "MAV-HB-3", "MAV-HB-4", "MAV-CMD-1", "MAV-CMD-3", "MAV-CMD-7",
                      "MAV-PRM-1", "MAV-PRM-2", "MAV-PRM-7", "MAV-PRM-10", "MAV-MIS-1", "MAV-MIS-2",
                      "MAV-MIS-8", "MAV-MIS-9", "MAV-MIS-20", "MAV-MIS-21"}, doc["rules"]
    assert doc["rules"]["MAV-HB-11"] == "not_observed"  # a tlog cannot tell a lost frame from a skipped seq
    assert {n["id"]: n["role"] for n in doc["nodes"]} == {"1/1": "vehicle", "255/230": "gcs"}
    assert doc["file"]["format"] == "tlog" and doc["frames"] == 164 and is_mavlink_capture(TLOG)


FIRST_NS = next(iter(open_trace(TLOG))).t_ns


def _ack_of(command: int):
    return lambda f: f.name == "COMMAND_ACK" and f.msg.command == command


FAULTS = {
    # the vehicle's COMMAND_ACK of MAV_CMD_DO_SET_MODE taken out
    "ack-removed": ("drop", _ack_of(MAV.MAV_CMD_DO_SET_MODE), "MAV-CMD-1"),
    # the same ACK twice
    "double-ack": ("double", _ack_of(MAV.MAV_CMD_DO_SET_MODE), "MAV-CMD-3"),
    # the vehicle's HEARTBEATs from +2 s to +6 s taken out: a gap of 4+ s
    "heartbeat-gap": ("drop", lambda f: f.name == "HEARTBEAT" and f.source == VEHICLE
                      and 2e9 < f.t_ns - FIRST_NS < 6e9, "MAV-HB-1"),
    # the vehicle's request for item 1 taken out: it asks for 0, then 2
    "item-out-of-order": ("drop", lambda f: f.name in ("MISSION_REQUEST", "MISSION_REQUEST_INT")
                          and f.source == VEHICLE and f.msg.seq == 1, "MAV-MIS-2"),
    # the PARAM_VALUE that echoes the PARAM_SET (index 65535, E-8) taken out
    "param-echo-removed": ("drop", lambda f: f.name == "PARAM_VALUE" and f.msg.param_index == 65535,
                           "MAV-PRM-7"),
}


@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_one_fault_injected_fails_its_rule_and_no_other(tmp_path, fault):
    how, pick, rule = FAULTS[fault]
    recs = records(TLOG)
    hit = [f.index for f, _ in recs if pick(f)]
    assert hit and (how == "drop" or len(hit) == 1), hit
    body = b"".join(raw * (2 if how == "double" and pick(f) else 1) for f, raw in recs
                    if how == "double" or not pick(f))
    faulty = tmp_path / f"{fault}.tlog"
    faulty.write_bytes(body)
    rc, doc, out, err = check(tmp_path, faulty)
    assert rc == 1 and doc["verdict"] == "FAILED", out + err
    assert bad_rules(doc) == {rule}, out
    assert f"{rule} MUST" in out and "expected" in out
    so = io.StringIO()
    with contextlib.redirect_stdout(so):
        assert main(["show", "--protocol", "mavlink", str(faulty)]) == 0
    marked = {int(line.split()[1][1:]) for line in so.getvalue().splitlines() if line.endswith(f"✗ {rule}")}
    assert marked == {i for v in doc["violations"] for i in v["frames"]}, so.getvalue()  # show marks its evidence


def test_a_tlog_is_recognised_without_protocol(tmp_path, capsys):
    """``mcp-capture check FILE.tlog``, no --protocol: each profile's detector is asked in turn
    and one that cannot read the file (Nsqd's: CaptureError) says "not mine", so MAVLink's
    recognises it; a file no protocol reads keeps the one-line error, exit 2."""
    out = tmp_path / "auto.json"
    assert main(["check", str(TLOG), "--json", str(out)]) == 0, capsys.readouterr()
    doc = json.loads(out.read_text())
    assert doc["protocol"] == "mavlink" and doc["file"]["format"] == "tlog" and doc["frames"] == 164
    text = tmp_path / "notes.txt"
    text.write_text("hello, this is no capture\n")
    capsys.readouterr()
    assert main(["check", str(text)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a capture" in err[0] and "Traceback" not in err[0], err


# ---------------------------------------------------------------- bad input
@pytest.mark.parametrize(("content", "says"), [
    (b"", "empty file, not a MAVLink trace"),
    (b"hello, this is a text file and no telemetry log\n", "not a MAVLink trace (starts 68 65"),
    (TLOG.read_bytes()[:8] + b"\x00" * 40, "not a MAVLink trace"),
])
def test_a_file_that_is_no_trace_is_one_line_exit_2(tmp_path, content, says):
    bad = tmp_path / "bad.tlog"
    bad.write_bytes(content)
    rc, _, out, err = check(tmp_path, bad)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and says in lines[0] and "Traceback" not in out + err, (out, err)


def test_a_cut_tlog_is_judged_up_to_its_last_record(tmp_path):
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(TLOG.read_bytes()[:3001])
    rc, doc, out, err = check(tmp_path, cut)
    assert rc == 0 and doc["verdict"] == "INCOMPLETE" and "TRUNCATED: " in out, out + err
    assert doc["file"]["truncated"].endswith("after the last whole record (a cut or damaged file)")
    assert 0 < doc["frames"] < 164


def test_garbage_between_records_is_survived(tmp_path):
    """Bytes that are no record in the middle of a log: pymavlink's reader finds the next
    record; nothing is put on a sender (a tlog does not say who sent them)."""
    recs = records(TLOG)
    body = b"".join(raw for _, raw in recs[:50]) + b"\x55" * 23 + b"".join(raw for _, raw in recs[50:])
    damaged = tmp_path / "damaged.tlog"
    damaged.write_bytes(body)
    rc, doc, out, err = check(tmp_path, damaged)
    assert rc in (0, 1) and "Traceback" not in out + err and doc["frames"] >= 150, out + err


def test_a_damaged_records_bytes_are_not_read_as_a_time_of_ages(tmp_path):
    """A record whose frame is junk after a start marker: pymavlink's robust reader takes bytes
    of the junk for the next records' times (a session of 3455895529195.7 s was reported). A
    time no tlog can hold is no time: such a record keeps the last good one, so the trace spans
    what its good records span."""
    good = [r.t_ns for r in open_trace(TLOG) if isinstance(r, MavFrame)]
    damaged = tmp_path / "damaged-first.tlog"
    damaged.write_bytes(TLOG.read_bytes()[:8] + b"\xfd" + bytes(range(40)) + TLOG.read_bytes())
    times = [r.t_ns for r in open_trace(damaged) if isinstance(r, MavFrame)]
    assert len(times) > len(good) and min(good) <= min(times) and max(times) <= max(good), (min(times), max(times))
    rc, doc, out, err = check(tmp_path, damaged)
    span = (max(good) - min(good)) / 1e9
    assert rc in (0, 1) and "Traceback" not in out + err and f" over {span:.1f} s" in out.splitlines()[0], out + err


# ---------------------------------------------------------------- show and diff
def test_show_lists_the_frames_and_diff_compares_the_conversations(tmp_path, capsys):
    assert main(["show", "--protocol", "mavlink", str(TLOG), "--from", "3", "--to", "4"]) == 0
    shown = capsys.readouterr().out
    assert "1/1 vehicle COMMAND_ACK" in shown and "255/230 gcs MISSION_COUNT" in shown
    assert "PARAM_REQUEST_LIST" not in shown  # before +3 s
    assert main(["diff", "--protocol", "mavlink", str(TLOG), str(TLOG)]) == 0
    assert capsys.readouterr().out.startswith("same: ")
    recs = records(TLOG)
    gone = tmp_path / "gone.tlog"
    gone.write_bytes(b"".join(raw for f, raw in recs if not _ack_of(MAV.MAV_CMD_DO_SET_MODE)(f)))
    assert main(["diff", "--protocol", "mavlink", str(TLOG), str(gone)]) == 1
    out = capsys.readouterr().out
    assert "missing (vehicle's messages):" in out and "vehicle COMMAND_ACK command=176" in out


# ---------------------------------------------------------------- the monitor, frame by frame
def _frames(*items: tuple[float, tuple[int, int], str, dict]) -> list[tuple[int, bytes]]:
    """Frames packed by pymavlink's dialect: (time s, sender, message, fields)."""
    coders: dict[tuple[int, int], object] = {}
    out = []
    for t, src, name, fields in items:
        enc = coders.setdefault(src, MAV.MAVLink(None, srcSystem=src[0], srcComponent=src[1]))
        msg = getattr(enc, name.lower() + "_encode")(**fields)
        out.append((int(t * 1e9), bytes(msg.pack(enc))))
        enc.seq = (enc.seq + 1) % 256
    return out


def _beats(until: float) -> list[tuple[float, tuple[int, int], str, dict]]:
    vehicle = {"type": MAV.MAV_TYPE_QUADROTOR, "autopilot": MAV.MAV_AUTOPILOT_ARDUPILOTMEGA, "base_mode": 0,
               "custom_mode": 0, "system_status": MAV.MAV_STATE_STANDBY}
    gcs = {**vehicle, "type": MAV.MAV_TYPE_GCS, "autopilot": MAV.MAV_AUTOPILOT_INVALID}
    return [x for s in range(int(until) + 1) for x in ((float(s), VEHICLE, "HEARTBEAT", vehicle),
                                                        (s + 0.5, (255, 190), "HEARTBEAT", gcs))]


@pytest.mark.parametrize(("ack_at", "verdict"), [(2.05, "passed"), (2.0 - ORDER_SLACK_S / 2, "passed"),
                                                  (2.0 - ORDER_SLACK_S - 0.2, "failed")])
def test_an_answer_stamped_just_before_its_request_is_its_answer(ack_at, verdict):
    """A recorder that stamps a frame after sending it (the runner's link) can stamp the
    answer first: an ACK up to ORDER_SLACK_S before its command answers it, not one earlier."""
    cmd = {"target_system": 1, "target_component": 1, "command": MAV.MAV_CMD_DO_SET_MODE, "confirmation": 0,
           "param1": 1, "param2": 4, "param3": 0, "param4": 0, "param5": 0, "param6": 0, "param7": 0}
    ack = {"command": MAV.MAV_CMD_DO_SET_MODE, "result": MAV.MAV_RESULT_ACCEPTED, "progress": 0,
           "result_param2": 0, "target_system": 255, "target_component": 190}
    items = sorted([*_beats(5), (2.0, (255, 190), "COMMAND_LONG", cmd), (ack_at, VEHICLE, "COMMAND_ACK", ack)],
                   key=lambda x: x[0])
    mon = MavlinkMonitor()
    for t, raw in _frames(*items):
        mon.frame(t, raw)
    mon.finish()
    v = mon.verdicts()
    assert v["MAV-CMD-1"] == verdict and v["MAV-CMD-3"] != "failed", mon.violations
    assert v["MAV-HB-1"] == v["MAV-HB-2"] == "passed"


def _mission_upload_crossed(gap: float) -> dict[str, str]:
    """An upload of 5 items the ground station leaves after item 2 (ArduPilot then re-requests
    seq 3 each second), a new upload's MISSION_COUNT, and the old re-request ``gap`` s after it
    before the new upload's request for seq 0."""
    gcs, to_v = (255, 190), {"target_system": 1, "target_component": 1, "mission_type": 0}
    req = lambda seq: (VEHICLE, "MISSION_REQUEST_INT",  # noqa: E731
                       {"target_system": 255, "target_component": 190, "seq": seq, "mission_type": 0})
    item = lambda seq: (gcs, "MISSION_ITEM_INT", {**to_v, "seq": seq, "frame": 3, "command": 16,  # noqa: E731
                                                   "current": 0, "autocontinue": 1, "param1": 0, "param2": 0,
                                                   "param3": 0, "param4": 0, "x": 357713000, "y": -786744000, "z": 10})
    t = 1.0
    items = [(t, gcs, "MISSION_COUNT", {**to_v, "count": 5})]
    for seq in range(3):
        items += [(t + 0.1 + 0.2 * seq, *req(seq)), (t + 0.15 + 0.2 * seq, *item(seq))]
    items += [(2.0, *req(3)), (3.0, *req(3)), (3.5, gcs, "MISSION_COUNT", {**to_v, "count": 2}),
              (3.5 + gap, *req(3)), (3.6 + gap, *req(0)), (3.65 + gap, *item(0)), (3.7 + gap, *req(1)),
              (3.75 + gap, *item(1)),
              (3.8 + gap, VEHICLE, "MISSION_ACK", {"target_system": 255, "target_component": 190, "type": 0,
                                                    "mission_type": 0})]
    mon = MavlinkMonitor()
    for t_ns, raw in _frames(*sorted([*_beats(6), *items], key=lambda x: x[0])):
        mon.frame(t_ns, raw)
    mon.finish()
    return mon.verdicts()


def test_a_request_of_the_upload_a_new_count_replaced_is_not_the_new_ones():
    """A re-request of the left upload that crossed the new upload's MISSION_COUNT (sent before
    the vehicle read it) is the old upload's, not the new one's first request out of order
    (MAV-MIS-2); one sent long after the count is the new upload's, out of order."""
    assert _mission_upload_crossed(0.02)["MAV-MIS-2"] == "passed"
    assert _mission_upload_crossed(2.0)["MAV-MIS-2"] == "failed"


@pytest.mark.parametrize("step", [0.0005, 0.05])
def test_an_item_out_of_sequence_answered_invalid_sequence_leaves_the_upload_going_on(step):
    """E-1: ArduPilot answers an item out of sequence with MISSION_ACK MAV_MISSION_INVALID_SEQUENCE
    and re-requests the expected item on its 1-s timer; the upload goes on ("A MISSION_ACK
    returning an error value (NACK) does not terminate the upload"). Its re-requests are that
    upload's, not the next upload's first requests stamped before its MISSION_COUNT when the
    frames come ``step`` apart, within ORDER_SLACK_S (before: MAV-MIS-2 "seq 1 after none" and
    "seq 0 after seq 3" against our vehicle, a capture of the live monitor's false verdict)."""
    gcs, to_v = (255, 190), {"target_system": 1, "target_component": 1, "mission_type": 0}
    req = lambda seq: (VEHICLE, "MISSION_REQUEST_INT",  # noqa: E731
                       {"target_system": 255, "target_component": 190, "seq": seq, "mission_type": 0})
    item = lambda seq: (gcs, "MISSION_ITEM_INT", {**to_v, "seq": seq, "frame": 3, "command": 16,  # noqa: E731
                                                   "current": 0, "autocontinue": 1, "param1": 0, "param2": 0,
                                                   "param3": 0, "param4": 0, "x": 357713000, "y": -786744000, "z": 10})
    ack = lambda kind: (VEHICLE, "MISSION_ACK", {"target_system": 255, "target_component": 190,  # noqa: E731
                                                 "type": kind, "mission_type": 0})
    first = [(gcs, "MISSION_COUNT", {**to_v, "count": 3}), req(0), item(0), req(1), item(2),
             ack(MAV.MAV_MISSION_INVALID_SEQUENCE)]
    again = [req(1), item(1), req(2), item(2), ack(MAV.MAV_MISSION_ACCEPTED),
             (gcs, "MISSION_COUNT", {**to_v, "count": 2}), req(0), item(0), req(1), item(1),
             ack(MAV.MAV_MISSION_ACCEPTED)]
    items = [(1.0 + k * step, *x) for k, x in enumerate(first)] + [(2.2 + k * step, *x) for k, x in enumerate(again)]
    mon = MavlinkMonitor()
    for t_ns, raw in _frames(*sorted([*_beats(5), *items], key=lambda x: x[0])):
        mon.frame(t_ns, raw)
    mon.finish()
    v = mon.verdicts()
    assert v["MAV-MIS-2"] == "passed" and v["MAV-MIS-1"] == "passed", mon.violations


# ---------------------------------------------------------------- slow: real sessions
def _conform(tmp_path: Path, *args: str) -> tuple[int, dict, Path, str]:
    from tests.forkserver import run_module

    report, capture = tmp_path / "run.json", tmp_path / "run.mcap"
    proc = run_module("conformance", ["--protocol", "mavlink", "--json", str(report), "--capture", str(capture),
                                      *args], timeout=300)
    assert report.exists(), proc.stdout + proc.stderr
    return proc.returncode, json.loads(report.read_text()), capture, proc.stdout + proc.stderr


def _agreement(run: dict, doc: dict) -> tuple[list[str], list[str]]:
    """The rules both the run's cases and the capture's check judged, and those on which
    they disagree (passed against failed or warned)."""
    both = [r for r, v in doc["rules"].items()
            if v != "not_observed" and run["rules"].get(r) in ("passed", "failed", "warned")]
    return both, [r for r in both if (doc["rules"][r] == "passed") != (run["rules"][r] == "passed")]


@pytest.mark.slow
def test_our_capture_is_clean_and_agrees_with_the_cases(tmp_path, tmp_path_factory):
    """Our vehicle's whole suite over TCP (the session's one run, tests/mavlink/reference_run.py):
    its capture checked clean offline, each rule the cases judged judged the same there."""
    from tests.mavlink.reference_run import reference_vehicle_run

    rc, run, capture, out = reference_vehicle_run(tmp_path_factory)
    assert rc == 0, out
    crc, doc, cout, cerr = check(tmp_path, capture)
    assert crc == 0 and doc["verdict"] == "OK" and not bad_rules(doc), cout + cerr
    assert doc["parameters"]["roles"] == ["vehicle"] and doc["parameters"]["complete"] and doc["rules"]["MAV-HB-11"] == "passed"
    both, differ = _agreement(run, doc)
    assert len(both) >= 25 and not differ, (both, differ)


#: faulty vehicles (tests/mavlink/faulty_vehicle.py) whose rule the capture shows, the cases
#: that judge it (--select)
OFFLINE_FAULTS = {
    "double-ack": ("MAV-CMD-3", "CMD"),
    "no-unsupported-ack": ("MAV-CMD-5", "CMD"),  # offline also MAV-CMD-1: below
    "acts-for-other-system": ("MAV-CMD-14", "CMD"),
    "acts-for-other-component": ("MAV-CMD-14", "CMD"),
    "type-gcs": ("MAV-HB-3", "HB"),
    "bad-param-type": ("MAV-PRM-10", "PRM"),
    "download-param1": ("MAV-MIS-9", "MIS"),
}


#: the faults whose run is the session's whole-suite run through the proxy
#: (tests/mavlink/reference_run.py's, whose verdicts tests/mavlink/test_conform_mavlink.py judges)
#: rather than one of their group alone: the same rule failed, offline as live, on more traffic
WHOLE_SUITE = ("double-ack",)


@pytest.mark.slow
@pytest.mark.parametrize("fault", sorted(OFFLINE_FAULTS))
def test_a_faulty_vehicle_fails_the_same_rule_offline_as_live(tmp_path, tmp_path_factory, fault):
    rule, group = OFFLINE_FAULTS[fault]
    if fault in WHOLE_SUITE:
        from tests.mavlink.reference_run import faulty_vehicle_run

        rc, run, capture, out = faulty_vehicle_run(tmp_path_factory, fault)
    else:
        spawn = f"{sys.executable} {FAULTY} --listen {{target_host}}:{{target_port}} --fault {fault} --duration 200"
        rc, run, capture, out = _conform(tmp_path, "--spawn", spawn, "--select", group)
    # failed rules only: our vehicle's own SHOULD warnings (ArduCopter's, docs/guide/mavlink-vehicle.md)
    # come with every group's run
    live = {r for r, v in run["rules"].items() if v == "failed"}
    assert rc == 1 and live == {rule}, out
    crc, doc, cout, cerr = check(tmp_path, capture)
    # the proxy drops every COMMAND_ACK whose result is UNSUPPORTED: also our vehicle's answer
    # to the calibration the IN_PROGRESS case sends, a known command left unanswered (MAV-CMD-1,
    # which the monitor proves; the case itself skips, having no answer to judge)
    also = {"MAV-CMD-1"} if fault == "no-unsupported-ack" else set()
    assert crc == 1 and bad_rules(doc) == {rule} | also, cout + cerr
    assert not [r for r in _agreement(run, doc)[1] if r not in also]


@pytest.mark.slow
def test_a_live_mavproxy_session_writes_a_tlog_checked_clean(tmp_path):
    """MAVProxy 1.8.75 (its console driven through a pipe) against our vehicle, its own
    telemetry log: clean; the session's commands, parameter set and mission each judged."""
    from tests.vehicle.clients import WAIT, MavproxyProcess, mavproxy_command, served

    class LoggingMavproxy(MavproxyProcess):
        """MavproxyProcess's MAVProxy with its telemetry log (no --no-state)."""

        def __init__(self, link, workdir: str) -> None:
            import os
            import queue
            import subprocess
            import threading

            args = mavproxy_command() + ["--master", link.pymavlink, "--state-basedir", workdir,
                                         "--streamrate", "1"]
            self.lines, self._new, self.started = [], queue.Queue(), time.monotonic()
            self.proc = subprocess.Popen(args, cwd=workdir, env=dict(os.environ, PYTHONUNBUFFERED="1", TERM="dumb"),
                                         text=True, bufsize=1, errors="replace", stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
            self._reader = threading.Thread(target=self._read, name="mavproxy-out", daemon=True)
            self._reader.start()

    mavproxy_command()
    mission = tmp_path / "mission.txt"
    mission.write_text("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t35.771332\t-78.674421\t0\t1\n"
                       "1\t0\t3\t22\t0\t0\t0\t0\t0\t0\t10\t1\n2\t0\t3\t16\t0\t0\t0\t0\t35.771103\t-78.674659\t10\t1\n")
    with served("tcp") as (_, link), LoggingMavproxy(link, str(tmp_path)) as mp:
        mp.send("set flushlogs 1")  # its log written as it comes (else it loses its buffered tail)
        mp.expect(r"Received \d+ parameters", 20.0)
        mp.send("param set WPNAV_SPEED 500")
        mp.send("mode GUIDED")
        mp.expect(r"COMMAND_ACK: DO_SET_MODE: ACCEPTED", WAIT)
        mp.send(f"wp load {mission}")
        mp.expect(r"MISSION_ACK: TYPE_MISSION: ACCEPTED", WAIT)
        mp.send("wp list")
        mp.expect(r"Saved 3 waypoints", WAIT)
        time.sleep(4.0)  # the parameter list is judged once param_list_gap_max_s (2 s) passed after it
        mp.send("exit")
        mp.proc.stdin.close()  # (with its console still open, MAVProxy does not end)
        mp.proc.wait(20)  # a clean exit: its log writer writes what it still holds
    tlog = tmp_path / "mav.tlog"
    rc, doc, out, err = check(tmp_path, tlog)
    assert rc == 0 and not bad_rules(doc), out + err
    judged = {r for r, v in doc["rules"].items() if v == "passed"}
    assert judged >= {"MAV-HB-1", "MAV-HB-2", "MAV-CMD-1", "MAV-PRM-2", "MAV-PRM-7", "MAV-MIS-1", "MAV-MIS-2",
                      "MAV-MIS-9"}, doc["rules"]
    assert judge_trace(tlog).format == "tlog"


def test_select_and_exclude_pick_the_rules_judged(tmp_path):
    """``--select``/``--exclude`` take prefixes of the rule IDs, with or without ``MAV-``."""
    gap = tmp_path / "gap.tlog"
    how, pick, rule = FAULTS["heartbeat-gap"]
    gap.write_bytes(b"".join(raw for f, raw in records(TLOG) if not pick(f)))
    for args, rc_want, kept in ((("--select", "CMD"), 0, "MAV-CMD-"), (("--exclude", "HB"), 0, None),
                                (("--select", "MAV-HB"), 1, "MAV-HB-"), (("--select", "HB-1"), 1, "MAV-HB-1"),
                                (("--select", "HB", "--exclude", "HB-1"), 0, "MAV-HB-")):
        rc, doc, out, _ = check(tmp_path, gap, *args)
        assert rc == rc_want and doc["rules"], (args, out)
        if kept is None:
            assert not any(r.startswith("MAV-HB-") for r in doc["rules"]), doc["rules"]
        else:
            assert all(r.startswith(kept) for r in doc["rules"]), doc["rules"]


def test_an_mcp_drone_runs_autopilot_link_is_judged_as_the_vehicles(tmp_path):
    """An MCP drone run's capture holds its autopilot link on ``/mavlink`` too: it stays MCP's
    (no --protocol: not recognised as MAVLink's); with ``--protocol mavlink`` the simulated
    vehicle's rules are judged, not its other side (the drone application and the runner's
    own liveness probes, sent as STATUSTEXT with sequence number 0)."""
    golden = Path(__file__).parents[2] / "captures" / "golden" / "drone-suite.mcap"
    assert not is_mavlink_capture(golden)
    rc, doc, out, err = check(tmp_path, golden)
    assert rc == 0 and doc["parameters"]["roles"] == ["vehicle"] and not bad_rules(doc), out + err
    assert {n["id"]: n["role"] for n in doc["nodes"]}["1/1"] == "vehicle"
    assert doc["rules"]["MAV-HB-1"] == doc["rules"]["MAV-HB-11"] == "passed"


@pytest.mark.parametrize(("segments", "hb11"), [(True, "passed"), (False, "failed")])
def test_a_ground_station_started_afresh_in_a_new_session_numbers_its_frames_anew(segments, hb11):
    """The gcs role's runner starts each ground station afresh, and its capture marks each run a
    session (``McapRecorder.begin_segment``): there its sequence numbers restart from 0 as a
    new process's do, no gap for MAV-HB-11, and its first command's confirmation 0 is no resend
    for MAV-CMD-8. In one session the same restart is a gap (the monitor judged the reference
    GCS's captures so, and warned MAV-CMD-8)."""
    cmd = {"target_system": 1, "target_component": 1, "command": MAV.MAV_CMD_DO_SET_MODE, "confirmation": 0,
           "param1": 1, "param2": 4, "param3": 0, "param4": 0, "param5": 0, "param6": 0, "param7": 0}
    # the runner withholds the ACK (MAV-CMD-6's case), then starts the next run
    run = sorted([*_beats(1), (1.2, (255, 190), "COMMAND_LONG", cmd)], key=lambda x: x[0])
    mon = MavlinkMonitor(roles=("gcs",), complete=True)
    for n in (1, 2):  # the same run twice, its parties' numbers from 0 each time
        for t, raw in _frames(*run):
            seg = f"gcs-run-{n}" if segments else None
            mon.feed(MavFrame(mon.count, t + (n - 1) * 1_600_000_000, "rx" if raw[5:7] == b"\xff\xbe" else "tx",
                              raw, MAV.MAVLink(None).parse_char(raw), seg))
    mon.finish()
    v = mon.verdicts()
    assert v["MAV-HB-11"] == hb11 and v["MAV-HB-2"] == "passed", mon.violations
    assert v["MAV-CMD-8"] == ("not_observed" if segments else "warned"), mon.violations  # no resend in a session
    assert [n["id"] for n in mon.to_json()["nodes"]] == ["1/1", "255/190"]

"""The Nsqd stateful engine (issue 21 item 1): faults only a second client or a reconnect
exposes, found by ``mcp-fuzz --protocol nsqd --engine stateful`` against the C backend of
tests/nsqd_backends, confirmed, minimised and replayable; no finding against the correct
backend; the stateless engine, one connection at a time, cannot see the second-client fault."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from mcp_conform.fuzz.nsqd_campaign import StreamCampaign, message_names
from mcp_conform.fuzz.nsqd_mutators import Write
from mcp_conform.fuzz.nsqd_player import Op, _whole_frames, command_bytes
from tests.forkserver import run_module
from tests.nsqd_backends.build import built_or_skip


def _spawn(exe: Path, fault: str | None = None) -> str:
    return f"{exe} --host {{target_host}} --port {{target_port}} --update-period 0.1" + (f" --fault {fault}" if fault else "")


def _replay(finding: Path, spawn: str) -> subprocess.CompletedProcess[str]:
    """``mcp-fuzz --replay``: a child of the tests' fork server (tests/forkserver.py)."""
    return run_module("mcp_conform.fuzz", ["--protocol", "nsqd", "--replay", str(finding), "--spawn", spawn], timeout=120)


def test_an_op_round_trips_through_finding_json():
    op = Op("send", 1, (Write(b"\x00\x00\x00\x05\x08"), Write(b"\x00", "rst")), "split-writes", True, False, note="n")
    assert Op.from_json(json.loads(json.dumps(op.to_json()))) == op
    assert Op.from_json(Op("close", 0, how="rst").to_json()).how == "rst"


def test_cut_and_whole_frames_and_the_tried_names():
    whole = command_bytes("SET_HOVERHEIGHT")
    assert _whole_frames(whole + command_bytes("TAKEOFF"))
    assert not _whole_frames(whole[:-1]) and not _whole_frames(whole[:3])
    assert message_names(whole + command_bytes("TAKEOFF")) == ["SET_HOVERHEIGHT", "TAKEOFF"]
    assert message_names(b"\x00\x00\x00\x05\xf0") == ["unknown"]
    assert message_names(b"\x01\x02") == ["-"]


@pytest.mark.slow
@pytest.mark.nsqd
@pytest.mark.parametrize("fault,rule", [("second-client-kicks-first", "NSQD-CON-2"),
                                        ("stale-partial-frame", "NSQD-ROB-3")])
def test_a_fault_of_several_connections_is_found_and_replays(tmp_path, fault, rule):
    exe = built_or_skip()
    c = StreamCampaign(None, _spawn(exe, fault), 20140307, 120.0, None, tmp_path, engine="stateful", stop_after=1)
    summary = c.run()
    assert [f.signature.rule for f in c.findings] == [rule], summary
    doc = json.loads((tmp_path / "finding-1" / "finding.json").read_text())
    assert doc["replays"] == "3 of 3" and doc["program"], doc
    if fault == "second-client-kicks-first":  # a program of two clients
        assert {o["slot"] for o in doc["program"]} == {0, 1}, doc["program"]
    assert summary["findings"][0]["engine"] == "stateful" and summary["findings_by_class"]
    assert _replay(tmp_path / "finding-1", _spawn(exe, fault)).returncode == 1
    run = _replay(tmp_path / "finding-1", _spawn(exe))
    assert run.returncode == 0, run.stdout + run.stderr


@pytest.mark.slow
@pytest.mark.nsqd
def test_one_connection_at_a_time_cannot_see_the_second_client_fault(tmp_path):
    """The stateless engine's cases on one connection: the same fault gives it nothing."""
    exe = built_or_skip()
    c = StreamCampaign(None, _spawn(exe, "second-client-kicks-first"), 20140307, 60.0, 600, tmp_path)
    summary = c.run()
    assert not [f for f in c.findings if f.signature.rule == "NSQD-CON-2"], summary


@pytest.mark.slow
@pytest.mark.nsqd
@pytest.mark.parametrize("backend", ["c", "reference"])
def test_no_false_alarm_on_a_correct_backend(tmp_path, backend):
    spawn = _spawn(built_or_skip()) if backend == "c" else None
    c = StreamCampaign(None, spawn, 5, 45.0, None, tmp_path, engine="stateful")
    summary = c.run()
    assert summary["findings"] == [] and summary["unconfirmed"] == 0 and summary["cases"] > 50, summary


@pytest.mark.nsqd
def test_a_program_finding_carries_what_a_case_finding_carries(tmp_path):
    """A stateful finding's finding-N/ (issue 21 item 3): finding.json, the input as hex and as
    a bytes literal, stderr, replay.txt, and its confirming replay's traffic as repro.mcap and
    repro.pcap, a TCP conversation per connection that tshark follows to the bytes sent; the
    replay command and ``mcp-capture replay`` of the MCAP reproduce it (exit 1) or not (0)."""
    import shutil

    from mcp_conform.fuzz.nsqd_backend import Backend
    from mcp_conform.fuzz.nsqd_stateful import play_program, triage_program
    from mcp_conform.fuzz.nsqd_triage import StreamTarget, StreamTriage
    from mcp_conform.traceio.nsqd import stream_records
    from mcp_conform.traceio.reader import StreamEvent, StreamFrame

    exe = built_or_skip()
    fault = _spawn(exe, "second-client-kicks-first")
    ops = [Op("open", 0), Op("open", 1), Op("cmd", 0, (Write(command_bytes("TAKEOFF")),), "TAKEOFF", valid=True)]
    b = Backend(None, fault)
    hit = play_program(b, ops)
    assert hit is not None and hit.signature.rule == "NSQD-CON-2", hit
    c = StreamCampaign(None, fault, 1, 10.0, None, tmp_path, engine="stateful")
    triage_program(StreamTriage(target=StreamTarget(b), store=c.store, seed=1, duration=10.0), b, hit, ops).close()
    d = tmp_path / "finding-1"
    assert {"finding.json", "input.hex", "input.py", "stderr.txt", "replay.txt", "repro.mcap", "repro.pcap"} \
        <= {p.name for p in d.iterdir()}
    doc = json.loads((d / "finding.json").read_text())
    assert doc["program"] and doc["replays"] == "3 of 3"
    data = bytes.fromhex((d / "input.hex").read_text())
    assert (d / "input.py").read_text().endswith(f"INPUT = {data!r}\n")
    for what in ("repro.mcap", "repro.pcap"):
        recs = [r for r in stream_records(d / what) if type(r) in (StreamFrame, StreamEvent)]
        assert b"".join(r.raw for r in recs if type(r) is StreamFrame and r.direction == "tx") == data, what
        opened = [r.conn for r in recs if type(r) is StreamEvent and r.event == "open"]
        assert len(opened) == 2, what  # both clients' connections
    assert ("close", "backend") in [(r.event, r.by) for r in recs if type(r) is StreamEvent]  # the first client kicked
    if shutil.which("tshark") is not None:
        from tests.captures.tshark_follow import follow

        per_conn = [b"".join(r.raw for r in recs if type(r) is StreamFrame and r.direction == "tx" and r.conn == k)
                    for k in opened]
        assert [follow(d / "repro.pcap", i)[0] for i in range(len(opened))] == per_conn
    assert _replay(d, fault).returncode == 1
    assert _replay(d, _spawn(exe)).returncode == 0
    run = run_module("mcp_conform.captures", ["replay", str(d / "repro.mcap"), "--spawn", fault], timeout=120)
    assert run.returncode == 1 and "reproduced NSQD-CON-2" in run.stdout, run.stdout + run.stderr


def _frozen_while_a_second_client_connects(fault: str | None) -> tuple[Exception | None, object, int]:
    """Clients 0 then 1 of the C backend, the backend stopped (SIGSTOP) from before the second
    connects until a second later, as a loaded host's scheduler may leave it: what the second
    client's op raised, the first client, and the UPDATEs it had read by the stop."""
    import os
    import signal
    import threading
    import time

    from mcp_conform.fuzz.nsqd_backend import Backend
    from mcp_conform.fuzz.nsqd_player import Hit, Player

    b = Backend(None, _spawn(built_or_skip(), fault))
    pid = b.process.pid
    timer = threading.Timer(1.0, os.kill, (pid, signal.SIGCONT))
    try:
        p = Player(b)
        p.play(Op("open", 0))
        first = p.clients[0]
        os.kill(pid, signal.SIGSTOP)
        while Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "T":
            time.sleep(0.001)  # stopped: it sends nothing more until SIGCONT
        first.conn.pump(0)
        before = len(first.conn.updates())
        timer.start()
        try:
            p.play(Op("open", 1))
        except Hit as hit:
            return hit, first, before
        return None, first, before
    finally:
        timer.cancel()
        os.kill(pid, signal.SIGCONT)
        b.close()


@pytest.mark.nsqd
def test_a_first_client_kicked_late_is_still_judged_at_the_second_clients_connect():
    """NSQD-CON-2 on a loaded host (CI: test_jobs_share_the_example_database, a worker's replay
    of the saved program found nothing): the first client is watched until the backend has gone
    round its loop with the second waiting, not for 0.15 s or until an UPDATE it had sent before
    (the old wait, which a frozen backend's late kick always escaped)."""
    hit, _, _ = _frozen_while_a_second_client_connects("second-client-kicks-first")
    assert hit is not None and hit.signature.rule == "NSQD-CON-2", hit
    assert hit.signature.kind == "first client closed by a second"


@pytest.mark.nsqd
def test_a_correct_backend_frozen_at_the_second_clients_connect_is_no_finding():
    """The same freeze on the correct backend: no finding; the watch ended by the first's
    UPDATEs since the second connected (the backend's own progress), its connection kept."""
    from mcp_conform.fuzz.nsqd_player import LOOP_UPDATES

    hit, first, before = _frozen_while_a_second_client_connects(None)
    assert hit is None, hit
    assert first.conn.closed_at is None and len(first.conn.updates()) >= before + LOOP_UPDATES


def _pipelined(fault: str | None, ops: list[Op]) -> tuple[object, bool]:
    """``ops`` played pipelined on the C backend (``fault``) and judged at their end
    (``Player.finish``): (the hit or None, whether the turnover left a served connection)."""
    from mcp_conform.fuzz.nsqd_backend import Backend
    from mcp_conform.fuzz.nsqd_player import Hit, Player

    b = Backend(None, _spawn(built_or_skip(), fault))
    p = Player(b, fast=True)
    try:
        for op in ops:
            p.play(op)
        spare = p.finish()
        return None, spare is not None and bool(spare.updates())
    except Hit as hit:
        return hit, False
    finally:
        p.close()
        b.close()


def _cmd(slot: int, name: str) -> Op:
    return Op("cmd", slot, (Write(command_bytes(name)),), name, valid=True)


@pytest.mark.nsqd
def test_a_pipelined_program_is_judged_at_its_end_by_the_turnover():
    """Ops written back to back, judged once: the last command's effect by the new
    connection's first UPDATE (NSQD-MSG-3), a first client kicked by a second (NSQD-CON-2);
    on the correct backend, a waiting client's command then its close (bytes the backend
    reads once the first leaves) void the judgement instead of failing it.

    A kick is watched for ``KICK_WATCH_S`` at most in a pipelined program: "the search's
    chance", never a misjudgement (a backend that kicks after that escapes this program; the
    careful replay's ``LOOP_UPDATES`` proves it). On a loaded host its UPDATE of the loop turn
    under way can end the watch before the turn that kicks: the kick is asked for within 3
    programs, as a campaign would meet it again (one try failed once, NSQD-CON-2 not seen)."""
    hit, _ = _pipelined("wrong-stop-test-state", [Op("open", 0), _cmd(0, "TAKEOFF"), _cmd(0, "STOP_TEST")])
    assert hit is not None and hit.signature.rule == "NSQD-MSG-3", hit
    for _ in range(3):
        hit, _ = _pipelined("second-client-kicks-first", [Op("open", 0), Op("open", 1), _cmd(0, "TAKEOFF")])
        if hit is not None:
            break
    assert hit is not None and hit.signature.rule == "NSQD-CON-2", hit
    ops = [Op("open", 0), Op("open", 1), _cmd(1, "CAPTURE_IMAGES"), Op("close", 1), _cmd(0, "TAKEOFF")]
    for program in (ops, [Op("open", 0), _cmd(0, "STOP_TEST")], [Op("open", 0), Op("open", 1), Op("close", 0),
                                                                    _cmd(1, "LAND")]):
        hit, served = _pipelined(None, program)
        assert hit is None and served, (hit, program)


def test_programs_are_seeded_and_leave_no_cut_frame_behind():
    """The same seed, the same programs; every frame cut by FIN or RST is followed in its own
    program by a new connection and a command (NSQD-ROB-3 is judged there, never on the next
    program's first bytes); a program round-trips through the example database's form."""
    from mcp_conform.fuzz.nsqd_programs import StreamProgramGenerator, dumps, loads

    a, b = StreamProgramGenerator(7), StreamProgramGenerator(7)
    programs = [a.program() for _ in range(200)]
    assert programs == [b.program() for _ in range(200)]
    assert programs != [StreamProgramGenerator(7, worker=1).program() for _ in range(200)]
    for ops in programs:
        assert ops[0] == Op("open", 0) and loads(dumps(ops)) == ops
        for i, op in enumerate(ops):
            if op.writes and op.writes[-1].end:
                assert [o.what for o in ops[i + 1:i + 3]] == ["open", "cmd"], [o.describe() for o in ops]
                assert ops[i + 1].slot == ops[i + 2].slot == op.slot
    whats = {o.what for ops in programs for o in ops}
    assert whats == {"open", "cmd", "send", "close"} and any({o.slot for o in ops} == {0, 1} for ops in programs)

"""A backend run with ASan's halt_on_error=0 (issue 36: the real Nsqd backend's ASan build
over-reads on every frame, writes a non-fatal report for each, and goes on, until an aborting
number parse kills it): a replay of its death is judged by the cause the process died of, not by
the non-fatal report on the way, and the over-read is one finding whatever size it read.

The backend is a small fake, written here into tmp_path and spoken to over TCP as the C backend
is: the reference backend's protocol (``reference_impl.nsqd_backend.BackendCore``, a correct
one), plus, for each frame, an AddressSanitizer heap-buffer-overflow report on stderr whose
READ size is the frame's length, and for a frame whose number text is not a number (SET_PID,
SET_RPYTFF: D-3) what an uncaught std::invalid_argument from std::stof writes, then abort(3).
"""

from __future__ import annotations

import json
import sys

import pytest

from mcp_conform.fuzz.nsqd_backend import Backend, _defaults, _reproduces
from mcp_conform.fuzz.nsqd_campaign import StreamCampaign
from mcp_conform.fuzz.nsqd_mutators import Case, Write
from mcp_conform.fuzz.nsqd_oracles import Signature
from mcp_conform.fuzz.nsqd_player import Op
from mcp_conform.fuzz.nsqd_stateful import play_program
from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd_codec import encode

pytestmark = [pytest.mark.slow, pytest.mark.nsqd]

FAKE = r'''
import argparse, os, sys
from mcp_conform.reference_impl.nsqd_backend import BackendCore, BackendServer
from mcp_conform.spec.nsqd_codec import BodyError, decode_body, number_problem

REPORT = """=================================================================
==%(pid)d==ERROR: AddressSanitizer: heap-buffer-overflow on address 0x60300000062b at pc 0x7fd3 bp 0x7ffe sp 0x7ffe
READ of size %(size)d at 0x60300000062b thread T0
    #0 0x7fd3a4c4814a in __interceptor_memcpy ../../../../src/libsanitizer/sanitizer_common/sanitizer_common_interceptors.inc:827
    #1 0x563538e22244 in char* std::copy<char const*, char*>(char const*, char const*, char*) /usr/include/c++/12/bits/stl_algobase.h:620
    #2 0x563538e22244 in Decoder::Decoder(char const*, int) src/Message.hpp:77
    #3 0x563538e22244 in Server::HandleConnection(int*) src/Server.cpp:172
    #4 0x563538e1a3a0 in main src/Main.cpp:484

0x60300000062b is located 0 bytes to the right of %(size)d-byte region [0x603000000610,0x60300000062b)
SUMMARY: AddressSanitizer: heap-buffer-overflow src/Message.hpp:77 in Decoder::Decoder(char const*, int)
"""


class OverreadCore(BackendCore):
    def _handle(self, fr):
        sys.stderr.write(REPORT % {"pid": os.getpid(), "size": 5 + len(fr.body)})
        sys.stderr.flush()
        if self.spec.has_message(fr.msg_id):
            msg = self.spec.message(fr.msg_id)
            try:
                values = decode_body(self.spec, fr.msg_id, fr.body, check_text=False).as_dict()
            except BodyError:
                values = {}
            for f in msg.fields:
                if f.text == "number" and f.name in values and number_problem(values[f.name]):
                    sys.stderr.write("terminate called after throwing an instance of 'std::invalid_argument'\n"
                                     "  what():  stof\n")
                    sys.stderr.flush()
                    os.abort()
        return super()._handle(fr)


p = argparse.ArgumentParser()
p.add_argument("--port", type=int, required=True)
a = p.parse_args()
server = BackendServer("127.0.0.1", a.port, core=OverreadCore(update_period=0.1))
try:
    server.serve(duration=600)
finally:
    server.close()
'''


def test_a_death_after_non_fatal_reports_is_confirmed_by_its_cause(tmp_path):
    script = tmp_path / "overread_backend.py"
    script.write_text(FAKE)
    out = tmp_path / "out"
    out.mkdir()
    c = StreamCampaign(None, f"{sys.executable} {script} --port {{target_port}}", 20140307, 120.0, None, out,
                       stop_after=2)
    summary = c.run()
    names = sorted(f.signature.describe() for f in c.findings)
    assert names == ["crash: abort: uncaught std::invalid_argument [NSQD-ROB-1]",
                     "sanitizer: heap-buffer-overflow in Decoder::Decoder < Server::HandleConnection < main "
                     "[NSQD-ROB-1]"], summary
    assert all(f.replays == f"{c.replays} of {c.replays}" for f in c.findings), summary
    # the over-read's size is the input's: never a signature of its own, counted or found
    assert not any("of size" in k for k in summary["untriaged"]), summary
    docs = [json.loads((out / f"finding-{i}" / "finding.json").read_text()) for i in (1, 2)]
    crash = next(d for d in docs if d["oracle"] == "crash")
    data = b"".join(bytes.fromhex(w["hex"]) for w in crash["writes"])
    assert data, crash  # the input that killed it, minimised, is there to replay


def test_a_replay_of_the_death_goes_on_past_the_reports_before_it(tmp_path):
    """Cases replayed together (a failed probe's window, suspects none of which reproduces
    alone): the first one's non-fatal report is not the replay's verdict, the death is."""
    script = tmp_path / "overread_backend.py"
    script.write_text(FAKE)
    spawn = f"{sys.executable} {script} --port {{target_port}}"
    valid = Case("valid", (Write(encode(NSQD, "STOP_TEST")),), True, "STOP_TEST")
    values = _defaults(NSQD.message("SET_PID")) | {"kp": "abc"}
    bad = Case("bad-number", (Write(encode(NSQD, "SET_PID", **values)),), False, "SET_PID.kp = 'abc'")
    death = Signature("crash", "abort: uncaught std::invalid_argument", (), "NSQD-ROB-1")
    b = Backend(None, spawn)
    try:
        ok, b, hit = _reproduces(b, [valid, valid, valid, bad], death, probe=False)
        assert ok, hit and hit.signature.describe()
        # and a replay that does not die is not the death, however many reports it wrote
        ok, b, hit = _reproduces(b, [valid, valid], death, probe=False)
        assert not ok and hit is not None and hit.signature.oracle == "sanitizer", hit
    finally:
        b.close()


def test_a_program_replay_of_the_death_goes_on_past_the_reports_before_it(tmp_path):
    """The stateful engine's replay (``play_program``) alike: ops that each draw a report, then
    the one that kills the process; without the death it wanted, the report is what it saw."""
    script = tmp_path / "overread_backend.py"
    script.write_text(FAKE)
    values = _defaults(NSQD.message("SET_PID")) | {"kp": "abc"}
    ok_frame, bad_frame = encode(NSQD, "STOP_TEST"), encode(NSQD, "SET_PID", **values)
    valid = [Op("open", 0)] + [Op("send", 0, (Write(ok_frame),), "valid", True, note="STOP_TEST")] * 3
    bad = Op("send", 0, (Write(bad_frame),), "bad-number", False, note="SET_PID.kp = 'abc'")
    death = Signature("crash", "abort: uncaught std::invalid_argument", (), "NSQD-ROB-1")
    b = Backend(None, f"{sys.executable} {script} --port {{target_port}}")
    try:
        b = b.fresh()
        hit = play_program(b, [*valid, bad], want=death)
        assert hit is not None and hit.signature == death, hit and hit.signature
        b = b.fresh()
        hit = play_program(b, valid, want=death)
        assert hit is not None and hit.signature.oracle == "sanitizer", hit and hit.signature
    finally:
        b.close()

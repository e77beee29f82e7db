"""The reference Nsqd backend: its sans-I/O core (bytes and ``now`` in, events, bytes and
the next timer out) and its command line (``mcp-node --protocol nsqd``)."""

from __future__ import annotations

import subprocess
import sys

from mcp_conform.reference_impl.nsqd_backend import BackendCore, Handled, Rejected
from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd_codec import Deframer, decode_body, encode


def _decoded(data: bytes) -> list[tuple[str, dict]]:
    return [(NSQD.message(f.msg_id).name, decode_body(NSQD, f.msg_id, f.body).as_dict())
            for f in Deframer(NSQD).feed(data)]


def test_update_on_its_period_and_none_while_idle():
    core = BackendCore(update_period=0.4)
    assert core.poll(0.0) == b"" and core.next_timer() is None
    core.connect(10.0)
    first = _decoded(core.poll(10.0))
    assert first == [("UPDATE", dict(roll=0, pitch=0, yaw=0, thrust=0, lat=0, lon=0, alt=0, state=0))]
    assert core.poll(10.2) == b"" and core.next_timer() == 10.4
    assert _decoded(core.poll(10.41))[0][0] == "UPDATE"


def test_commands_take_their_effect_from_the_spec_table_even_byte_by_byte():
    core = BackendCore()
    core.connect(0.0)
    events: list = []
    for b in encode(NSQD, "TAKEOFF") + encode(NSQD, "STOP_TEST"):
        events += core.receive(bytes([b]), 0.0)[0]
    assert events == [Handled("TAKEOFF", 2), Handled("STOP_TEST", 10)]
    assert _decoded(core.update_frame())[0][1]["state"] == 10


def test_unknown_ids_and_bad_bodies_are_survived_named_and_answered():
    core = BackendCore()
    core.connect(0.0)
    events, out, close = core.receive(encode(NSQD, "TAKEOFF") + bytes.fromhex("00000008c8010203"), 0.0)
    assert events[1] == Rejected("NSQD-MSG-4", "unknown message id 200") and not close
    assert _decoded(out) == [("ERROR", {"text": "unknown message id 200"})]
    events, out, close = core.receive(encode(NSQD, "SET_PID", kp="1", ki="x", kd="0", flag=1), 0.0)
    assert events[0].rule == "NSQD-MSG-7" and "not a decimal number" in events[0].reason and not close
    assert core.state == 2  # unchanged by what was rejected


def test_a_framing_error_closes_and_a_new_connection_starts_clean():
    core = BackendCore()
    core.connect(0.0)
    events, _, close = core.receive(b"\x00\x00\x00\x00", 0.0)
    assert close and events[0].rule == "NSQD-FRM-4"
    core.disconnect()
    core.connect(1.0)
    core.receive(encode(NSQD, "TAKEOFF")[:3], 1.0)
    assert core.disconnect() == 3  # the cut frame is dropped with its connection (NSQD-ROB-3)
    core.connect(2.0)
    assert core.receive(encode(NSQD, "LAND"), 2.0)[0] == [Handled("LAND", 0)]


def test_cli_one_line_errors():
    run = subprocess.run([sys.executable, "-m", "mcp_conform.reference_impl", "--protocol", "nsqd", "backend",
                          "--bind", "nowhere"], capture_output=True, text=True, timeout=30)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1 and "--bind" in run.stderr
    run = subprocess.run([sys.executable, "-m", "mcp_conform.reference_impl", "--protocol", "xyz"],
                         capture_output=True, text=True, timeout=30)
    assert run.returncode == 2 and "not one of mcp, nsqd" in run.stderr

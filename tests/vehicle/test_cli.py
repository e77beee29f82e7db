"""``mcp-vehicle``: help, one-line usage errors, and serving until interrupted."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from mcp_conform.vehicle.cli import main

ROOT = Path(__file__).resolve().parents[2]


def test_help_exits_zero(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    assert "--fix-delay" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["--listen", "x"], ["--port", "x"], ["--fix-delay", "-1"], ["--home", "1"],
                                  ["--listen", "127.0.0.1:70000"], ["--bogus"]])
def test_bad_arguments_give_one_line_and_status_2(argv: list[str],
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err


def test_serves_until_interrupted() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "mcp_conform.vehicle", "--listen", "127.0.0.1:0", "--fix-delay", "0.2"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
        assert "listening on tcp:127.0.0.1:" in first, first + proc.stderr.read()
        url = first.split()[-1]
        conn = mavutil.mavlink_connection(url, source_system=42, retries=0)
        assert conn.wait_heartbeat(timeout=5) is not None
        conn.arducopter_arm()
        conn.close()
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)  # a bound on a loaded machine, not a timing
        assert proc.returncode == 130  # SIGINT: docs/grammar.md
        assert "connect" in out and "command" in out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_record_has_a_line_for_every_request_with_answer_and_reason(tmp_path: Path) -> None:
    """Issue 35: every request the peer makes is a line of ``--record`` (commands, mode,
    parameters, mission, message rates, data streams, position targets, FTP)."""
    record = tmp_path / "requests.jsonl"
    proc = subprocess.Popen(
        [sys.executable, "-m", "mcp_conform.vehicle", "--listen", "127.0.0.1:0", "--record", str(record)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        assert proc.stdout is not None
        url = ""
        for _ in range(5):  # the first fix may be printed before the address
            line = proc.stdout.readline()
            if "listening on tcp:" in line:
                url = line.split()[-1]
                break
        assert url, proc.stderr.read() if proc.stderr else ""
        conn = mavutil.mavlink_connection(url, source_system=42, retries=0)
        assert conn.wait_heartbeat(timeout=5) is not None
        mav, cmd = conn.mav, mavutil.mavlink
        sends = [
            lambda: mav.command_long_send(1, 1, cmd.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0,
                                          0, 0, 0),
            lambda: mav.set_mode_send(1, cmd.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4),
            lambda: mav.command_long_send(1, 1, cmd.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 30, 1e6, 0,
                                          0, 0, 0, 0),
            lambda: mav.command_long_send(1, 1, cmd.MAV_CMD_DO_DIGICAM_CONTROL, 0, 0, 0, 0, 0,
                                          0, 0, 0),
            lambda: mav.request_data_stream_send(1, 1, cmd.MAV_DATA_STREAM_ALL, 4, 1),
            lambda: mav.param_set_send(1, 1, b"NO_SUCH_PARAM", 1.0, 9),
            lambda: mav.param_request_read_send(1, 1, b"RTL_ALT", -1),
            lambda: mav.set_position_target_local_ned_send(0, 1, 1, 1, 0xDC7, 0, 0, 0, 1, 0, 0,
                                                           0, 0, 0, 0, 0),
            lambda: mav.mission_request_list_send(1, 1),
            lambda: mav.file_transfer_protocol_send(0, 1, 1, b"\x00\x00\x00\x04" + b"\0" * 247),
        ]
        for send in sends:
            send()
        # the link stays open until every line is written: closing it with the vehicle's
        # telemetry unread makes the kernel send a reset, which discards the requests the
        # vehicle had not read yet (a loaded run recorded 1 of 10)
        deadline = time.monotonic() + 10  # a bound on a loaded machine, not a timing
        while time.monotonic() < deadline and len(record.read_text().splitlines()) < len(sends):
            time.sleep(0.1)
        conn.close()
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    from mcp_conform.vehicle.recordfile import read_records
    rows = read_records(str(record))
    got = [(r["request"], r["result"], r["answer"]) for r in rows]
    assert got == [
        ("arm", "accepted", "MAV_RESULT_ACCEPTED"), ("mode", "accepted", "MAV_RESULT_ACCEPTED"),
        ("message_interval", "accepted", "MAV_RESULT_ACCEPTED"),
        ("command", "denied", "MAV_RESULT_UNSUPPORTED"), ("data_stream", "accepted", "4 Hz"),
        ("param_set", "denied", "none"), ("param_read", "accepted", "PARAM_VALUE RTL_ALT"),
        ("position_target", "accepted", "flying to the velocity"),
        ("mission_download", "accepted", "MISSION_COUNT count=0"),
        ("ftp", "denied", "FILE_TRANSFER_PROTOCOL NAK FileNotFound"),
    ], got
    assert all(r["reason"] for r in rows if r["result"] == "denied")
    assert all(r["srcsys"] == 42 for r in rows)

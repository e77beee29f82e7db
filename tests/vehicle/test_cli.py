"""``python -m vehicle``: help, one-line usage errors, and serving until interrupted."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from vehicle.cli import main

ROOT = Path(__file__).resolve().parents[2]


def test_help_exits_zero(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    assert "--fix-delay" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["--port", "x"], ["--fix-delay", "-1"], ["--home", "1"],
                                  ["--port", "70000"], ["--bogus"]])
def test_bad_arguments_give_one_line_and_status_2(argv: list[str],
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err


def test_serves_until_interrupted() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "vehicle", "--port", "0", "--fix-delay", "0.2"],
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
        assert proc.returncode == 0
        assert "connect" in out and "command" in out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()

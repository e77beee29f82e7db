"""The grammar's exit code for a signal (docs/grammar.md, issue 40 item 1): 128 + its number,
130 for SIGINT and 143 for SIGTERM, from every tool that runs until it is stopped. Each test
starts the real command, waits for the line that says it is running (printed once its own
handlers are in place), sends the signal to the process and checks the exit code and that
no traceback was printed. ``mcp-node``, ``mcp-impair`` and the vehicle exited 0 before;
``mcp-conform --parallel``'s code was unchecked: it was 2."""

from __future__ import annotations

import json
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
ENV = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1")
READY_WITHIN = 60.0  # s: a bound for a loaded host, not a timing
SIGNALS = [pytest.param(signal.SIGINT, id="SIGINT"), pytest.param(signal.SIGTERM, id="SIGTERM")]


def _run_until(argv: list[str], ready: Callable[[str], bool], stream: str, sig: int) -> tuple[int, str, str]:
    """Start ``argv``, wait for a line of ``stream`` (stdout or stderr) that ``ready`` accepts,
    send ``sig``; the exit code, stdout and stderr."""
    proc = subprocess.Popen(argv, cwd=ROOT, env=ENV, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    watched = proc.stdout if stream == "stdout" else proc.stderr
    other = proc.stderr if stream == "stdout" else proc.stdout
    assert watched is not None and other is not None
    seen: list[str] = []
    rest: list[str] = []
    drain = threading.Thread(target=lambda: rest.append(other.read()), daemon=True)  # never a full pipe
    drain.start()
    try:
        deadline = time.monotonic() + READY_WITHIN
        while time.monotonic() < deadline:
            line = watched.readline()
            if not line:
                break
            seen.append(line)
            if ready(line):
                break
        assert seen and ready(seen[-1]), f"{argv[0]}: not running after {READY_WITHIN:g} s: {''.join(seen)[-2000:]}"
        proc.send_signal(sig)
        tail = watched.read()
        proc.wait(timeout=60)
        drain.join(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = "".join(seen) + tail
    out, err = (text, "".join(rest)) if stream == "stdout" else ("".join(rest), text)
    return proc.returncode, out, err


def _check(code: int, out: str, err: str, sig: int) -> None:
    assert code == 128 + sig, f"exit {code}, want {128 + sig}\nstdout: {out[-1500:]}\nstderr: {err[-1500:]}"
    assert "Traceback" not in err, err


@pytest.mark.parametrize("sig", SIGNALS)
def test_mcp_node(sig: int) -> None:
    code, out, err = _run_until(
        ["mcp-node", "drone", "--id", "1", "--listen", "127.0.0.1:0", "--target", "127.0.0.1:9",
         "--gps-fix-delay", "1000"], lambda ln: "waiting for a 3D GPS fix" in ln, "stderr", sig)
    _check(code, out, err, sig)
    assert '"outcome": "stopped"' in out, out  # the record, as on any exit


@pytest.mark.parametrize("sig", SIGNALS)
def test_mcp_node_nsqd_backend(sig: int) -> None:
    code, out, err = _run_until(["mcp-node", "--protocol", "nsqd", "backend", "--listen", "127.0.0.1:0"],
                                lambda ln: ln.startswith("listening on"), "stdout", sig)
    _check(code, out, err, sig)


@pytest.mark.parametrize("sig", SIGNALS)
def test_mcp_node_nsqd_client_ctrl_c(sig: int) -> None:
    """The client listens --duration seconds; Ctrl-C (or SIGTERM) before is an interrupt, not
    a traceback, even when it was started with SIGINT ignored, as a script's background job is
    (a CI run started so: the client relied on Python's KeyboardInterrupt, which Python does not
    install then, and ran its whole 60 s; the likely cause of the runs described next).

    It is signalled once it has printed a frame the backend sent it: then it is listening, past
    its imports, on our connection. Signalled 0.3 s after a connection was accepted, it ran its
    whole 60 s and exited 0 in 3 of 4 full quick runs here (never alone; its SIGINT handling was
    in place, /proc's SigCgt): the signal was lost, and the likely way is that the connection
    accepted was not its own (another test's process reaching a port it had freed, which this
    one then bound) and the SIGINT came during its start. Not proven; this test no longer
    depends on it."""
    from mcp_conform.spec import NSQD
    from mcp_conform.spec.nsqd_codec import encode

    with socket.socket() as backend:
        backend.bind(("127.0.0.1", 0))
        backend.listen(4)
        proc = subprocess.Popen(["mcp-node", "--protocol", "nsqd", "client", "--target",
                                 f"127.0.0.1:{backend.getsockname()[1]}", "--duration", "60"],
                                cwd=ROOT, env=ENV, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
        conns: list[socket.socket] = []
        try:
            assert proc.stdout is not None
            end = time.monotonic() + READY_WITHIN
            line = ""
            while not line and time.monotonic() < end:
                ready, _, _ = select.select([backend, proc.stdout], [], [], 0.5)
                if backend in ready:  # each connection gets a frame; only the client's prints
                    conn, _ = backend.accept()
                    conns.append(conn)
                    conn.sendall(encode(NSQD, "TAKEOFF"))
                if proc.stdout in ready:
                    line = proc.stdout.readline()
            assert '"TAKEOFF"' in line, (line, proc.poll())
            proc.send_signal(sig)
            out, err = proc.communicate(timeout=60)
        finally:
            for c in conns:
                c.close()
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    _check(proc.returncode, out, err, sig)


@pytest.mark.parametrize("sig", SIGNALS)
def test_mcp_impair(sig: int) -> None:
    code, out, err = _run_until(["mcp-impair", "--listen", "127.0.0.1:0", "--target", "127.0.0.1:9",
                                 "--duration", "120"], lambda ln: ln.startswith("mcp-impair: "), "stdout", sig)
    _check(code, out, err, sig)
    assert "datagrams" in out or " up" in out, out  # what it did, printed all the same


def test_mcp_impair_duration_is_its_normal_end() -> None:
    run = subprocess.run(["mcp-impair", "--listen", "127.0.0.1:0", "--target", "127.0.0.1:9", "--duration", "0.5",
                          "-q"], cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr


@pytest.mark.parametrize("sig", SIGNALS)
@pytest.mark.parametrize("command", [[sys.executable, "-m", "mcp_conform.vehicle"], ["mcp-vehicle"]],
                         ids=["mcp-vehicle", "mcp-vehicle"])
def test_the_vehicle(command: list[str], sig: int) -> None:
    code, out, err = _run_until([*command, "--listen", "127.0.0.1:0", "--duration", "120", "-q"],
                                lambda ln: "listening on" in ln, "stdout", sig)
    _check(code, out, err, sig)


def test_the_vehicle_duration_is_its_normal_end() -> None:
    run = subprocess.run([sys.executable, "-m", "mcp_conform.vehicle", "--listen", "127.0.0.1:0", "--duration", "0.5", "-q"],
                         cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr


@pytest.mark.parametrize("sig", SIGNALS)
def test_mcp_conform_parallel(sig: int, tmp_path: Path) -> None:
    """Two instances of the embedded reference drone; the signal once a case has ended. The
    report is written and says so, and the code is 128 + the signal's, as a run of one."""
    js = tmp_path / "run.json"
    code, out, err = _run_until(
        ["mcp-conform", "--parallel", "2", "--rto", "0.2", "--ack-window", "0.25", "--json", str(js)],
        lambda ln: ln.lstrip().startswith(("PASSED", "FAILED", "SKIPPED", "WARNED", "ERROR")), "stdout", sig)
    assert json.loads(js.read_text(encoding="utf-8"))["error"].startswith("interrupted"), js.read_text()
    _check(code, out, err, sig)

"""``mcp-node``: arguments, one-line errors (exit 2), clean exits, and the command line the
conformance runner spawns (``--listen/--target/--mavlink/--rto``)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from mcp_conform.reference_impl.cli import _addresses, build_parser, main
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import MANAGER_ID, Action
from mcp_conform.vehicle import SimVehicle, make_probe
from tests.capturing import free_port
from tests.reference_impl.test_drone import FakePeer

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).parent / "data"
PORTS = SPEC.protocol["ports"]
BROADCAST = SPEC.protocol["broadcast_address"]


def spawn(*args: str, **kw: Any) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "mcp_conform.reference_impl", *args], cwd=ROOT, text=True,
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kw)


def finish(proc: subprocess.Popen[str], timeout: float = 20.0) -> tuple[int, str, str]:
    try:
        out, err = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return proc.returncode, out, err


def test_help() -> None:
    code, out, err = finish(spawn("--help"))
    assert code == 0 and "drone" in out and "manager" in out
    code, out, _ = finish(spawn("drone", "--help"))
    for opt in ("--listen", "--target", "--mavlink", "--rto", "--retries", "--gps-fix-delay",
                "--takeoff-alt", "--reply-to-source", "--json", "BROADCAST", "LOCAL_PORT"):
        assert opt in out
    code, out, _ = finish(spawn("manager", "--help"))
    assert code == 0 and "--challenge" in out and "--waypoints" in out and "--obstacles" in out


@pytest.mark.parametrize("argv", [
    [],
    ["fly"],
    ["drone"],
    ["drone", "--id", "x"],
    ["drone", "--id", "0"],
    ["drone", "--id", "1", "--rto", "0"],
    ["drone", "--id", "1", "--rto", "nan"],
    ["drone", "--id", "1", "--retries", "-1"],
    ["drone", "--id", "1", "--listen", "127.0.0.1:99999"],
    ["drone", "--id", "1", "--target", "127.0.0.1:0"],
    ["drone", "--id", "1", "127.255.255.255", "port"],
    ["drone", "--id", "1", "--takeoff-alt", "-3"],
    ["drone", "--id", "1", "-v", "-q"],
    ["manager", "--drones", "1", "--waypoints", "x"],
    ["manager", "--challenge", "4", "--drones", "1", "--waypoints", "x"],
    ["manager", "--challenge", "1", "--drones", "a,b", "--waypoints", "x"],
    ["manager", "--challenge", "1", "--drones", "1,1", "--waypoints", str(DATA / "challenge.waypoints")],
    ["manager", "--challenge", "1", "--drones", "1", "--waypoints", "/nonexistent.waypoints"],
    ["manager", "--challenge", "3", "--drones", "1", "--waypoints", str(DATA / "challenge.waypoints")],
    ["manager", "--challenge", "1", "--drones", "1", "--waypoints", str(Path(__file__))],
])
def test_bad_arguments_exit_2_with_one_line(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("mcp-node: error: "), err
    assert "Traceback" not in err


def addresses(*argv: str) -> tuple[str, int, str, int]:
    args = build_parser().parse_args(list(argv))
    own, other = ("drone", "manager") if args.role == "drone" else ("manager", "drone")
    return _addresses(args, PORTS[own], PORTS[other])


def test_address_defaults_follow_the_description() -> None:
    wp = str(DATA / "challenge.waypoints")
    assert addresses("drone", "--id", "1") == ("", PORTS["drone"], BROADCAST, PORTS["manager"])
    assert addresses("manager", "--challenge", "2", "--drones", "1", "--waypoints", wp) == (
        "", PORTS["manager"], BROADCAST, PORTS["drone"])
    # ./mission_manager.py 2 127.255.255.255 7889 7890 and the drone's mirror image
    assert addresses("manager", "--challenge", "2", "--drones", "1", "--waypoints", wp,
                     "127.255.255.255", "17889", "17890") == ("", 17889, "127.255.255.255", 17890)
    assert addresses("drone", "--id", "1", "127.0.0.255", "17890", "17889") == ("", 17890, "127.0.0.255", 17889)
    assert addresses("drone", "--id", "1", "127.0.0.255", "17890", "17889", "--listen", "127.0.0.1:5",
                     "--target", "127.0.0.2:6") == ("127.0.0.1", 5, "127.0.0.2", 6)
    assert addresses("drone", "--id", "1", "--listen", "7") == ("", 7, BROADCAST, PORTS["manager"])


def test_unreachable_autopilot_exits_2_in_one_line() -> None:
    import socket

    port = free_port(socket.SOCK_STREAM)  # nothing listens there
    code, out, err = finish(spawn("drone", "--id", "1", "--listen", "127.0.0.1:0", "--target", "127.0.0.1:9",
                                  "--mavlink", f"tcp:127.0.0.1:{port}"))
    assert code == 2
    assert [ln for ln in err.splitlines() if ln.startswith("mcp-node: error: ")] != []
    assert "Traceback" not in err


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_while_waiting_for_the_fix_exits_128_plus_its_number(sig: signal.Signals, tmp_path: Path) -> None:
    rec = tmp_path / "rec.json"
    proc = spawn("drone", "--id", "1", "--listen", "127.0.0.1:0", "--target", "127.0.0.1:9",
                 "--gps-fix-delay", "1000", "--json", str(rec))
    try:
        deadline = time.monotonic() + 20
        assert proc.stderr is not None
        line = ""
        while time.monotonic() < deadline and "waiting for a 3D GPS fix" not in line:
            line = proc.stderr.readline()
            if not line:
                break
        assert "waiting for a 3D GPS fix" in line
        proc.send_signal(sig)
        code, out, err = finish(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert code == 128 + sig, err  # docs/grammar.md: 130 for SIGINT, 143 for SIGTERM
    assert "Traceback" not in err
    assert json.loads(out.splitlines()[-1])["outcome"] == "stopped"
    assert json.loads(rec.read_text())["received"] == {}


def test_sigterm_while_the_manager_waits_exits_143(tmp_path: Path) -> None:
    proc = spawn("manager", "--challenge", "1", "--drones", "1,2", "--waypoints", str(DATA / "challenge.waypoints"),
                 "--listen", "127.0.0.1:0", "--target", "127.0.0.1:9", "--json", str(tmp_path / "m.json"))
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        assert "manager listening" in line, line
        proc.send_signal(signal.SIGTERM)
        code, out, err = finish(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert code == 128 + signal.SIGTERM and "Traceback" not in err, err
    rec = json.loads((tmp_path / "m.json").read_text())
    assert rec["outcome"] == "stopped" and rec["sent"] == []


def test_the_runner_spawn_command(tmp_path: Path) -> None:
    """``drone --id {id} --listen {target} --target {listen} --mavlink {mavlink} --rto 0.2``, with the
    fix withheld for a while and the first copies of Mission_Ready left unACKed."""
    runner = FakePeer()
    v = SimVehicle(fix_withheld=True)
    v.start()

    target = free_port()
    proc = spawn("drone", "--id", "4", "--listen", f"127.0.0.1:{target}", "--target", f"127.0.0.1:{runner.port}",
                 "--mavlink", v.url, "--rto", "0.2")
    try:
        runner.to = ("127.0.0.1", target)
        assert v.wait_for(lambda: v.connected, 20)
        assert runner.expect(Action.MISSION_READY, 1.0) is None  # no fix: no Mission_Ready (MCP-BLK-5)
        v.give_fix()
        copies = [runner.expect(Action.MISSION_READY, 10) for _ in range(4)]  # 3 left unACKed
        assert all(c is not None for c in copies)
        assert {c[0].seq for c in copies if c} == {copies[0][0].seq} and copies[0][0].dst == MANAGER_ID
        runner.ack(copies[-1][0], copies[-1][1])
        runner.src = MANAGER_ID
        runner.command(Action.MAV_PASSTHROUGH, make_probe("spawned"), dst=4)
        assert v.wait_for(lambda: v.probe_count("spawned") == 1, 10)
        assert not v.events("arm")
        runner.command(Action.START_MISSION, dst=4)
        assert v.wait_for(lambda: v.armed, 10)
        runner.command(Action.END_MISSION, dst=4)
        assert v.wait_for(lambda: v.rtl_commanded, 10)
        code, out, err = finish(proc)
        assert code == 0, err
        rec = json.loads(out.splitlines()[-1])
        assert rec["received"] == {"Mav_Passthrough": 1, "Start_Mission": 1, "End_Mission": 1}
        assert "Traceback" not in err
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
            proc.communicate()
        v.close()
        runner.close()


def _until(proc: subprocess.Popen[str], text: str, timeout: float = 20.0) -> str:
    """Read the node's stderr until a line containing ``text``."""
    assert proc.stderr is not None
    deadline = time.monotonic() + timeout
    line = ""
    while time.monotonic() < deadline and text not in line:
        line = proc.stderr.readline()
        if not line:
            break
    assert text in line, line
    return line


@pytest.mark.slow
def test_a_port_is_shared_only_when_asked_and_sigterm_exits_promptly(tmp_path: Path) -> None:
    """Issue 8: two drones bound one address without a word (a stale node silently taking
    part of the traffic), and a drone took 1.7 s to exit on SIGTERM."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("", 0))
        port = s.getsockname()[1]
    common = ["--listen", f"127.0.0.1:{port}", "--target", "127.0.0.1:9", "--rto", "0.2"]
    first = spawn("drone", "--id", "1", *common)
    procs = [first]
    try:
        _until(first, "listening on")
        code, _, err = finish(spawn("drone", "--id", "2", *common))
        assert code == 2 and "Traceback" not in err, err
        errors = [ln for ln in err.splitlines() if ln.startswith("mcp-node: error: ")]
        assert len(errors) == 1 and "in use" in errors[0], err
        first.send_signal(signal.SIGTERM)
        assert finish(first)[0] == 128 + signal.SIGTERM
        a = spawn("drone", "--id", "1", *common, "--reuse-port")
        b = spawn("drone", "--id", "2", *common, "--reuse-port")
        procs += [a, b]
        for p in (a, b):
            _until(p, "sending Mission_Ready")  # both bound, both past their startup
        t0 = time.monotonic()
        for p in (a, b):
            p.send_signal(signal.SIGTERM)
        results = [finish(p) for p in (a, b)]
        took = time.monotonic() - t0
        print(f"two drones exited {took * 1000:.0f} ms after SIGTERM")
        assert [r[0] for r in results] == [128 + signal.SIGTERM] * 2, results
        assert took < 1.0, f"{took:.2f} s to exit on SIGTERM (was 1.7 s)"
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate()


def test_the_waypoint_files_the_docs_name_are_shipped() -> None:
    """Every ``*.waypoints`` file the README or a page of docs/ names exists and loads (QGC WPL
    110 through pymavlink, ``spec.mission``)."""
    import re

    from mcp_conform.spec.mission import load_waypoints

    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    names = {n for page in pages for n in re.findall(r"[\w./-]+\.waypoints", page.read_text())}
    assert names, "the README and docs/ name no waypoint file"
    for name in names:
        path = ROOT / name
        assert path.is_file(), f"the docs name {name}, not shipped"
        assert load_waypoints(path), name


def test_a_signal_stops_a_role_blocked_in_a_future_without_touching_its_locks() -> None:
    """CI run of stop 15: SIGTERM raised KeyboardInterrupt inside ``Future.result()`` of a
    drone waiting for Mission_Ready's ACK and the node died with "cannot release
    un-acquired lock" (exit 1). The handler now only flags; the role thread is stopped by
    the main thread. Here a role blocks in ``Future.result()`` while signals keep arriving:
    every run ends through ``stop()`` with no exception, and the role's thread is released."""
    import concurrent.futures
    import threading

    from mcp_conform.reference_impl.cli import _Interrupt, _run_role

    class BlockedRole:
        def __init__(self) -> None:
            self.fut: concurrent.futures.Future[int] = concurrent.futures.Future()
            self.stopped = 0
            self.returned = threading.Event()  # run() left Future.result(), whatever it raised

        def run(self) -> int:
            try:
                return self.fut.result()
            finally:
                self.returned.set()

        def stop(self) -> None:
            self.stopped += 1
            self.fut.set_exception(RuntimeError("stopped"))  # what Mcp.close does to a blocked send

    for _ in range(20):
        role, interrupt = BlockedRole(), _Interrupt()
        previous = signal.signal(signal.SIGUSR1, interrupt)
        try:
            killer = threading.Timer(0.01, os.kill, (os.getpid(), signal.SIGUSR1))
            killer.start()
            assert _run_role(role, interrupt) is None  # type: ignore[arg-type]
            killer.join()
        finally:
            signal.signal(signal.SIGUSR1, previous)
        assert interrupt.signum == signal.SIGUSR1 and role.stopped == 1
        assert role.returned.is_set()  # the role thread was released by stop(), not left blocked
    done = BlockedRole()
    done.fut.set_result(3)
    assert _run_role(done, _Interrupt()) == 3  # type: ignore[arg-type]
    failing = BlockedRole()
    failing.fut.set_exception(ValueError("a bug in the role"))
    with pytest.raises(ValueError, match="a bug in the role"):
        _run_role(failing, _Interrupt())  # type: ignore[arg-type]

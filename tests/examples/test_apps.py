"""The example drone applications (examples/apps/) under ``mcp-conform --mavlink``, as a user
runs them.

Each application is an independent MCP node written with a real MAVLink client library
(DroneKit-Python, MAVSDK 4.x) flying the runner's simulated vehicle; a run must exit 0 with
every verdict of its JSON report a pass, a skip, an INFO or at worst a SHOULD warning — and the
cases the applications are for (MCP-BLK-4/5/7, MCP-PAY-8 and duplicate discard judged through
the forwarded passthrough frames) passed, never skipped. A library that is not installed skips
its application's tests with the reason. Also: a bad argument is one line and exit 2, and
SIGTERM ends an application that is still waiting for its vehicle with exit 0.
"""

from __future__ import annotations

import importlib.util
import shlex
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conformance.runner_helpers import RunResult, run_conform

ROOT = Path(__file__).resolve().parents[2]
APPS = ROOT / "examples" / "apps"
#: The library each application is written with (its import name).
LIBRARY = {"dronekit_drone": "dronekit", "mavsdk_drone": "mavsdk"}
#: Rules these applications exist to be judged on: passed, never skipped nor warned.
JUDGED_ON_THE_LINK = ("MCP-BLK-4", "MCP-BLK-5", "MCP-BLK-7", "MCP-PAY-8", "MCP-DUP-1", "MCP-DUP-2")


def _need(app: str) -> None:
    lib = LIBRARY[app]
    if importlib.util.find_spec(lib) is None:
        pytest.skip(f"{lib} is not installed (the {app} example needs it)")


def app_command(app: str, rto: float) -> str:
    """The application's command line with the runner's ``--spawn`` placeholders."""
    return (f"{shlex.quote(sys.executable)} {shlex.quote(str(APPS / f'{app}.py'))} --id {{id}} "
            f"--listen {{target_port}} --manager {{listen_host}}:{{listen_port}} "
            f"--autopilot {{mavlink}} --rto {rto:g}")


def conform(app: str, transport: str, rto: float, *extra: str, timeout: float = 300.0) -> RunResult:
    mavlink = ["--mavlink"] if transport == "tcp" else ["--mavlink", transport]
    return run_conform(*mavlink, "--spawn", app_command(app, rto), "--rto", f"{rto:g}", *extra,
                       "--timeout", str(int(timeout - 20)), timeout=timeout)


def check(res: RunResult) -> None:
    """Exit 0; the scheduled batch kept (an independent node's interleaving is no reason to run
    the cases again one by one); no case failed or errored; the link's rules passed; the trace
    monitor proved no MUST violation of the node."""
    assert res.rc == 0, res.explain()
    assert (res.report.get("schedule") or {}).get("batch_outcome") == "kept", \
        (res.report.get("schedule"), res.explain())
    cases = res.report["cases"]
    assert cases, res.explain()
    bad = [c for c in cases if c["outcome"] not in ("passed", "skipped", "info", "warned")]
    assert not bad, res.explain()
    for rule in JUDGED_ON_THE_LINK:
        outcomes = {c["id"]: c["outcome"] for c in cases if rule in c["rules"]}
        assert outcomes, f"no case judges {rule}"
        seen = set(outcomes.values())
        assert "passed" in seen and not {"skipped", "warned"} & seen, \
            f"{rule}: {outcomes}\n{res.explain()}"
    must = [v for v in res.report["monitor"]["violations"] if v["level"] == "MUST"]
    assert not must, must


@pytest.mark.slow
@pytest.mark.parametrize("transport", ["tcp", "udp"])
@pytest.mark.parametrize("app", ["dronekit_drone", "mavsdk_drone"])
def test_app_conforms_at_short_timeouts(app: str, transport: str) -> None:
    """``--rto 0.3 --ack-window 0.3``, the vehicle on TCP (the node connects) or UDP (the node
    listens, the vehicle sends, as SITL's --out)."""
    _need(app)
    check(conform(app, transport, 0.3, "--ack-window", "0.3"))


@pytest.mark.slow
def test_dronekit_app_conforms_at_the_descriptions_timeout() -> None:
    """The description's 5 s timeout and the default ACK window."""
    _need("dronekit_drone")
    check(conform("dronekit_drone", "tcp", 5.0, timeout=400.0))


@pytest.mark.parametrize("app", ["dronekit_drone", "mavsdk_drone"])
@pytest.mark.parametrize("argv", [
    ["--id", "0", "--manager", "127.0.0.1:7889", "--autopilot", "tcp:127.0.0.1:5760"],
    ["--id", "1", "--manager", "7889", "--autopilot", "tcp:127.0.0.1:5760"],
    ["--id", "1", "--manager", "127.0.0.1:7889", "--autopilot", "tcp:nowhere"],
    ["--id", "1", "--manager", "127.0.0.1:7889", "--autopilot", "tcp:127.0.0.1:1", "--rto", "-1"],
])
def test_bad_arguments_are_one_line(app: str, argv: list[str]) -> None:
    _need(app)
    proc = subprocess.run([sys.executable, str(APPS / f"{app}.py"), "--listen", "7890", *argv],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{app}.py: error: "), proc.stderr


@pytest.mark.slow
@pytest.mark.parametrize("app", ["dronekit_drone", "mavsdk_drone"])
def test_sigterm_while_waiting_for_the_vehicle(app: str) -> None:
    """A vehicle that reports no GPS fix: the application connects, sends no Mission_Ready
    (MCP-BLK-5) and SIGTERM ends it with exit 0 and no traceback."""
    _need(app)
    from mcp_conform.vehicle import SimVehicle
    from tests.capturing import free_port

    with SimVehicle() as v, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as manager:
        v.withhold_fix()
        manager.bind(("127.0.0.1", 0))
        proc = subprocess.Popen(
            [sys.executable, str(APPS / f"{app}.py"), "--id", "3", "--listen", str(free_port()),
             "--manager", f"127.0.0.1:{manager.getsockname()[1]}", "--autopilot", v.url,
             "--rto", "0.3"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert v.wait_for(lambda: v.connected, 30.0), "the application never connected"
            manager.settimeout(2.0)  # well into its readiness wait
            with pytest.raises(TimeoutError):
                manager.recvfrom(65535)
            assert proc.poll() is None, proc.communicate()
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=10)  # the runner gives 2 s before SIGKILL
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    assert proc.returncode == 0, err
    assert "Traceback" not in err, err

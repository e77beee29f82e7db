"""Issue 35, deliverable 5: a node that never announces is explained.

Observed: a dronekit application waiting on ``is_armable`` under ``mcp-conform --mavlink --rto
0.3 --startup-timeout 40 --spawn ...`` ended with "error: the node sent no Mission_Ready within
20.0 s" (after "up to 40 s" was printed), nothing else: not that it had connected to the
vehicle, nor what it had asked. The wait was the session's own (``max(SPAWN_STARTUP_S, 4 x
--rto + 5)``), not the --startup-timeout the runner printed.

Each node here is a one-file script the test writes, run by the runner (``--spawn``): it
asks the vehicle and waits, never reaches it, or complains and exits. The error says what
each did, from the vehicle's records and what reached the runner; exit 2, no traceback; and
the run waits the --startup-timeout (elapsed times are bounded generously: a loaded host is
slow, never early).
"""

from __future__ import annotations

import sys
import textwrap
import time
from pathlib import Path

import pytest

from tests.conformance.runner_helpers import FAST, ROOT, free_port, run_conform

pytestmark = pytest.mark.slow

STARTUP_S = 4.0  # time for a node's interpreter to start on a loaded host
#: How long past --startup-timeout a run may take on a loaded host (startup, teardown).
SLACK_S = 12.0

#: Connects to its autopilot, asks what dronekit and MAVSDK ask at connection (streams, the
#: autopilot's version three times, an arm) and waits for an answer it never acts on.
ASKER = """
    import sys, time
    from pymavlink import mavutil
    m = mavutil.mavlink_connection(sys.argv[1], source_system=255)
    if sys.argv[1].startswith("udp"):  # a UDP vehicle hears of its peer from a first frame
        m.mav.heartbeat_send(6, 8, 0, 0, 0)
    m.wait_heartbeat(timeout=10)
    m.mav.request_data_stream_send(1, 1, 0, 4, 1)
    m.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)  # MAV_CMD_COMPONENT_ARM_DISARM
    for _ in range(3):
        m.mav.command_long_send(1, 1, 512, 0, 148, 0, 0, 0, 0, 0, 0)  # REQUEST_MESSAGE(148)
        time.sleep(0.1)
    print("waiting for the autopilot's version", flush=True)
    end = time.monotonic() + 30
    while time.monotonic() < end:
        m.recv_match(blocking=True, timeout=0.5)
"""

#: Never opens its autopilot link; sends the runner (HOST PORT [COUNT]) one datagram (or COUNT,
#: 0.2 s apart) that is not Mission_Ready (so the runner's wait for the first datagram is over
#: and its wait for Mission_Ready is what ends the run), then sleeps.
SPEAKS_ONLY = """
    import socket, sys, time
    from mcp_conform.spec.codec import Action, build_datagram
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for i in range(int(sys.argv[3]) if len(sys.argv) > 3 else len(sys.argv) > 1):
        if i:
            time.sleep(0.2)
        try:  # (attach mode: the runner may not listen yet)
            s.sendto(build_datagram(0, 1, 1 + i, int(Action.WP_OFF)), (sys.argv[1], int(sys.argv[2])))
        except OSError:
            pass
    time.sleep(30)
"""

COMPLAINS = """
    import sys
    print("starting drone 1")
    print("config.yaml: no such file", file=sys.stderr)
    sys.exit(3)
"""


def script(tmp_path: Path, name: str, text: str) -> str:
    path = tmp_path / f"{name}.py"
    path.write_text(textwrap.dedent(text))
    return f"{sys.executable} {path}"


def run(*args: str) -> tuple[dict, str, float]:
    t0 = time.monotonic()
    res = run_conform(*FAST, "--startup-timeout", f"{STARTUP_S:g}", *args, timeout=120)
    took = time.monotonic() - t0
    assert res.rc == 2, res.explain()
    assert "Traceback" not in res.output, res.output
    assert res.report["cases"] == [], res.explain()
    return res.report, res.output, took


def detail(doc: dict) -> str:
    return "\n".join(doc.get("error_detail") or [])


@pytest.mark.parametrize("transport", ["tcp", "udp"])
def test_a_node_that_asks_the_vehicle_and_never_announces(tmp_path, transport):
    doc, out, took = run("--mavlink", transport, "--spawn", script(tmp_path, "asker", ASKER) + " {mavlink}")
    text = detail(doc)
    assert f"connected to the simulated vehicle over {transport}" in text, text
    assert "REQUEST_DATA_STREAM" in text, text
    assert "COMMAND_LONG MAV_CMD_REQUEST_MESSAGE(148 AUTOPILOT_VERSION) ×3" in text, text
    assert "it asked: arm request (COMMAND_LONG" in text, text  # and the answer, as the vehicle gave it
    assert "to the runner: no datagram" in text, text
    assert "hint: the node connected to the vehicle but never sent a datagram to the runner" in text, text
    # the fix came after the connection and FAST's hold (2 x --ack-window, at least 0.5 s)
    assert "the vehicle reported a 3D GPS fix from" in text, text
    assert "waiting for the autopilot's version" in doc["node"]["stdout"], doc["node"]
    assert f"within {STARTUP_S:g} s" in doc["error"], doc["error"]
    assert len(doc["error_detail"]) <= 12, text
    # the terminal says it too, under the one-line error
    assert doc["error"] in out and "hint: the node connected to the vehicle" in out, out
    assert STARTUP_S - 0.1 <= took < STARTUP_S + SLACK_S, took


def test_a_node_that_never_reaches_the_vehicle(tmp_path):
    doc, out, took = run("--mavlink", "--spawn", script(tmp_path, "loner", SPEAKS_ONLY))
    text = detail(doc)
    assert "autopilot: the node never connected to the simulated vehicle at tcp:127.0.0.1:" in text, text
    assert "the vehicle had no GPS fix" in text, text
    assert "to the runner: no datagram" in text, text
    assert "hint: the node never reached the vehicle: does it take the {mavlink} placeholder" in text, text
    assert STARTUP_S - 0.1 <= took < STARTUP_S + SLACK_S, took


def test_the_wait_for_mission_ready_is_the_startup_timeout(tmp_path):
    """A node that speaks (not Mission_Ready) ends the wait for its first datagram; the wait
    for its Mission_Ready is still --startup-timeout (was: 20 s whatever it said)."""
    node = script(tmp_path, "speaker", SPEAKS_ONLY) + " {listen_host} {listen_port}"
    doc, out, took = run("--mavlink", "--spawn", node)
    assert doc["error"] == f"the node sent no Mission_Ready within the --startup-timeout of {STARTUP_S:g} s", doc
    text = detail(doc)
    assert "to the runner: 1 datagram(s), none a Mission_Ready: WP_OFF" in text, text
    assert "never connected to the simulated vehicle" in text, text
    assert STARTUP_S - 0.1 <= took < STARTUP_S + SLACK_S, took


def test_a_node_that_complains_and_exits(tmp_path):
    doc, out, took = run("--mavlink", "--spawn", script(tmp_path, "complainer", COMPLAINS))
    assert "the node exited with code 3" in doc["error"], doc["error"]
    assert doc["node"]["stderr"] == ["config.yaml: no such file"], doc["node"]
    assert doc["node"]["stdout"] == ["starting drone 1"], doc["node"]
    text = detail(doc)
    assert "never connected to the simulated vehicle" in text and "hint: the node exited" in text, text
    assert "config.yaml: no such file" in out, out
    assert took < STARTUP_S + SLACK_S, took


def test_without_mavlink_there_are_no_vehicle_records(tmp_path):
    doc, out, took = run("--spawn", script(tmp_path, "quiet", SPEAKS_ONLY))
    text = detail(doc)
    assert "autopilot: none given (no --mavlink), so there are no vehicle records" in text, text
    assert "hint: the node sent the runner nothing: if it waits on an autopilot, run with --mavlink" in text, text
    assert STARTUP_S - 0.1 <= took < STARTUP_S + SLACK_S, took


def test_attach_mode_says_what_the_runner_knows(tmp_path):
    """Attach mode: no vehicle of the runner's, and an attached target's errors stay one line:
    what reached the runner is said in it."""
    import subprocess

    port, listen = free_port(), free_port()
    speaker = script(tmp_path, "speaker", SPEAKS_ONLY).split()  # speaks once the runner listens
    node = subprocess.Popen([*speaker, "127.0.0.1", str(listen), "40"], cwd=ROOT,
                            env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        doc, out, took = run("--target", f"127.0.0.1:{port}", "--listen", f"127.0.0.1:{listen}")
    finally:
        node.kill()
        node.wait(timeout=5)
    assert doc["error"].startswith("target never answered: no Mission_Ready within "), doc["error"]
    assert "(attach mode, so no vehicle records; to the runner: " in doc["error"], doc
    assert ("datagram(s), none a Mission_Ready: WP_OFF ×" in doc["error"] and doc["error"].endswith(
        "; hint: the node speaks to the runner but never announced Mission_Ready)")), doc
    assert "error_detail" not in doc
    assert [ln for ln in out.splitlines() if ln.startswith("error:")] == [f"error: {doc['error']}"], out


def test_a_silent_attached_target_is_explained(tmp_path):
    listen = free_port()
    doc, out, took = run("--target", f"127.0.0.1:{free_port()}", "--listen", f"127.0.0.1:{listen}")
    assert doc["error"].endswith(f"(attach mode, so no vehicle records; to the runner: no datagram at "
                                 f"127.0.0.1:{listen}; hint: is the node running, and does it send there?)"), doc

"""The runner's drone cases with its vehicle in the simulator (``sim.runner.run_cases(...,
mavlink=True)``, issue 38): ``vehicle.SimVehicle`` on the session's virtual clock (its seam,
``vehicle.seam``; sim.vehicle) over TCP (``--mavlink``'s default) or UDP, and the drone model's
MAVLink client (sim.autopilot) talking to it, so the cases observed on the autopilot link are
judged instead of skipped.

Correct: the reference drone with the vehicle gets no failed or warned verdict (cases or
monitor) at the short timings and at the description's 5 s ones, serial and scheduled, through
the runner's impaired link too; each vehicle case is judged. The same seed gives the same run.
"""

from __future__ import annotations

import pytest

from mcp_conform.harness.clock import VirtualClock
from mcp_conform.sim.autopilot import AutopilotClient
from mcp_conform.sim.faults import FAULTS
from mcp_conform.sim.mutants import mutant_factory
from mcp_conform.sim.runner import run_cases
from mcp_conform.sim.vehicle import SimVehicleNet, start_vehicle

SHORT = {"rto": 0.2, "ack_window": 0.25}
DESCRIPTION = {"rto": 5.0, "ack_window": 2.0}
IMPAIR = ("--impair", "loss=0.1,dup=0.05,reorder=0.1,seed=5")
#: the cases observed on the vehicle's link (skipped in a run without one)
VEHICLE_CASES = {
    "BLK/test_no_mission_ready_without_a_gps_fix": "passed",
    "BLK/test_no_arming_before_start_mission": "passed",
    "BLK/test_end_mission_then_rtl": "passed",
    "DUP/test_same_seq_twice_is_delivered_once": "passed",
    "DUP/test_new_seq_with_the_same_bytes_is_delivered": "passed",
    "DUP/test_same_seq_from_another_src_is_not_a_duplicate": "passed",
    "DUP/test_late_copy_of_an_older_message": "info",  # MCP-DUP-4: not specified, reported
    "PAY/test_passthrough_frame_reaches_the_autopilot_once": "passed",
    "SEQ/test_zero_after_65535_is_new": "passed",
}


def _bad(run):
    return {c["id"]: c["outcome"] for c in run.report["cases"] if c["outcome"] in ("failed", "warned", "error")}


@pytest.mark.parametrize("serial", [True, False], ids=["serial", "scheduled"])
@pytest.mark.parametrize("timing", [SHORT, DESCRIPTION], ids=["short", "description-5s"])
def test_the_reference_drone_with_the_vehicle_passes_every_case(timing, serial):
    run = run_cases(None, seed=1, serial=serial, mavlink=True, **timing)
    assert run.rc == 0, run.explain()
    assert not _bad(run), run.explain()
    assert not run.rules_with("failed", "warned"), run.explain()  # the monitor's included
    cases = run.cases()
    assert {c: cases.get(c) for c in VEHICLE_CASES} == VEHICLE_CASES, run.explain()
    skipped = [c for c in run.report["cases"] if c["outcome"] == "skipped"]
    assert all("not observable on a drone" in c["reason"] for c in skipped), [c["reason"] for c in skipped]
    assert run.models == 1


def test_the_vehicle_over_udp():
    """``--mavlink udpout``: the vehicle listens on UDP and learns the node from its HEARTBEAT."""
    run = run_cases(None, seed=1, mavlink="udpout", **SHORT)
    assert not _bad(run) and not run.rules_with("failed", "warned"), run.explain()
    cases = run.cases()
    assert {c: cases.get(c) for c in VEHICLE_CASES} == VEHICLE_CASES, run.explain()


def test_a_restarted_node_connects_again():
    """A node that crashes (MCP-ROB-1's sample fault) is started again for the next case: its
    client connects anew, and the vehicle's cases after it are judged on the new connection."""
    run = run_cases(mutant_factory("crash-on-short", rto=0.2, seed=3), seed=3, mavlink=True, **SHORT)
    assert run.rules_with("failed", "warned") == {"MCP-ROB-1": "failed"}, run.explain()
    assert run.models >= 2
    cases = run.cases()
    assert cases["BLK/test_end_mission_then_rtl"] == "passed", run.explain()


@pytest.mark.parametrize("serial", [True, False], ids=["serial", "scheduled"])
def test_the_vehicle_cases_through_the_runners_impaired_link(serial):
    """The MCP link impaired (the autopilot link is the host's loopback in a real run: clean):
    no failed or warned verdict; a vehicle case whose observation the link spoiled may be
    skipped, never failed."""
    run = run_cases(None, seed=5, serial=serial, mavlink=True, extra=IMPAIR)
    assert not run.rules_with("failed", "warned"), run.explain()
    assert not _bad(run), run.explain()
    judged = {c for c, o in run.cases().items() if c in VEHICLE_CASES and o != "skipped"}
    assert len(judged) >= len(VEHICLE_CASES) - 2, sorted(set(VEHICLE_CASES) - judged)


def test_a_seed_gives_the_same_run_with_the_vehicle():
    a, b = (run_cases(None, seed=4, mavlink=True, extra=IMPAIR) for _ in range(2))
    assert a.report["cases"] == b.report["cases"]
    assert a.report["monitor"] == b.report["monitor"]
    assert (a.virtual_s, a.switches) == (b.virtual_s, b.switches)


@pytest.mark.parametrize("transport", ["tcp", "udpout"])
def test_the_vehicle_runs_on_the_virtual_clock(transport):
    """The vehicle's seam: its threads, waits and timestamps on the virtual clock, its sockets
    the simulated net. A client that connects (TCP) or sends its HEARTBEAT (UDP) is on the link
    (``connected``), gets the vehicle's HEARTBEAT and, ``gps_fix_delay`` virtual seconds after
    the start, the 3D fix -- in no wall time to speak of; over TCP its end is the vehicle's
    ``disconnect``."""
    clock = VirtualClock(step=1e-6)
    net = SimVehicleNet(clock)
    client = AutopilotClient(("127.0.0.1", 41000))
    seen: dict[str, float] = {}

    def deliver(data: bytes) -> None:
        client.receive(data, clock.now)
        if client.fix:
            seen.setdefault("fix", clock.now)
        for frame in client.take_output():
            net.from_node(frame, client.addr)

    def main() -> None:
        vehicle, url = start_vehicle(clock, net, transport, gps_fix_delay=30.0)
        t0 = clock.monotonic()
        net.attach(client.addr, deliver)
        client.start(clock.now)
        for frame in client.take_output():
            net.from_node(frame, client.addr)
        assert url.startswith(f"{transport}:127.0.0.1:")
        assert vehicle.wait_for(lambda: vehicle.connected, 1.0)
        assert vehicle.wait_for(lambda: "fix" in seen, 60.0)
        seen["t0"] = t0
        assert client.heartbeat and vehicle.connections == 1
        net.detach(client.addr)
        if transport == "tcp":
            assert vehicle.wait_for(lambda: not vehicle.connected, 1.0)
            assert [e.detail["peer"] for e in vehicle.events("disconnect")] == ["127.0.0.1:41000"]
        vehicle.close()

    clock.run(main)
    assert 30.0 <= seen["fix"] - seen["t0"] < 31.5


@pytest.mark.parametrize("fault", sorted(n for n, f in FAULTS.items() if f.role == "drone"))
def test_each_drone_fault_with_the_vehicle_fails_its_rule_and_no_other(fault):
    """sim.faults' drone faults with the vehicle: ``no-dup-discard`` (MCP-DUP-1, which a run
    without a vehicle cannot observe: test_runner_sim's UNOBSERVED) is caught with its rule;
    a model that breaks no rule (``ack-twice``, D-9) gets no verdict."""
    run = run_cases(fault, seed=2, mavlink=True, **SHORT)
    rule = FAULTS[fault].rule
    assert run.rules_with("failed", "warned") == ({rule: "failed"} if rule else {}), run.explain()


def test_the_live_monitor_judges_as_the_capture_check_does(tmp_path):
    """The run's monitor ends at the run's clock (harness.drone_session ``close``): ended at the
    host's instead -- years after a virtual run's epoch -- it let MCP-BLK-7's deadline (3 s after
    End_Mission's ACK, past the run's end) pass, and judged 'passed' what ``mcp-capture check``
    of the same run's capture, rightly, left not observed. (The RTL the node commands after
    End_Mission is now judged when it comes, live and offline alike: 'passed' in both.)"""
    from tests.conformance.test_mutants import same_verdicts_offline

    capture = tmp_path / "run.mcap"
    run = run_cases(None, seed=7, mavlink=True, extra=("--capture", str(capture)), **SHORT)
    assert run.report["monitor"]["rules"]["1"]["MCP-BLK-7"] == "passed"
    same_verdicts_offline(run, capture)


@pytest.mark.parametrize("serial", [True, False], ids=["serial", "scheduled"])
def test_the_runners_threads_stalled_with_the_vehicle(serial):
    """sim.stalls with the vehicle: the runner's and the vehicle's threads left off the CPU for up
    to 0.3 s at one handoff in ten; no failed or warned verdict."""
    run = run_cases(None, seed=0, serial=serial, mavlink=True, stalls=(0.1, 0.3))
    assert not run.rules_with("failed", "warned"), run.explain()
    assert not _bad(run), run.explain()

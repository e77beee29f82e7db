"""``mcp-fuzz --protocol mavlink`` (issue 39 item 4): the cases are pymavlink's frames, the
profile's vehicle role names the fuzz target, our reference vehicle gives no finding, and each
fragile vehicle (tests/fuzz/fragile_vehicle.py; tests/mavlink/faulty_vehicle.py's answer faults)
is found, confirmed 3 of 3 on fresh processes, minimised, named by its rule, and replays
against itself (exit 1) and not against the reference vehicle (exit 0)."""

from __future__ import annotations

import json
import math
import random
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.findings import read_finding
from mcp_conform.fuzz.mavlink_campaign import MavlinkCampaign
from mcp_conform.fuzz.mavlink_cases import (
    KINDS,
    SET_INTERVAL,
    Case,
    CaseMaker,
    D,
    Vehicle,
    asks_heartbeat_stop,
    case_from_json,
    frame_name,
)
from tests.forkserver import run_module

FRAGILE = Path(__file__).with_name("fragile_vehicle.py")
FAULTY = Path(__file__).parents[1] / "mavlink" / "faulty_vehicle.py"


def fuzz(*args: str, timeout: float = 200) -> subprocess.CompletedProcess[str]:
    """``python -m mcp_conform.fuzz --protocol mavlink ARGS``: a child of the tests' fork server
    (tests/forkserver.py: its own process, the modules imported once)."""
    return run_module("mcp_conform.fuzz", ["--protocol", "mavlink", *args], timeout=timeout)


def proxy(path: Path, fault: str) -> str:
    return f"{sys.executable} {path} --listen {{target_host}}:{{target_port}} --fault {fault} --duration 400"


def _vehicle() -> Vehicle:
    return Vehicle(1, 1, {b"FORMAT_VERSION": (0, D.MAV_PARAM_TYPE_INT16), b"RTL_ALT": (1, D.MAV_PARAM_TYPE_INT32)},
                   b"FORMAT_VERSION")


def test_cases_are_the_dialects_frames():
    """Every kind is drawn; a well-formed case's frames are pymavlink's frames of the messages
    it names; malformed framing does not parse as the frame it spoiled; a case survives its
    finding.json form; no case touches the probe's parameter."""
    maker = CaseMaker(random.Random(7), _vehicle())
    seen = set()
    parser = D.MAVLink(None)
    parser.robust_parsing = True
    for _ in range(3000):
        c = maker.draw()
        seen.add(c.kind)
        assert case_from_json(json.loads(json.dumps(c.to_json()))) == c
        assert c.rule.startswith("MAV-") and c.frames
        assert b"FORMAT_VERSION" not in b"".join(c.frames)
        if c.kind in ("command-long", "command-int", "param-set", "mission-seq", "any-message", "v1-frame",
                      "untruncated"):
            got = [m.get_type() for m in parser.parse_buffer(b"".join(c.frames)) or []]
            assert got == [frame_name(f) for f in c.frames] == list(c.messages), c
        if c.kind == "bad-crc":
            assert [m.get_type() for m in parser.parse_buffer(c.frames[0]) or []] == ["BAD_DATA"]
    assert seen == set(KINDS)


def _stop_case(cls: str, param1: float, param2: float, target: tuple[int, int] = (1, 1)) -> Case:
    enc = D.MAVLink(None, srcSystem=255, srcComponent=190)
    if cls == "COMMAND_LONG":
        msg = D.MAVLink_command_long_message(*target, SET_INTERVAL, 0, param1, param2, 0, 0, 0, 0, 0)
    else:
        msg = D.MAVLink_command_int_message(*target, 0, SET_INTERVAL, 0, 0, param1, param2, 0, 0, 0, 0, 0)
    return Case("command-long", "MAV-CMD-1", (bytes(msg.pack(enc)),), messages=(cls,))


def test_a_case_asking_the_heartbeat_stopped_is_told_apart():
    """MAV_CMD_SET_MESSAGE_INTERVAL with param1 HEARTBEAT (0, or what a C cast may make 0) and
    param2 -1 or past the oracle's gap asks the stop (ArduPilot: ACCEPTED, the HEARTBEAT stops);
    another message, or an interval up to a second, does not."""
    for cls in ("COMMAND_LONG", "COMMAND_INT"):
        for p1, p2 in ((0, -1), (-0.0, -1), (1e-45, 3.4028234e38), (math.nan, -1), (0, 5e6), (0, math.inf)):
            assert asks_heartbeat_stop(_stop_case(cls, p1, p2)), (cls, p1, p2)
        for p1, p2 in ((30, -1), (1, -1), (0, 0), (0, 1e6), (0, 1e-45), (0, -0.5)):
            assert not asks_heartbeat_stop(_stop_case(cls, p1, p2)), (cls, p1, p2)
    spoiled = _stop_case("COMMAND_LONG", 0, -1)
    assert not asks_heartbeat_stop(replace(spoiled, frames=(spoiled.frames[0][:-1] + b"\0",)))  # bad checksum


def test_no_case_asks_the_heartbeat_stopped():
    """The command kinds' MAV_CMD_SET_MESSAGE_INTERVAL keeps the HEARTBEAT: a param2 that would
    stop it is sent as 0 (its default). Before, 249 of these 600 cases asked the stop, and a
    campaign on our vehicle that drew one reported a hang (the input's documented effect)."""
    maker = CaseMaker(random.Random(11), _vehicle())
    maker._command_id = lambda: (SET_INTERVAL, True)  # type: ignore[method-assign]
    parser = D.MAVLink(None)
    spared = 0
    for i in range(600):
        c = maker._command_long() if i % 2 else maker._command_int()
        assert not asks_heartbeat_stop(c), c
        m = parser.decode(bytearray(c.frames[0]))
        assert m.command == SET_INTERVAL
        spared += "would stop the HEARTBEAT" in c.note
    assert spared > 50, spared  # the rewrite was needed, and its cases still go to the HEARTBEAT


def test_a_hang_after_a_case_that_asked_it_is_no_finding(tmp_path):
    """Triage does not blame the vehicle for a heartbeat a suspect asked stopped (counted, not
    triaged), and ``--replay`` of such a finding (one written before) says so, exit 0, without
    replaying it."""
    from mcp_conform.fuzz.findings import FindingStore
    from mcp_conform.fuzz.mavlink_triage import STOP_ASKED, MavTriage, mavlink_finding, write_repro
    from mcp_conform.fuzz.mavlink_vehicle import Hit, Signature

    case = _stop_case("COMMAND_LONG", 0, -1)
    hit = Hit(Signature("hang", case.rule, case.kind), "a HEARTBEAT at least every 3 s", "none for 3 s", [])
    store = FindingStore(tmp_path, ["--protocol", "mavlink"], write_repro)
    triage = MavTriage(target=None, store=store)  # type: ignore[arg-type]  # no replay may start
    triage._triage(hit, [_stop_case("COMMAND_LONG", 30, 1e6), case])
    assert triage.untriaged == {STOP_ASKED: 1} and triage.replays == 0 and not store.order
    store.add(mavlink_finding(hit, [case], "3 of 3", b"FORMAT_VERSION", seed=0, worker=0))
    # no replay's traffic: repro.mcap holds its frames as the vehicle received them, and the finding
    from mcp_conform.traceio.reader import MavlinkFrame, open_capture

    repro = tmp_path / "finding-1" / "repro.mcap"
    assert read_finding(repro).doc["cases"] == [case.to_json()]
    assert [(r.direction, r.data) for r in open_capture(repro) if isinstance(r, MavlinkFrame)] == [("rx", case.frames[0])]
    run = fuzz("--replay", str(tmp_path / "finding-1"), timeout=60)
    assert run.returncode == 0 and "is no finding" in run.stdout and "not replayed" in run.stdout, run


def test_a_known_findings_hit_is_counted_by_its_group():
    """A hit whose group (rule and shape) is a finding already is one more occurrence of it,
    with no replay: an answer by its signature, a death by the case it showed after; one of
    another kind or signature is not that finding's, and a hang is never known this way (its
    culprit is among its suspects: ``HitTriage.known_lasting``)."""
    from mcp_conform.fuzz.findings import FindingStore
    from mcp_conform.fuzz.mavlink_triage import MavTriage, mavlink_finding
    from mcp_conform.fuzz.mavlink_vehicle import Hit, Signature

    case = CaseMaker(random.Random(3), _vehicle()).draw()
    answer = Hit(Signature("answer", "MAV-CMD-1", "no COMMAND_ACK"), "one COMMAND_ACK", "none")
    crash = Hit(Signature("crash", case.rule, case.kind), "the vehicle goes on", "it exited")
    store = FindingStore(None, ["--protocol", "mavlink"])
    for hit in (answer, crash):
        store.add(mavlink_finding(hit, [case], "3 of 3", b"FORMAT_VERSION"))
    triage = MavTriage(target=None, store=store)  # type: ignore[arg-type]  # no replay may start
    triage._triage(answer, [case])
    triage._triage(crash, [case])
    assert [f.occurrences for f in store.order] == [2, 2] and triage.replays == 0
    for sig in (Signature("answer", "MAV-CMD-1", "two COMMAND_ACKs"), Signature("answer", "MAV-CMD-2", "no COMMAND_ACK"),
                Signature("crash", case.rule, case.kind + "-other"), Signature("unanswered", case.rule, case.kind),
                Signature("hang", case.rule, case.kind)):
        assert triage._known(sig) is None, sig


def test_a_death_of_the_attached_vehicle_ends_the_campaign():
    """Attach mode: a vehicle that crashed or hung is the only one there is (no fresh vehicle to
    replay on): ``TargetLost`` names it and what it did, and triage replays nothing."""
    from types import SimpleNamespace

    from mcp_conform.fuzz.findings import FindingStore
    from mcp_conform.fuzz.mavlink_triage import MavTriage
    from mcp_conform.fuzz.mavlink_vehicle import Hit, Signature
    from mcp_conform.fuzz.target_base import TargetLost
    from mcp_conform.fuzz.target_core import TargetSpec

    how = TargetSpec(None, ("127.0.0.1", 5790))
    assert how.attached and not TargetSpec("mcp-vehicle", None).attached and not TargetSpec().attached
    target = SimpleNamespace(attached=how.attached, how=how)
    triage = MavTriage(target=target, store=FindingStore(None, ["--protocol", "mavlink"]))
    for oracle in ("crash", "hang"):
        with pytest.raises(TargetLost, match=f"the attached vehicle at tcp:127.0.0.1:5790: it {oracle}ed"):
            triage.consider(Hit(Signature(oracle, "MAV-CMD-1", "command-long"), "the vehicle goes on",
                                f"it {oracle}ed"), [])
    assert triage.replays == 0


def test_the_vehicle_role_names_its_fuzz_target():
    """spec.profiles: the vehicle role's fuzz target, its one engine, and mcp-fuzz's one-line
    refusals of what a MAVLink campaign does not take."""
    from mcp_conform.fuzz.config import default_engine, engines
    from mcp_conform.fuzz.mavlink_vehicle import MavTarget
    from mcp_conform.spec.profiles import pick, resolve

    assert resolve(pick("mavlink")[1].fuzz_target) is MavTarget
    assert engines("mavlink", "vehicle") == ("stateless",) and default_engine("vehicle", "mavlink") == "stateless"
    for args, says in ((["--engine", "stateful"], "--engine: a vehicle is fuzzed by the stateless engine only"),
                       (["--seeds", "x"], "--seeds: not available with --protocol mavlink"),
                       (["--target", "udp:127.0.0.1:14550"], "TCP only")):
        run = fuzz(*args, "--max-cases", "1", timeout=60)
        assert run.returncode == 2 and says in run.stderr and "Traceback" not in run.stderr, run.stderr
        assert len(run.stderr.strip().splitlines()) == 1, run.stderr


def test_a_short_campaign_on_the_reference_vehicle_finds_nothing(tmp_path):
    run = fuzz("--max-cases", "400", "--out", str(tmp_path), "-q", timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["protocol"] == "mavlink" and s["cases"] == 400 and s["findings"] == 0, s
    assert s["target"]["probe"] == "FORMAT_VERSION" and s["target"]["vehicle"] == "1/1"


@pytest.mark.slow
@pytest.mark.parametrize("spawn", ["reference", "proxy"])
def test_our_vehicle_gives_no_finding(tmp_path, spawn):
    """Our vehicle, alone and behind the fragile proxy with no fault: no finding (a false
    alarm is as bad as a missed fault; a hit a loaded host made, not confirmed by the replays,
    is counted unconfirmed, no finding)."""
    args = [] if spawn == "reference" else ["--spawn", proxy(FRAGILE, "none")]
    run = fuzz("--duration", "20", "--out", str(tmp_path), *args)
    s = json.loads((tmp_path / "summary.json").read_text())
    assert run.returncode == 0 and s["findings"] == 0, run.stdout + run.stderr
    assert s["cases"] > 1000 and set(s["by_kind"]) == set(KINDS), s["by_kind"]


#: fault -> (vehicle, oracle, rule): a death of each kind and the answers the conformance
#: suite's faulty vehicles give
FAULTS = {
    "param16-crash": (FRAGILE, "crash", "MAV-PRM-9"),
    "mission-seq-hang": (FRAGILE, "hang", "MAV-MIS-4"),
    "ignores-clear-all": (FRAGILE, "answer", "MAV-MIS-13"),
    "deaf-after-bad-crc": (FRAGILE, "unanswered", "MAV-HB-14"),
    "slow-heartbeat": (FRAGILE, "hang", "MAV-HB-1"),  # the vehicle's own: no input blamed
    "double-ack": (FAULTY, "answer", "MAV-CMD-3"),
    "acts-for-other-system": (FAULTY, "answer", "MAV-CMD-14"),
    "no-unsupported-ack": (FAULTY, "answer", "MAV-CMD-5"),
}


#: a campaign's bound: long enough for its first triage (which the budget never cuts), far
#: shorter than the 240 s a failure took before; the longest, mission-seq-hang (a stopped
#: heartbeat: 1 case among 500-2,500 suspects), is found by a search over the suspects'
#: prefixes (fuzz.triage_core.earliest_prefix) in 9-11 replays, 34-42 s of triage at load 4
DURATION_S = 120.0


@pytest.mark.slow
@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_a_fragile_vehicle_is_found_confirmed_and_replays(tmp_path, fault):
    path, oracle, rule = FAULTS[fault]
    spawn = proxy(path, fault)
    cfg = FuzzConfig(spawn=spawn, seed=7, duration=DURATION_S, engine="stateless", out=str(tmp_path),
                     protocol="mavlink", role="vehicle")
    cfg.extra["stop_on_rule"] = rule
    c = MavlinkCampaign(cfg)
    s = c.fuzz()
    found = [f for f in c.store.order if f.rule == rule]
    assert found, s
    f = found[0]
    assert f.source == oracle and f.replays == "3 of 3" and f.protocol == "mavlink", f
    n = c.store.order.index(f) + 1
    d = tmp_path / f"finding-{n}"
    doc = json.loads((d / "finding.json").read_text())
    assert doc["rule"] == rule and doc["rule_text"] and doc["probe"] == "FORMAT_VERSION"
    if fault == "slow-heartbeat":  # a fresh vehicle sent nothing shows it: no case is blamed
        assert doc["no_input"] and doc["cases"] == [] and [g.rule for g in c.store.order] == [rule], doc
    else:
        assert len(doc["cases"]) == 1 and not doc["no_input"], doc["cases"]  # minimised to the one case
    assert read_finding(d / "repro.mcap").rule == rule
    for args, want in ((["--spawn", spawn], 1), ([], 0)):
        run = fuzz("--replay", str(d), *args, timeout=120)
        assert run.returncode == want, (args, run.stdout, run.stderr)

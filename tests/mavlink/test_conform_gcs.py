"""``mcp-conform --protocol mavlink --role gcs`` (issue 39) end to end on real processes and
sockets: the runner plays the vehicle and spawns the ground station.

The matrix runs in the simulator (tests/sim/test_mavlink_gcs_sim.py, issue 38 item 4: the
reference GCS over every transport, under stalls and lossy links, and each of the 16 faulty
ground stations against the whole suite, ~1-2 s a run). What stays here, each run on real
sockets and timers, and why:

- the reference GCS (``mcp-node --protocol mavlink gcs``, the embedded default) over TCP,
  every case, and its capture; its verdicts, case by case, the simulator's for the same run;
- two faulty ground stations (tests/mavlink/faulty_gcs.py, processes of sim.gcs_faults'
  classes): ``mavlink1-start``, whose fault is pymavlink's own switch from MAVLink 1 (which the
  simulator restates), and ``rereads-out-of-order``, a parameter exchange -- each its rule and
  no other, case by case as the simulator judges it;
- over UDP (udp, udpout) a ground station slow to start (a process's start, which the
  simulator has not);
- the ground stations no one here wrote (mavwp, dronekit2, MAVSDK, MAVProxy) and a ground
  station that never starts (one line, exit 2).

A whole-suite test runs the suite in parts at once (``PARTS``, ``run_parts``), each part a
runner process of its own with its ``--select``, and judges their reports merged (``merged``):
the same cases against the same ground station, each with the run of its behaviour, in about
half the wall time of one serial run (issue 38; in the simulator, the parts merged give every
fault's verdicts of the whole suite, case by case and rule by rule).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from mcp_conform.sim.gcs_faults import RULES as FAULTS
from mcp_conform.sim.gcs_role import run_gcs_cases
from mcp_conform.spec import RULES
from tests.forkserver import run_module

FAULTY = Path(__file__).with_name("faulty_gcs.py")


def run(tmp_path: Path, *args: str, timeout: float = 400) -> tuple[int, dict, str]:
    out = tmp_path / "r.json"
    proc = run_module("conformance", ["--protocol", "mavlink", "--role", "gcs", "--json", str(out), *args],
                      timeout=timeout)
    assert out.exists(), proc.stdout + proc.stderr
    return proc.returncode, json.loads(out.read_text()), proc.stdout + proc.stderr


#: the parts a whole-suite test runs at once (a runner process each, starting its own ground
#: stations), balanced by their waits: CMD holds MAV-CMD-9's give-up window and the IN_PROGRESS
#: hold, MIS MAV-MIS-23's, PRM the list's. Each case asks for the run of its behaviour and gets
#: it, started afresh or kept from the case before that asked for the same, in a part as in the
#: whole suite; each part's verdicts are the simulator's for the same --select
PARTS = (("CMD",), ("HB", "MIS"), ("PRM",))


def run_parts(tmp_path: Path, *args: str, capture: bool = False,
              timeout: float = 400) -> list[tuple[tuple[str, ...], int, dict, str]]:
    """The whole suite as :data:`PARTS`, run at the same time: each part's (groups, exit code,
    report, output); ``{part}`` in an argument is the part's own directory (part-N); ``capture``:
    each part with ``--capture`` to its directory's run.mcap."""
    from concurrent.futures import ThreadPoolExecutor

    def part(n: int) -> tuple[tuple[str, ...], int, dict, str]:
        home = tmp_path / f"part-{n}"
        home.mkdir()
        extra = ("--capture", str(home / "run.mcap")) if capture else ()
        groups = PARTS[n]
        mine = [a.replace("{part}", str(home)) for a in args]
        rc, doc, out = run(home, *mine, *extra, *(a for g in groups for a in ("--select", g)), timeout=timeout)
        return groups, rc, doc, out

    with ThreadPoolExecutor(len(PARTS)) as pool:
        return list(pool.map(part, range(len(PARTS))))


def merged(parts: list[tuple[tuple[str, ...], int, dict, str]]) -> tuple[int, dict, str]:
    """The parts as one run's (exit code, report, output): the runner's own merge of several
    runs' reports (``conformance.report.merge_json``, as for xdist workers and ``--parallel``
    instances: the cases of all, each rule's worst outcome -- a part's report has the rules of
    the other parts' groups skipped -- the monitors' sections merged and their failures folded
    in as one run's)."""
    from mcp_conform.conformance.report import merge_json

    assert all(rc in (0, 1) and doc["error"] is None for _, rc, doc, _ in parts), [out for *_, out in parts]
    docs = [doc for _, _, doc, _ in parts]
    assert all(set(d["rules"]) == set(docs[0]["rules"]) for d in docs), [sorted(d["rules"]) for d in docs]
    return (max(rc for _, rc, _, _ in parts), merge_json(docs),
            "\n".join(f"--select {' '.join(g)}:\n{out}" for g, _, _, out in parts))


def failed(doc: dict) -> tuple[set[str], set[str]]:
    """The failed and warned rules, and the cases that did not pass."""
    rules = {r for r, o in doc["rules"].items() if o in ("failed", "warned", "error")}
    cases = {c["id"] for c in doc["cases"] if c["outcome"] not in ("passed", "info", "skipped")}
    return rules, cases


def outcomes(doc: dict) -> dict[str, str]:
    return {c["id"]: c["outcome"] for c in doc["cases"]}


def as_the_simulator_judges(doc: dict, fault: str | None, select: tuple[str, ...] = ()) -> None:
    """The real run's verdicts are the simulator's for the same ground station and cases: every
    case's outcome and every rule's."""
    sim = run_gcs_cases(fault, seed=1, select=select).report
    assert outcomes(doc) == outcomes(sim), (outcomes(doc), outcomes(sim))
    assert doc["rules"] == sim["rules"], {r: (o, sim["rules"].get(r)) for r, o in doc["rules"].items()
                                          if sim["rules"].get(r) != o}


@pytest.mark.slow
def test_reference_gcs_passes_every_case(tmp_path):
    """The embedded reference GCS over TCP: every case passes, none skipped, as in the
    simulator (each part's run as the simulator's for the same --select, and the whole suite's);
    each run's capture has the MAVLink channel and the cases."""
    parts = run_parts(tmp_path, capture=True)
    rc, doc, out = merged(parts)
    assert rc == 0, out
    assert failed(doc) == (set(), set()), out
    assert doc["role"] == "gcs" and doc["spec"]["protocol"] == "MAV"
    assert {c["outcome"] for c in doc["cases"]} == {"passed"}, out
    for groups, _, part, _ in parts:
        as_the_simulator_judges(part, None, groups)
    as_the_simulator_judges(doc, None)
    from mcap.reader import make_reader

    for n in range(len(parts)):
        with open(tmp_path / f"part-{n}" / "run.mcap", "rb") as fh:
            topics = {ch.topic for _, ch, _ in make_reader(fh).iter_messages()}
        assert "/mavlink" in topics and "/conformance/case" in topics, topics


#: the faults that stay on real processes (the module docstring says why)
REAL_FAULTS = ("mavlink1-start", "rereads-out-of-order")


@pytest.mark.slow
@pytest.mark.parametrize("fault", REAL_FAULTS)
def test_a_faulty_gcs_fails_its_rule_and_no_other(tmp_path, fault):
    """The ground station with one fault, as a process, against its rule's group and the
    heartbeat's: its rule and nothing else fails (warned, for a SHOULD), the case naming it with
    what was expected and seen -- and each case as the simulator judges it."""
    spawn = f"{sys.executable} {FAULTY} --fault {fault} {{mavlink}} --linger 5"
    group = (FAULTS[fault].split("-")[1], "HB")
    rc, doc, out = run(tmp_path, "--spawn", spawn, *(a for g in group for a in ("--select", g)))
    rules, cases = failed(doc)
    rule = FAULTS[fault]
    assert rules == {rule}, out
    assert rc == (0 if RULES[rule].level == "SHOULD" else 1), out  # a SHOULD is warned: exit 0
    case = next(c for c in doc["cases"] if c["id"] in cases)
    assert case["failed_rule"] == rule and case["expected"] and case["actual"], case
    as_the_simulator_judges(doc, fault, group)


def test_a_gcs_that_never_connects_is_one_line_exit_2(tmp_path):
    """A ground station that exits at once: exit 2, the reason in one line, no traceback."""
    rc, doc, out = run(tmp_path, "--spawn", f"{sys.executable} -c pass", "--startup-timeout", "2", timeout=60)
    assert rc == 2 and "the ground station" in doc["error"] and "Traceback" not in out, out


@pytest.mark.slow
@pytest.mark.parametrize("transport", ["udp", "udpout"])
def test_a_ground_station_slow_to_start_over_udp_has_no_heartbeat_gap(tmp_path, transport):
    """Over UDP the runner's link is open before the ground station is spawned; a station
    whose process takes 3.5 s to start (a loaded host: CI's run at 642 s gave the reference
    GCS's first gap as 3.14 s) has its heartbeat judged from its first frame, not from the
    link's opening (MAV-HB-2 failed it before)."""
    import shlex

    ref = f"{shlex.quote(sys.executable)} -m mcp_conform.reference_impl --protocol mavlink gcs {{mavlink}}"
    spawn = f"sh -c {shlex.quote(f'sleep 3.5; exec {ref}')}"
    rc, doc, out = run(tmp_path, "--mavlink", transport, "--spawn", spawn, "--select", "MAV-HB-2", timeout=120)
    assert rc == 0 and doc["rules"]["MAV-HB-2"] == "passed", out


REAL = Path(__file__).with_name("real_gcs.py")
#: what each ground station no one here wrote gets (docs/guide/mavlink-gcs.md's table): its
#: failed and warned rules, pinned so that a change in the library or in the suite shows
REAL_GCS = {
    "mavwp": {"MAV-HB-6", "MAV-CMD-6", "MAV-MIS-12", "MAV-MIS-22", "MAV-PRM-16", "MAV-PRM-17"},
    "dronekit": {"MAV-HB-6", "MAV-HB-11", "MAV-CMD-6", "MAV-CMD-16", "MAV-MIS-20", "MAV-MIS-22", "MAV-PRM-16",
                 "MAV-PRM-17"},
    "mavsdk": {"MAV-CMD-8"},
}
#: of those, the rules a ground station breaks only in its first moments, depending on what it
#: heard by then: dronekit2's pymavlink starts in MAVLink 1 and switches at the first MAVLink 2
#: frame it hears, its numbers starting again (MAV-HB-11) only if it sent before that; its
#: start-up requests to component 0 (MAV-CMD-16) likewise (fresh-clone CI run 14: neither)
STARTUP_DEPENDENT = {"dronekit": {"MAV-HB-11", "MAV-CMD-16"}}


@pytest.mark.slow
@pytest.mark.parametrize("client", sorted(REAL_GCS))
def test_real_ground_stations(tmp_path, client):
    """pymavlink's mavwp upload idiom, dronekit2 and MAVSDK's client side, each in its own
    idiom (tests/mavlink/real_gcs.py): the rules each fails, each failure with its evidence."""
    rc, doc, out = merged(run_parts(tmp_path, "--spawn", f"{sys.executable} {REAL} --client {client} {{mavlink}}"))
    rules, _ = failed(doc)
    assert REAL_GCS[client] - STARTUP_DEPENDENT.get(client, set()) <= rules <= REAL_GCS[client], out
    assert all(c["expected"] and c["actual"] for c in doc["cases"] if c["outcome"] in ("failed", "warned")), out


@pytest.mark.slow
def test_mavproxy_wp_load(tmp_path):
    """MAVProxy headless: ``wp load`` and ``long`` from --cmd; it never resends an unanswered
    MISSION_COUNT (its wp module copes with loss on download only) nor a ``long`` command."""
    import shutil

    mavproxy = shutil.which("mavproxy.py")
    if mavproxy is None:
        pytest.skip("MAVProxy is not installed")
    mission = Path(__file__).resolve().parents[2] / "examples" / "mission.waypoints"
    spawn = (f"{sys.executable} {mavproxy} --master={{mavlink}} --non-interactive --target-system=1 "
             "--target-component=1 --state-basedir={part} "
             f"--cmd='wp load {mission}; long REQUEST_MESSAGE 148'")
    rc, doc, out = merged(run_parts(tmp_path, "--spawn", spawn))
    assert failed(doc)[0] == {"MAV-CMD-6", "MAV-MIS-22"}, out


@pytest.mark.slow
@pytest.mark.parametrize("transport", ["udp", "tcp"])
def test_a_ground_station_that_dies_before_its_first_frame_is_an_error_not_a_skip(tmp_path, transport):
    """A ground station started afresh for a behaviour (``harness.link_session.PlayedNodeSession.run``)
    that ends before it sends a frame: each case of that behaviour is an error naming its death,
    over UDP as over TCP. Before, over UDP, the wait for its first frame ended at its death and
    the run went on: its cases were skipped as "the ground station sent no ... (it never
    exercised the rule)", the crash nowhere (H-harness39b noticed)."""
    count = tmp_path / "starts"
    script = tmp_path / "dies_after_first.sh"
    script.write_text(f"#!/bin/sh\nn=$(cat {count} 2>/dev/null || echo 0)\necho $((n + 1)) > {count}\n"
                      f'[ "$n" -ge 1 ] && {{ echo "crashed on start $((n + 1))" >&2; exit 3; }}\n'
                      f'exec {sys.executable} {REAL} --client mavwp "$1"\n')
    script.chmod(0o755)
    rc, doc, out = run(tmp_path, "--mavlink", transport, "--select", "MIS", "--spawn", f"{script} {{mavlink}}")
    cases = doc["cases"]  # in the order they ran: those of its first start, then the later ones
    first = next((i for i, c in enumerate(cases) if c["outcome"] == "error"), len(cases))
    assert int(count.read_text()) > 1 and cases[first:], out  # the suite started it again: an error
    for c in cases[first:]:  # each case after its first start: the death named (TCP: before it connected)
        said = c.get("reason") or c.get("actual") or ""
        assert c["outcome"] == "error" and "exited with code 3 before it" in said, (c, out)

"""Every protocol's and role's run report follows the shipped ``report.schema.json``
(``conformance.report.validate_json``), its monitor section included: MAVLink's reports of
both roles did not (role ``vehicle``/``gcs``, ``MAV`` and ``MAV-`` rule IDs, a monitor of frames
by SYSID/COMPID). The runs are the simulator's (the same cases and monitor as a real run, on
virtual time); Nsqd's real runs are checked in tests/nsqd/test_conform_nsqd.py, the loading of
the schema from an installed package in tests/conformance/test_report_schema.py. And a run of a
ground station that stays in MAVLink 1, whose report is checked here too."""

from __future__ import annotations

import pytest

from mcp_conform.conformance.report import validate_json
from mcp_conform.sim.gcs_faults import RULES as GCS_FAULTS
from mcp_conform.sim.gcs_role import run_gcs_cases
from mcp_conform.sim.vehicle_faults import RULES as VEHICLE_FAULTS
from tests.sim.shared_runs import gcs_run, vehicle_run

#: the runs are the ones tests/sim/test_mavlink_*_sim.py judge (tests/sim/shared_runs.py): the
#: reference's at seed 1, a fault's at seed 2
REFERENCE_SEED, FAULT_SEED = 1, 2


@pytest.mark.parametrize("fault", [None, next(iter(GCS_FAULTS))])
def test_a_gcs_role_report_follows_the_schema(fault):
    doc = gcs_run(fault, REFERENCE_SEED if fault is None else FAULT_SEED).report
    assert doc["role"] == "gcs" and doc["spec"]["protocol"] == "MAV" and doc["monitor"]["nodes"], doc["monitor"]
    validate_json(doc)


@pytest.mark.parametrize("fault", [None, next(iter(VEHICLE_FAULTS))])
def test_a_vehicle_role_report_follows_the_schema(fault):
    doc = vehicle_run(fault, REFERENCE_SEED if fault is None else FAULT_SEED).report
    assert doc["role"] == "vehicle" and doc["monitor"]["nodes"], doc["monitor"]
    if fault is not None:
        assert doc["monitor"]["violations"] or any(o == "failed" for o in doc["rules"].values()), doc["rules"]
    validate_json(doc)


def test_a_ground_station_that_stays_in_mavlink1_runs_the_whole_suite():
    """``--mavlink1``: a ground station that starts in MAVLink 1 (sim.gcs_faults' mavlink1-start,
    the reference GCS on pymavlink's MAVLink 1 dialect) stays in it, its vehicle never speaking
    MAVLink 2: its uploads leave out the extension fields MAVLink 1 has not (``mission_type``).
    It raised TypeError on MISSION_ITEM_INT's ``mission_type`` and its cases were skipped; its
    fault (the switch's sequence gap) is not observable there, so every case passes."""
    doc = run_gcs_cases("mavlink1-start", extra=("--mavlink1",)).report
    assert doc["error"] is None and {c["outcome"] for c in doc["cases"]} == {"passed"}, doc["summary"]
    validate_json(doc)


def test_reports_of_a_vehicle_role_merge_into_one_that_follows_the_schema():
    """``report.merge_json`` (xdist workers, ``--parallel`` instances) of MAVLink reports: it
    raised AttributeError on the frame monitor's section (one rule table, nodes by SYSID/COMPID,
    frames), which it read as MCP's per-node tables. Frames summed, the faulty run's failures
    kept, valid against the schema."""
    from mcp_conform.conformance.report import merge_json

    good = vehicle_run(None, REFERENCE_SEED).report
    bad = vehicle_run("double-ack", FAULT_SEED).report
    doc = merge_json([good, bad])
    assert validate_json(doc) is None
    assert doc["monitor"]["frames"] == good["monitor"]["frames"] + bad["monitor"]["frames"]
    failed = {r for r, v in bad["rules"].items() if v == "failed"}
    assert failed and failed <= {r for r, v in doc["rules"].items() if v == "failed"}
    assert len(doc["cases"]) == len(good["cases"]) + len(bad["cases"])
    ids = [n["id"] for n in doc["monitor"]["nodes"]]
    assert len(ids) == len(set(ids)) == len({n["id"] for n in good["monitor"]["nodes"]})

"""Seed 001's style of ground station through ``mcp-conform --protocol mavlink --role gcs``
(issue 39): the C programs of examples/mavlink_c/ (built now by their Makefile, on MAVLink 1
headers from pymavlink's mavgen) run as the ground station for every behaviour of the runner's
vehicle, each failure named under its rule with evidence; the outcome pinned like the other
real ground stations' (tests/mavlink/test_conform_gcs.py, docs/guide/mavlink-gcs.md's table).

The programs speak UDP with ``-v/-l/-H`` and parse MAVLink 1 only: the runner's vehicle speaks
MAVLink 1 from the start (``mcp-conform --mavlink1``), and tests/mavlink/udp_args.py only turns
``{mavlink}`` into their options (no relay: the runner and the program exchange datagrams
directly)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.examples import test_mavlink_c as examples
from tests.mavlink.test_conform_gcs import failed, merged, run_parts

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
WRAP = Path(__file__).with_name("udp_args.py")
build = examples.build  # the examples built by their Makefile and checked, once a module

#: the failed and warned rules of each program, as docs/guide/mavlink-gcs.md's table says why
SEED_GCS = {
    # the seed's defect (-b: item 1 first as a MISSION_ITEM with the degE7 integer in its
    # degrees field) shows as the deprecated MISSION_ITEM (MIS-12) and as a re-requested item 1
    # that differs from the first (MIS-20: the program sends the corrected item the second time),
    # and as MAV-MIS-26 (D-6): a latitude of 357713312.0 degrees. Arm is retried until accepted or the
    # program's -t deadline: more than 10 resends (CMD-9), confirmation back to 0 every three (CMD-8), resent
    # through IN_PROGRESS (CMD-10); no HEARTBEAT after the vehicle's first (HB-2)
    "mission_takeoff -b": {"MAV-HB-2", "MAV-CMD-8", "MAV-CMD-9", "MAV-CMD-10", "MAV-MIS-12", "MAV-MIS-20",
                           "MAV-MIS-26"},
    "arm_disarm": {"MAV-CMD-8", "MAV-CMD-9", "MAV-CMD-10"},
}


@pytest.mark.parametrize(("program", "transport"), [("mission_takeoff -b", "udpout"), ("arm_disarm", "udp")])
def test_seed_programs_through_the_gcs_suite(tmp_path, build, program, transport):
    """Each program as the ground station over UDP (udpout: it sends to the runner's port, -v;
    udp: the runner sends to its port, -l): the rules it fails, each failure with what was
    expected and what came."""
    spawn = f"{sys.executable} {WRAP} {{mavlink}} {build / program}"
    rc, doc, out = merged(run_parts(tmp_path, "--mavlink", transport, "--mavlink1", "--spawn", spawn))
    rules, _ = failed(doc)
    assert rules == SEED_GCS[program], out
    assert rc == 1 and doc["summary"]["error"] == 0, out
    assert all(c["expected"] and c["actual"] for c in doc["cases"] if c["outcome"] in ("failed", "warned")), out
    assert any(c["outcome"] == "passed" and c["id"].startswith("HB/") for c in doc["cases"]), out


def test_wrapper_refuses_tcp_in_one_line(build):
    """The programs speak UDP only: a TCP ``{mavlink}`` is one line, exit 2, nothing run."""
    proc = subprocess.run([sys.executable, str(WRAP), "tcp:127.0.0.1:5760", str(build / "heartbeat")],
                          capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "UDP only" in proc.stderr, proc.stderr


def test_wrapper_leaves_mavlink1_to_the_runner():
    """The wrapper re-packs nothing: its old ``--mavlink1`` is one line naming the runner's, exit 2."""
    proc = subprocess.run([sys.executable, str(WRAP), "--mavlink1", "udp:127.0.0.1:14550", "true"],
                          capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "mcp-conform" in proc.stderr, proc.stderr

"""NSQD-MSG-1 observed at a fast UPDATE period: "no gap longer than update_gap_max_s" (1.5 s).

MSG/test_update_stream_keeps_its_period watches a connection for twelve of the backend's
periods. Below 0.125 s that was under 1.5 s, so no gap over the allowance fit in the watch and
a stream that stopped could not fail the case. The watch is now never under twice the
allowance: a backend at a 0.05 s period whose stream stops 0.6 s into each connection
(tests/fuzz/servers/misbehaving_backend.py ``--mode stops``) fails NSQD-MSG-1 there; before,
the case passed it. The reference backend, at the same period, passes."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

from tests.forkserver import run_module

pytestmark = [pytest.mark.slow, pytest.mark.nsqd]

ROOT = Path(__file__).resolve().parents[2]
CASE = "MSG/test_update_stream_keeps_its_period"


def _case(tmp_path: Path, *spawn: str) -> dict:
    out = tmp_path / "r.json"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = run_module("conformance", ["--protocol", "nsqd", "--json", str(out), *spawn, "--select", CASE],
                      timeout=300, cwd=ROOT, env=env)
    doc = json.loads(out.read_text())
    (case,) = [c for c in doc["cases"] if c["id"] == CASE]
    return {"case": case, "rules": doc["rules"], "out": proc.stdout + proc.stderr}


def test_a_stream_that_stops_at_a_fast_period_fails_msg1(tmp_path):
    cmd = (f"{sys.executable} -m tests.fuzz.servers.misbehaving_backend --bind {{target_host}}:{{target_port}} "
           "--mode stops --lifetime 120")
    got = _case(tmp_path, "--spawn", cmd)
    assert got["case"]["outcome"] == "failed" and got["rules"]["NSQD-MSG-1"] == "failed", got["out"]
    assert "a gap of" in got["case"]["actual"], got["case"]


def test_the_reference_backend_at_its_fast_period_passes(tmp_path):
    got = _case(tmp_path)  # the embedded reference backend: a 0.05 s period
    assert got["case"]["outcome"] == "passed" and got["rules"]["NSQD-MSG-1"] == "passed", got["out"]

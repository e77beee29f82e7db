"""A backend that dies on a case's frame but is seen dead only later (its connection closed
at once, its process ended ``--delay`` s after: tests/nsqd/late_death_backend.py) is that
case's NSQD-ROB-1 failure, with the frame that killed it in hex, and the next case runs on a
restarted backend and passes. The runner proves the backend alive after a case's writes
before its verdict (``StreamCaseContext.conclude``), as the fuzzer keeps a case a suspect
until a probe proves the backend alive after it; a refused connection gives the process a
moment to end (a death, not a node lost)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

from tests.forkserver import run_module

pytestmark = [pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[2]
NEXT = "ROB/test_client_leaving_mid_frame[fin]"


def _run(tmp_path: Path, killer: str, *backend_args: str) -> tuple[dict, str, int]:
    out = tmp_path / "r.json"
    cmd = " ".join([sys.executable, "-m", "tests.nsqd.late_death_backend", "--bind", "{target_host}:{target_port}",
                    *backend_args])
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = run_module("conformance", ["--protocol", "nsqd", "--json", str(out), "--spawn", cmd, "--select", killer,
                                      NEXT], timeout=300, cwd=ROOT, env=env)
    doc = json.loads(out.read_text())
    cases = {c["id"]: c for c in doc["cases"]}
    assert list(cases) == [killer, NEXT], proc.stdout + proc.stderr
    return cases, proc.stdout + proc.stderr, proc.returncode


@pytest.mark.parametrize("killer,backend_args,killing_frame", [
    # the case sees the backend close the connection (D-3 allows it) and ends; the process
    # dies 0.6 s later, while a new connection waits in the backlog
    ("MSG/test_rejected_frame_leaves_the_stream_in_sync[number-text-not-a-number]", ("--delay", "0.6"),
     " 06 00 01 78 "),  # SET_PID (id 6), kp the 1-byte text "x"
    # the case sees the close, then its new connection refused while the process still runs
    ("MSG/test_malformed_body_is_not_applied[number-text-not-a-number]", ("--delay", "0.3", "--close-listener"),
     " 07 00 03 61 62 63 "),  # SET_RPYTFF (id 7), roll the text "abc"
], ids=["seen-in-the-next-case", "refused-before-reaped"])
def test_a_late_death_is_blamed_on_the_frame_that_killed_the_backend(tmp_path, killer, backend_args, killing_frame):
    cases, out, rc = _run(tmp_path, killer, *backend_args)
    case = cases[killer]
    assert case["outcome"] == "failed" and case["failed_rule"] == "NSQD-ROB-1", case
    assert "killed by SIGABRT" in case["actual"], case
    assert any(e.startswith("sent ") and killing_frame in e for e in case["evidence"]), case["evidence"]
    assert cases[NEXT]["outcome"] == "passed", cases[NEXT]
    assert rc == 1, out

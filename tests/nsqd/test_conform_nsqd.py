"""``mcp-conform --protocol nsqd`` against the embedded reference backend and against the C
backend of tests/nsqd_backends (built with AddressSanitizer), correct and with each of its
faults: every fault fails its own rule and no other (issue 20); the reference backend passes
runs in a row with one outcome set; a backend that dies on a frame is reported as a failure
of the rule that frame tested, with the signal, the sanitizer's line and the frame in hex,
and the run completes with its JSON and JUnit intact."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

from mcp_conform.conformance.report import validate_json
from tests.capturing import free_port
from tests.forkserver import run_module
from tests.nsqd_backends.build import FAULTS, built_or_skip

pytestmark = [pytest.mark.slow, pytest.mark.nsqd]


def run(tmp_path: Path, *args: str) -> tuple[int, dict, str]:
    out = tmp_path / "r.json"
    proc = run_module("conformance", ["--protocol", "nsqd", "--json", str(out), "--junit", str(tmp_path / "j.xml"),
                                      *args], timeout=300)
    return proc.returncode, json.loads(out.read_text()), proc.stdout + proc.stderr


def rules_with(doc: dict, *outcomes: str) -> dict[str, str]:
    return {rule: outcome for rule, outcome in doc["rules"].items() if outcome in outcomes}


@pytest.fixture(scope="module")
def backend() -> Path:
    return built_or_skip()


#: The UPDATE period of a backend whose run is no test of timing (CI time): a faulty C backend,
#: the attached reference backend; the embedded reference backend's
#: (``harness.nsqd_session.EMBEDDED_UPDATE_PERIOD``).
CI_PERIOD = "0.05"


def spawn(exe: Path, fault: str | None = None) -> list[str]:
    """The C backend; the correct one at the description's 0.4 s UPDATE period, a faulty one
    at :data:`CI_PERIOD` (CI time: every fault is one of a verdict, not of timing), but
    update-stops at the description's 0.4 s (its stream stops 3 s into a connection, and
    NSQD-MSG-1's case watches twelve periods)."""
    cmd = f"{exe} --host {{target_host}} --port {{target_port}}"
    if fault and fault != "update-stops":
        cmd += f" --update-period {CI_PERIOD}"
    return ["--spawn", cmd + (f" --fault {fault}" if fault else "")]


def test_reference_backend_passes_every_rule(tmp_path):
    """Runs in a row with one outcome set (``MCP_NSQD_RUNS``, default 2; 20 by hand); the
    first records a capture whose channels are the protocol's own."""
    outcomes = set()
    for i in range(int(os.environ.get("MCP_NSQD_RUNS", "2"))):
        extra = ("--capture", str(tmp_path / "run.mcap")) if i == 0 else ()
        rc, doc, out = run(tmp_path, *extra)
        assert rc == 0, out
        assert not rules_with(doc, "failed", "warned"), out
        assert doc["spec"]["protocol"] == "NSQD" and doc["role"] == "backend"
        validate_json(doc)  # the shipped report.schema.json (NSQD- rule IDs)
        outcomes.add(tuple(sorted((c["id"], c["outcome"]) for c in doc["cases"])))
        if i == 0:
            from mcap.reader import make_reader

            with open(tmp_path / "run.mcap", "rb") as fh:
                topics = Counter(ch.topic for _, ch, _ in make_reader(fh).iter_messages())
            assert set(topics) == {"/nsqd/tx", "/nsqd/rx", "/nsqd/conn", "/conformance/case", "/log"}, topics
            assert topics["/conformance/case"] == 2 * len(doc["cases"]) == topics["/log"]  # Foxglove's log
    assert len(outcomes) == 1


def test_correct_c_backend_passes(tmp_path, backend):
    rc, doc, out = run(tmp_path, *spawn(backend))
    assert rc == 0, out
    assert not rules_with(doc, "failed", "warned"), out


@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_each_fault_fails_its_own_rule_and_no_other(tmp_path, backend, fault):
    rule = FAULTS[fault]
    extra = ("--capture", str(tmp_path / "run.mcap"), "--html", str(tmp_path / "run.html")) \
        if fault in ("wrong-stop-test-state", "crash-on-negative-string") else ()
    rc, doc, out = run(tmp_path, *spawn(backend, fault), *extra)
    flagged = rules_with(doc, "failed", "warned")
    assert rule in flagged, out
    assert set(flagged) == {rule}, (flagged, out)
    assert rc == (1 if flagged[rule] == "failed" else 0), out
    assert (tmp_path / "j.xml").read_text().count("<testcase") == len(doc["cases"])
    if extra:  # the capture stays whole through a death and a restart; the page charts the failure
        from mcp_conform.traceio.reader import CaseMark, open_capture

        cap = open_capture(tmp_path / "run.mcap")
        records = list(cap)
        assert cap.truncated is None
        assert sum(type(r) is CaseMark for r in records) == 2 * len(doc["cases"])
        page = (tmp_path / "run.html").read_text()
        assert "<svg" in page and "runner conn" in page
    if fault in ("crash-on-negative-string", "gpx-stack-overflow", "crash-on-bad-number"):
        failed = [c for c in doc["cases"] if c["outcome"] == "failed"]
        assert any("killed by SIGABRT" in (c.get("actual") or "") or "exited with status" in (c.get("actual") or "")
                   for c in failed), failed
        assert any(any("sent " in e for e in c.get("evidence", [])) for c in failed), failed


def test_attach_mode_against_a_running_backend(tmp_path):
    """``--target``: the reference backend started by hand (``mcp-node --protocol nsqd``)."""
    import socket

    port = free_port(socket.SOCK_STREAM)
    node = subprocess.Popen([sys.executable, "-m", "mcp_conform.reference_impl", "--protocol", "nsqd", "backend",
                             "--bind", f"127.0.0.1:{port}", "--update-period", CI_PERIOD],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert node.stdout is not None and node.stdout.readline().startswith("listening on")
        rc, doc, out = run(tmp_path, "--target", f"127.0.0.1:{port}")
        assert rc == 0, out
        assert doc["target"] == f"127.0.0.1:{port}" and not rules_with(doc, "failed", "warned")
    finally:
        node.terminate()
        node.wait(timeout=10)
    rc, doc, out = run(tmp_path, "--target", f"127.0.0.1:{port}")  # nothing listens now
    assert rc == 2 and "accepted no connection" in doc["error"]

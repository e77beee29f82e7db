"""``mcp-conform --protocol nsqd`` against the embedded reference backend and against the C
backend of tests/nsqd_backends (built with AddressSanitizer), correct and with each of its
faults: every fault fails its own rule and no other (issue 20); the reference backend passes
runs in a row with one outcome set; a backend that dies on a frame is reported as a failure
of the rule that frame tested, with the signal, the sanitizer's line and the frame in hex,
and the run completes with its JSON and JUnit intact."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.nsqd_backends.build import FAULTS, available, build

pytestmark = pytest.mark.slow


def run(tmp_path: Path, *args: str) -> tuple[int, dict, str]:
    out = tmp_path / "r.json"
    proc = subprocess.run([sys.executable, "-m", "conformance", "--protocol", "nsqd", "--json", str(out),
                           "--junit", str(tmp_path / "j.xml"), *args],
                          capture_output=True, text=True, timeout=300)
    return proc.returncode, json.loads(out.read_text()), proc.stdout + proc.stderr


def rules_with(doc: dict, *outcomes: str) -> dict[str, str]:
    return {rule: outcome for rule, outcome in doc["rules"].items() if outcome in outcomes}


@pytest.fixture(scope="module")
def backend() -> Path:
    why = available()
    if why:
        pytest.skip(why)
    return build()


def spawn(exe: Path, fault: str | None = None) -> list[str]:
    """The C backend; a faulty one at a 0.1 s UPDATE period (CI time), but update-stops at the
    description's 0.4 s (its stream stops 3 s into a connection)."""
    cmd = f"{exe} --host {{target_host}} --port {{target_port}}"
    if fault and fault != "update-stops":
        cmd += " --update-period 0.1"
    return ["--spawn", cmd + (f" --fault {fault}" if fault else "")]


def test_reference_backend_passes_every_rule(tmp_path):
    outcomes = set()
    for _ in range(3):
        rc, doc, out = run(tmp_path)
        assert rc == 0, out
        assert not rules_with(doc, "failed", "warned"), out
        assert doc["spec"]["protocol"] == "NSQD" and doc["role"] == "backend"
        outcomes.add(tuple(sorted((c["id"], c["outcome"]) for c in doc["cases"])))
    assert len(outcomes) == 1


def test_correct_c_backend_passes(tmp_path, backend):
    rc, doc, out = run(tmp_path, *spawn(backend))
    assert rc == 0, out
    assert not rules_with(doc, "failed", "warned"), out


@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_each_fault_fails_its_own_rule_and_no_other(tmp_path, backend, fault):
    rule = FAULTS[fault]
    rc, doc, out = run(tmp_path, *spawn(backend, fault))
    flagged = rules_with(doc, "failed", "warned")
    assert rule in flagged, out
    assert set(flagged) == {rule}, (flagged, out)
    assert rc == (1 if flagged[rule] == "failed" else 0), out
    assert (tmp_path / "j.xml").read_text().count("<testcase") == len(doc["cases"])
    if fault in ("crash-on-negative-string", "gpx-stack-overflow", "crash-on-bad-number"):
        failed = [c for c in doc["cases"] if c["outcome"] == "failed"]
        assert any("killed by SIGABRT" in (c.get("actual") or "") or "exited with status" in (c.get("actual") or "")
                   for c in failed), failed
        assert any(any("sent " in e for e in c.get("evidence", [])) for c in failed), failed

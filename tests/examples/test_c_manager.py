"""The C Mission Manager (examples/mcp_c/manager/) built now and judged by ``mcp-conform --role
manager``: an MCP node no one here wrote in Python, from the protocol's documents only.

The correct manager (built under AddressSanitizer) earns, challenge by challenge, every rule the
manager role observes at that challenge (MCP-FLOW-4, -5, -6 each at its own) with no failure,
warning or error, in the report and in the trace monitor; each faulty build (``make FAULT=...``)
fails the one rule its fault breaks, found by the rule's text, and no other MUST or SHOULD rule.
Short timings: the node's --rto and the runner's are both 0.3 s (--ack-window 0.3).
"""

from __future__ import annotations

import json
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from mcp_conform.spec import RULES
from tests.forkserver import run_module
from tests.xdist_once import once

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
SOURCE = ROOT / "examples" / "mcp_c" / "manager"
RTO = "0.3"
FAULTS = ("ACK_HOST_ORDER", "NO_RETRANSMIT", "ANY_ACK")

#: the manager role's rules no manager can show on the wire (the spec's observe: none), or
#: that this manager never exercises: it sends no broadcast (MCP-RTX-4) and no
#: Mav_Passthrough (MCP-PAY-6)
NOT_OBSERVED = {"MCP-SEQ-3", "MCP-DUP-1", "MCP-DUP-2", "MCP-DUP-3", "MCP-DUP-4",
                "MCP-RTX-4", "MCP-PAY-6"}
INFO = {"MCP-SEQ-4", "MCP-TRN-1", "MCP-FLOW-7"}
#: the rules of one challenge only: (challenge 1, 2, 3) -> the rules it exercises
BY_CHALLENGE = {1: {"MCP-FLOW-4", "MCP-PAY-3"}, 2: {"MCP-FLOW-5", "MCP-PAY-5"},
                3: {"MCP-FLOW-6", "MCP-PAY-3"}}


def rule_by_text(words: str) -> str:
    """The ID of the one rule whose text holds ``words``."""
    found = [r.id for r in RULES.values() if words in r.text]
    assert len(found) == 1, (words, found)
    return found[0]


#: each fault and the rule it breaks, by the rule's text
BROKEN = {
    "ACK_HOST_ORDER": rule_by_text("An ACK's payload is exactly 2 bytes"),
    "NO_RETRANSMIT": rule_by_text("retransmits it until it is ACKed or its retry limit"),
    "ANY_ACK": rule_by_text("Only an ACK from the message's destination whose payload equals"),
}


@pytest.fixture(scope="module")
def builds(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The correct manager (ASan) and each faulty one, built by the Makefile once a test
    session (tests/xdist_once.py), the MAVLink headers generated once for all."""
    missing = [t for t in ("cc", "make") if shutil.which(t) is None]
    if missing:
        pytest.skip(f"{' and '.join(missing)} not installed (.ci/apt-tools installs gcc, make)")

    def make(out: Path) -> dict[str, Path]:
        made = {}
        for name, flags in (("ok", ["ASAN=1"]), *((f, [f"FAULT={f}"]) for f in FAULTS)):
            proc = subprocess.run(["make", "-C", str(SOURCE), f"PYTHON={sys.executable}",
                                   f"BUILD={out / name}", f"INCLUDE={out / 'include'}", *flags],
                                  capture_output=True, text=True, timeout=300)
            assert proc.returncode == 0, proc.stdout + proc.stderr
            assert "warning:" not in proc.stderr, proc.stderr
            made[name] = out / name / "manager"
        return made

    made = once(tmp_path_factory, "mcp_c_manager", make)
    assert all(p.is_file() for p in made.values()), made
    assert not list(SOURCE.rglob("mavlink.h")), "generated headers must not be in the source tree"
    return made


def run(tmp_path: Path, manager: Path, challenge: int) -> tuple[int, dict, str]:
    spawn = (f"{shlex.quote(str(manager))} --challenge {{challenge}} --drones {{drones}}"
             " --waypoints {waypoints} --obstacles {obstacles}"
             " --bind {target_host}:{target_port} --send-to {broadcast}:{listen_port}"
             f" --rto {RTO}")
    out = tmp_path / "r.json"
    proc = run_module("conformance", ["--role", "manager", "--challenge", str(challenge),
                                      "--rto", RTO, "--ack-window", RTO, "--json", str(out),
                                      "--spawn", spawn], timeout=300)
    assert out.exists(), proc.stdout + proc.stderr
    return proc.returncode, json.loads(out.read_text()), proc.stdout + proc.stderr


@pytest.mark.parametrize("challenge", [1, 2, 3])
def test_the_c_manager_earns_every_rule_it_shows(tmp_path: Path, builds: dict[str, Path],
                                                 challenge: int) -> None:
    rc, doc, out = run(tmp_path, builds["ok"], challenge)
    assert rc == 0, out
    other = set().union(*BY_CHALLENGE.values()) - BY_CHALLENGE[challenge]
    expected = {}
    for rule in doc["rules"]:
        expected[rule] = ("info" if rule in INFO
                          else "skipped" if rule in NOT_OBSERVED | other else "passed")
    assert doc["rules"] == expected, out
    assert {k: v for k, v in doc["summary"].items() if k in ("failed", "warned", "error")} \
        == {"failed": 0, "warned": 0, "error": 0}, out
    assert doc["monitor"]["violations"] == [], doc["monitor"]
    assert "ERROR: AddressSanitizer" not in out, out


@pytest.mark.parametrize("fault", FAULTS)
def test_a_faulty_c_manager_fails_its_rule_and_no_other(tmp_path: Path, builds: dict[str, Path],
                                                        fault: str) -> None:
    rc, doc, out = run(tmp_path, builds[fault], 1)
    assert rc == 1, out
    bad = {rule for rule, outcome in doc["rules"].items() if outcome in ("failed", "warned", "error")}
    assert bad == {BROKEN[fault]}, out
    assert doc["rules"][BROKEN[fault]] == "failed", out

"""NSQD-MSG-3 ("a valid command takes its effect") judged on a backend that ignores commands.

Every case that judges a command's effect first settles the backend (CAPTURE_IMAGES, else
STOP_TEST, else TAKEOFF) out of the command's states. A backend that ignores those three never
settled, so every NSQD-MSG-3 case skipped "judged by NSQD-MSG-3's cases" and nobody judged it:
against tests/fuzz/servers/misbehaving_backend.py ``--mode deaf`` the rule ended skipped. The
cases now start from the state the backend shows when it cannot be settled
(``StreamCaseContext.start_outside``): the deaf backend fails NSQD-MSG-3 on each command
whose effect differs from its state, and one that ignores only the settling commands
(``--mode deaf-to``) fails it on exactly those, its other commands passing. The correct
backends pass as before (tests/nsqd/test_conform_nsqd.py)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

from tests.forkserver import run_module

pytestmark = [pytest.mark.slow, pytest.mark.nsqd]

ROOT = Path(__file__).resolve().parents[2]
SETTLING = ("CAPTURE_IMAGES", "STOP_TEST", "TAKEOFF")  # conformance.nsqd_case.SETTLE_COMMANDS
EFFECT = "MSG/test_command_takes_its_effect"


def _run(tmp_path: Path, *mode: str) -> tuple[int, dict, str]:
    out = tmp_path / "r.json"
    cmd = " ".join((sys.executable, "-m tests.fuzz.servers.misbehaving_backend",
                    "--bind {target_host}:{target_port} --lifetime 120", *mode))
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = run_module("conformance", ["--protocol", "nsqd", "--json", str(out), "--spawn", cmd,
                                      "--select", "NSQD-MSG-3"], timeout=300, cwd=ROOT, env=env)
    return proc.returncode, json.loads(out.read_text()), proc.stdout + proc.stderr


def _by_outcome(doc: dict, outcome: str) -> dict[str, dict]:
    return {c["id"]: c for c in doc["cases"] if c["outcome"] == outcome}


def test_a_deaf_backend_fails_msg3(tmp_path):
    rc, doc, out = _run(tmp_path, "--mode deaf")
    assert rc == 1 and doc["rules"]["NSQD-MSG-3"] == "failed", out
    failed, skipped = _by_outcome(doc, "failed"), _by_outcome(doc, "skipped")
    assert {c["failed_rule"] for c in failed.values()} == {"NSQD-MSG-3"}, out
    assert {f"{EFFECT}[{n}]" for n in SETTLING} <= set(failed), out  # the cases a skip points at judge
    assert "MSG/test_large_flight_path_is_taken" in failed, out
    for c in failed.values():
        assert "states seen: GROUNDED" in c["actual"] and "from GROUNDED, unsettled" in c["expected"], c
    # LAND's effect is the state the deaf backend sits in: that case alone cannot observe, and says so
    assert set(skipped) == {f"{EFFECT}[LAND]"}, out
    reason = skipped[f"{EFFECT}[LAND]"]["reason"]
    assert "it shows GROUNDED" in reason and "NSQD-MSG-3's cases of those commands judge them" in reason


def test_a_backend_deaf_to_the_settling_commands_fails_them_alone(tmp_path):
    rc, doc, out = _run(tmp_path, "--mode deaf-to --ignore", ",".join(SETTLING))
    assert rc == 1 and doc["rules"]["NSQD-MSG-3"] == "failed", out
    failed = _by_outcome(doc, "failed")
    assert set(failed) == {f"{EFFECT}[{n}]" for n in SETTLING}, out  # the commands it takes pass
    assert {c["failed_rule"] for c in failed.values()} == {"NSQD-MSG-3"}, out
    assert len(_by_outcome(doc, "passed")) >= 6, out
